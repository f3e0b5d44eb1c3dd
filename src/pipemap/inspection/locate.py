"""`pipemap locate`: the wall point seen at a pixel of a frame, as chainage, clock position and 3D point.

The pixel is unprojected by the result's camera model to a bearing, turned into the world by the frame's
pose and cast to the fitted wall within the camera's sight along the route (wall_cast.py); the point's route
coordinates follow (Route.to_route, the pass nearest the camera's own chainage where the route loops). A
keyframe has its pose; any other frame gets its position interpolated between the keyframes and its orientation
registered to the nearest keyframe from the images when the result's dataset can be read, else slerped
(frame_pose.py; measured in benchmarks/bench_locate.py).

Uncertainty: first-order propagation. The located chainage and clock are differentiated numerically with
respect to the pixel, the camera centre, its orientation and the pipe radius; their variances (the `locate`
settings) map through those derivatives, and the VO's scale drift adds drift_fraction x chainage along.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from pipemap.camera import CameraModel, camera_from_dict
from pipemap.config import LocateSettings
from pipemap.errors import PipemapError
from pipemap.inspection.frame_pose import interpolated_pose, registered_rotation
from pipemap.inspection.route import Route
from pipemap.inspection.result_route import load_route
from pipemap.inspection.wall_cast import Bend, Tube, cast_to_wall, in_sight, thicker, wall_shapes
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
    images: Callable[[int], np.ndarray] | None = None  # grey image of a frame (None: the dataset is not at hand)
    _registered: dict = field(default_factory=dict)

    def pose(self, frame: int, settings: LocateSettings | None = None) -> tuple[np.ndarray, np.ndarray, str]:
        """(R_wc, centre, how: keyframe | registered | interpolated | nearest keyframe) of a frame."""
        if not 0 <= frame < self.frame_count:
            raise PipemapError(f"frame {frame} is not in the recording (0..{self.frame_count - 1})",
                               self.folder / "frames.csv")
        R, C, how = interpolated_pose(self.keyframe_frames, self.poses, frame)
        s = settings or LocateSettings()
        if how != "interpolated" or not s.register_frames or self.images is None:
            return R, C, how
        if frame not in self._registered:
            k = int(np.argmin(np.abs(self.keyframe_frames - frame)))
            try:
                key, image = self.images(int(self.keyframe_frames[k])), self.images(frame)
            except (PipemapError, OSError, IndexError):
                key = image = None
            self._registered[frame] = None if key is None else registered_rotation(
                self.camera, key, image, self.poses[k, :3, :3], s.register_threshold_px)
        R_reg = self._registered[frame]
        return (R, C, how) if R_reg is None else (R_reg, C, "registered")

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
                         list(run.get("wall_pieces") or []), frames[1], _frame_images(run, camera, frames[1]))


def _frame_images(run: dict, camera: CameraModel, frame_count: int) -> Callable[[int], np.ndarray] | None:
    """A reader of the run's own frames, or None where its dataset is gone or is not the one that was run."""
    from pipemap.dataset import load_dataset

    try:
        ds = load_dataset(run.get("input", ""))
    except PipemapError:
        return None
    if len(ds) != frame_count or (ds.camera.width, ds.camera.height) != (camera.width, camera.height):
        return None
    return lambda index: ds.read(index).image


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
    """Chainage, clock, wall point, route segment and success of pixels: each along the pipe whose wall its ray
    met (the segment named as the wall piece or elbow)."""
    bearings, valid = res.camera.unproject(pixels)
    points, hit, shape = cast_to_wall(C, bearings @ R.T, tubes, bends)
    names = np.array([s.name for s in list(tubes) + list(bends)] + [""], dtype=object)[shape]
    chain, clock, _, seg = res.route.to_route(np.where(hit[:, None], points, 0.0), wall=True, near_chainage=near,
                                              segment=res.route.segments_named(names, near))
    return chain, clock, points, seg, hit & valid


def locate_pixels(res: LocatedResult, frame: int, pixels, settings: LocateSettings | None = None) -> Located:
    """Locate pixels (n, 2) of `frame` on the wall, with their uncertainty."""
    s = settings or LocateSettings()
    px = np.atleast_2d(np.asarray(pixels, float))
    R, C, how = res.pose(frame, s)
    near = res.chainage_of_frame(frame)
    shapes = in_sight(res.tubes, res.bends, res.route, near)
    chain, clock, points, seg, ok = _coordinates(res, R, C, px, *shapes, near)
    var_c = np.zeros(len(px))
    var_k = np.zeros(len(px))

    def add(sigma, step, chain2, clock2):
        nonlocal var_c, var_k
        var_c = var_c + (sigma * (chain2 - chain) / step) ** 2
        var_k = var_k + (sigma * _wrap(clock2 - clock) / step) ** 2

    for axis in range(2):
        d = np.zeros(2)
        d[axis] = STEP_PX
        c2, k2, *_ = _coordinates(res, R, C, px + d, *shapes, near)
        add(s.pixel_sigma_px, STEP_PX, c2, k2)
    for axis in range(3):
        d = np.zeros(3)
        d[axis] = STEP_M
        c2, k2, *_ = _coordinates(res, R, C + d, px, *shapes, near)
        add(s.position_sigma_m, STEP_M, c2, k2)
        turn = Rotation.from_rotvec(d / STEP_M * STEP_RAD).as_matrix()
        c2, k2, *_ = _coordinates(res, turn @ R, C, px, *shapes, near)
        add(np.radians(s.rotation_sigma_deg), STEP_RAD, c2, k2)
    c2, k2, *_ = _coordinates(res, R, C, px, *thicker(*shapes, STEP_M), near)
    add(s.radius_sigma_m, STEP_M, c2, k2)
    var_c = var_c + (s.drift_fraction * np.abs(chain)) ** 2
    return Located(np.where(ok, chain, np.nan), np.where(ok, clock, np.nan), np.where(ok[:, None], points, np.nan),
                   np.where(ok, np.sqrt(var_c), np.nan), np.where(ok, np.sqrt(var_k), np.nan), seg, ok, how)


def _wrap(deg):
    return (np.asarray(deg) + 180.0) % 360.0 - 180.0


__all__ = ["LocatedResult", "Located", "open_result", "locate_pixels"]
