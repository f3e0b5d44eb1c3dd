"""`pipemap locate`: the wall point seen at a pixel of a frame, as chainage, clock position and 3D point.

The pixel is unprojected by the result's camera model to a bearing, turned into the world by the frame's
pose and cast to the fitted wall (wall_cast.py); the point's route coordinates follow (Route.to_route, the
pass nearest the camera's own chainage where the route loops). A keyframe has its pose; any other frame gets
one interpolated between the keyframes either side by frame index (position linearly, orientation by slerp):
keyframes are a few frames apart on a robot that moves smoothly, so this costs millimetres, measured in
benchmarks/bench_locate.py. Frames before the first or after the last keyframe take the nearest one's pose.

Uncertainty: first-order propagation. The located chainage and clock are differentiated numerically with
respect to the pixel, the camera centre, its orientation and the pipe radius; their variances (the `locate`
settings) map through those derivatives, and the VO's scale drift adds drift_fraction x chainage along.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pipemap.camera import CameraModel, camera_from_dict
from pipemap.config import LocateSettings
from pipemap.errors import PipemapError
from pipemap.inspection.route import Route
from pipemap.inspection.result_route import load_route
from pipemap.inspection.wall_cast import Bend, Tube, cast_to_wall, wall_shapes
from pipemap.mapping.pieces import read_run
from pipemap.trajectory import read_tum

STEP_PX, STEP_M, STEP_RAD = 0.5, 1e-3, 1e-3  # finite-difference steps of the uncertainty's derivatives


@dataclass
class LocatedResult:
    """What locating needs from a result folder."""

    folder: Path
    route: Route
    camera: CameraModel
    keyframe_frames: np.ndarray  # (K,) frame index of each pose
    poses: np.ndarray  # (K, 4, 4) T_wc
    keyframe_chainage: np.ndarray  # (K,)
    tubes: list[Tube]
    bends: list[Bend]
    pieces: list[dict]
    frame_count: int

    def pose(self, frame: int) -> tuple[np.ndarray, np.ndarray, str]:
        """(R_wc, centre, how: keyframe | interpolated | nearest keyframe) of a frame."""
        if not 0 <= frame < self.frame_count:
            raise PipemapError(f"frame {frame} is not in the recording (0..{self.frame_count - 1})",
                               self.folder / "frames.csv")
        k = np.searchsorted(self.keyframe_frames, frame)
        if k < len(self.keyframe_frames) and self.keyframe_frames[k] == frame:
            return self.poses[k, :3, :3], self.poses[k, :3, 3], "keyframe"
        if k == 0 or k == len(self.keyframe_frames):
            k = min(k, len(self.keyframe_frames) - 1)
            return self.poses[k, :3, :3], self.poses[k, :3, 3], "nearest keyframe"
        f0, f1 = self.keyframe_frames[k - 1], self.keyframe_frames[k]
        a = (frame - f0) / (f1 - f0)
        rots = Rotation.from_matrix(self.poses[k - 1:k + 1, :3, :3])
        R = Slerp([0.0, 1.0], rots)([a]).as_matrix()[0]
        C = (1 - a) * self.poses[k - 1, :3, 3] + a * self.poses[k, :3, 3]
        return R, C, "interpolated"

    def chainage_of_frame(self, frame: int) -> float:
        return float(np.interp(frame, self.keyframe_frames, self.keyframe_chainage))


def open_result(folder: str | Path) -> LocatedResult:
    """The route, camera, keyframe poses and wall of a network result folder."""
    folder = Path(folder)
    run = read_run(folder)
    route = load_route(folder, run)
    block = run.get("camera")
    if block is None:  # results before pipemap-run/2: the dataset's own camera block
        from pipemap.dataset import load_dataset

        try:
            camera = load_dataset(run.get("input", "")).camera
        except PipemapError as exc:
            raise PipemapError(f"run.json has no camera and its dataset cannot be read ({exc.line()})",
                               folder / "run.json") from None
    else:
        camera = camera_from_dict(block, folder / "run.json")
    traj = read_tum(folder / "trajectory.tum")
    frames = _keyframe_frames(folder / "frames.csv", len(traj))
    poses = traj.matrices()
    tubes, bends = wall_shapes(run.get("wall_pieces") or [], route)
    return LocatedResult(folder, route, camera, frames[0], poses, route.follow(poses[:, :3, 3]), tubes, bends,
                         list(run.get("wall_pieces") or []), frames[1])


def _keyframe_frames(path: Path, poses: int) -> tuple[np.ndarray, int]:
    """(frame index of each trajectory pose, frames in the recording) from frames.csv."""
    try:
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        index = np.array([int(r["index"]) for r in rows])
        key = np.array([str(r["keyframe"]).strip() in ("1", "true", "True") for r in rows])
    except FileNotFoundError:
        raise PipemapError("no frames.csv in the result folder", path) from None
    except (KeyError, ValueError, OSError) as exc:
        raise PipemapError(f"cannot read frames: {exc}", path) from None
    frames = index[key]
    if len(frames) != poses:
        raise PipemapError(f"{len(frames)} keyframes but {poses} poses in trajectory.tum", path)
    return frames, int(index.max()) + 1 if len(index) else 0


@dataclass
class Located:
    """Located pixels: chainage (m), clock (deg), world points (n, 3), their sigmas, the route segment and
    whether the ray met the wall; `pose` says where the frame's pose came from."""

    chainage: np.ndarray
    clock_deg: np.ndarray
    points: np.ndarray
    sigma_chainage: np.ndarray
    sigma_clock_deg: np.ndarray
    segment: np.ndarray
    ok: np.ndarray
    pose: str


def _coordinates(res: LocatedResult, R, C, pixels, tubes, bends, near):
    bearings, valid = res.camera.unproject(pixels)
    points, hit = cast_to_wall(C, bearings @ R.T, tubes, bends)
    chain, clock, _, seg = res.route.to_route(np.where(hit[:, None], points, 0.0), wall=True, near_chainage=near)
    return chain, clock, points, seg, hit & valid


def locate_pixels(res: LocatedResult, frame: int, pixels, settings: LocateSettings | None = None) -> Located:
    """Locate pixels (n, 2) of `frame` on the wall, with their uncertainty."""
    s = settings or LocateSettings()
    px = np.atleast_2d(np.asarray(pixels, float))
    R, C, how = res.pose(frame)
    near = res.chainage_of_frame(frame)
    chain, clock, points, seg, ok = _coordinates(res, R, C, px, res.tubes, res.bends, near)
    var_c = np.zeros(len(px))
    var_k = np.zeros(len(px))

    def add(sigma, step, chain2, clock2):
        nonlocal var_c, var_k
        var_c = var_c + (sigma * (chain2 - chain) / step) ** 2
        var_k = var_k + (sigma * _wrap(clock2 - clock) / step) ** 2

    for axis in range(2):
        d = np.zeros(2)
        d[axis] = STEP_PX
        c2, k2, *_ = _coordinates(res, R, C, px + d, res.tubes, res.bends, near)
        add(s.pixel_sigma_px, STEP_PX, c2, k2)
    for axis in range(3):
        d = np.zeros(3)
        d[axis] = STEP_M
        c2, k2, *_ = _coordinates(res, R, C + d, px, res.tubes, res.bends, near)
        add(s.position_sigma_m, STEP_M, c2, k2)
        turn = Rotation.from_rotvec(d / STEP_M * STEP_RAD).as_matrix()
        c2, k2, *_ = _coordinates(res, turn @ R, C, px, res.tubes, res.bends, near)
        add(np.radians(s.rotation_sigma_deg), STEP_RAD, c2, k2)
    tubes = [Tube(t.start, t.end, t.radius + STEP_M) for t in res.tubes]
    bends = [Bend(b.centre, b.normal, b.e1, b.bend_radius, b.angle, b.radius + STEP_M) for b in res.bends]
    c2, k2, *_ = _coordinates(res, R, C, px, tubes, bends, near)
    add(s.radius_sigma_m, STEP_M, c2, k2)
    var_c = var_c + (s.drift_fraction * np.abs(chain)) ** 2
    return Located(np.where(ok, chain, np.nan), np.where(ok, clock, np.nan), np.where(ok[:, None], points, np.nan),
                   np.where(ok, np.sqrt(var_c), np.nan), np.where(ok, np.sqrt(var_k), np.nan), seg, ok, how)


def _wrap(deg):
    return (np.asarray(deg) + 180.0) % 360.0 - 180.0


__all__ = ["LocatedResult", "Located", "open_result", "locate_pixels"]
