"""Dense straight-pipe visual odometry (2010 report section 4) and its stitched wall image (section 6).

Per adjacent pair of reduced, undistorted frames the image translation is registered (full
search, hierarchical Lucas-Kanade, or both), converted to metres with zeta pixels per metre
(eq. 19) and integrated. The translation model needs a camera square to the wall with image x
along the pipe; unless told it is (dense.mount = square), the camera's mount is estimated first by
the sparse method's initial batch (mount.py) and every frame is turned to a virtual camera in that
pose (undistort.py), whose offset from the axis also gives zeta where no reference is given.
World frame = the first frame's virtual camera, a pipe frame: x along the pipe (h), y across it,
z towards the wall it looks at. Rotation is assumed constant (the report's model; every pose
carries the mount); only the camera centre moves.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable, Iterator

import cv2
import numpy as np

from pipemap.config import DenseSettings, Settings
from pipemap.dataset import Dataset, load_dataset
from pipemap.errors import PipemapError
from pipemap.footage import FootageLog
from pipemap.frontend.tracks_io import write_frames_csv
from pipemap.output import result_folder
from pipemap.quality import FrameStats, RunVerdict, require_mappable, straight_verdict
from pipemap.results import run_record, write_run_json
from pipemap.straight.mount import Mount, estimate_mount
from pipemap.straight.registration import Shift, adaptive_full_search, hybrid, lucas_kanade
from pipemap.straight.scale import row_pixels_per_metre, wall_depth
from pipemap.straight.sparse.features import flatten_light
from pipemap.straight.sparse.geometry import R0, rotation_from_travel, wall_distance
from pipemap.straight.stations import OffsetTrack, offset_track, station_starts
from pipemap.straight.undistort import QUARTER, Rectifier, reduction_for_wall
from pipemap.straight.unroll import frame_images, unroll_poses, write_wall
from pipemap.trajectory import Trajectory, write_tum

DENSE_METHODS = ("dense-full-search", "dense-lk", "dense-hybrid")


@dataclass
class DenseResult:
    method: str
    indices: np.ndarray  # (N,) frame indices
    shifts: np.ndarray  # (N-1, 2) content displacement frame k-1 -> k, rectified pixels
    scores: np.ndarray  # (N-1,)
    zeta: float  # pixels per metre
    zeta_source: str
    trajectory: Trajectory
    size: tuple[int, int]  # rectified (width, height)
    rows: tuple[int, int]
    seconds: dict = field(default_factory=dict)
    mount: Mount | None = None
    quality: RunVerdict | None = None  # the self-checks


def band_rows(height: int, fraction: float) -> tuple[int, int]:
    y0 = int(round(height * (1 - fraction) / 2))
    return y0, max(y0 + 8, height - y0)


def register_pair(I0: np.ndarray, I1: np.ndarray, method: str, dense: DenseSettings,
                  prior=(0.0, 0.0), rows=None) -> Shift:
    """The shift of one pair of rectified images by the chosen method."""
    search = (dense.search_px, dense.search_px // 2 if dense.search_y_px is None else dense.search_y_px)
    if method == "dense-full-search":
        return adaptive_full_search(I0, I1, search, prior, dense.metric, rows, dense.search_min_zncc)
    if method == "dense-lk":
        return lucas_kanade(I0, I1, prior, dense.pyramid_levels, dense.lk_iterations, rows, dense.lk_tolerance_px)
    if method == "dense-hybrid":
        return hybrid(I0, I1, search, prior, dense.metric, dense.lk_iterations, rows, dense.lk_tolerance_px,
                      dense.search_min_zncc)
    raise PipemapError(f"unknown dense method {method!r} (expected one of {', '.join(DENSE_METHODS)})", key="method")


def estimate_shifts(images: Iterable[np.ndarray], method: str, dense: DenseSettings,
                    rows=None, on_frame: Callable[[int, np.ndarray, np.ndarray], None] | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Shift of every adjacent pair of rectified images: (N-1, 2) pixels and (N-1,) scores.

    The full search registers each frame against a reference frame kept until the content has moved
    dense.full_search_reference_fraction of the image width (then the frame becomes the reference):
    its integer rounding then errs once per reference, not once per frame, where a steady speed would
    round the same way every frame. With the fraction None (and for the other methods) every frame is
    registered against the one before, as the report's Algorithm 1 does.

    on_frame(k, image, shift) after each image; shift is the pair (k-1, k)'s, zeros for k = 0."""
    if method not in DENSE_METHODS:
        raise PipemapError(f"unknown dense method {method!r} (expected one of {', '.join(DENSE_METHODS)})",
                           key="method")
    fraction = dense.full_search_reference_fraction if method == "dense-full-search" else None
    shifts, scores = [], []
    ref = None
    ref_c = c_prev = velocity = np.zeros(2)  # content displacements from the first frame
    for k, img in enumerate(images):
        t = np.zeros(2)
        if ref is not None:
            since_ref = c_prev - ref_c
            prior = since_ref + (velocity if dense.predict else 0.0)
            s = register_pair(ref, img, method, dense, prior, rows)
            t = s.t - since_ref
            shifts.append(t)
            scores.append(s.score)
            if np.all(np.isfinite(t)):
                velocity = t
                c_prev = c_prev + t
        if ref is None or fraction is None or abs(c_prev[0] - ref_c[0]) >= fraction * img.shape[1]:
            ref, ref_c = img, c_prev
        if on_frame is not None:
            on_frame(k, img, t)
    return np.reshape(np.array(shifts, float), (-1, 2)), np.array(scores, float)


def integrate(shifts: np.ndarray, zeta) -> np.ndarray:
    """Camera centres (N, 3) in the first camera's frame: the camera moves against the image content.
    `zeta`: pixels per metre, one for all pairs or (N-1,) one per pair."""
    steps = np.asarray(shifts, float) / np.reshape(np.asarray(zeta, float), (-1, 1))
    c = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    pos = np.zeros((len(c), 3))
    pos[:, :2] = -c
    return pos


def texture_weights(img: np.ndarray, rows) -> np.ndarray:
    """Each registered row's weight in a fitted shift along the pipe: its sum of squared x-gradients."""
    gx = cv2.Sobel(np.asarray(img, np.float32)[int(rows[0]):int(rows[1])], cv2.CV_32F, 1, 0, ksize=3)
    return np.einsum("ij,ij->i", gx, gx).astype(float)


def _frames(dataset: Dataset, rect: Rectifier, counter: list, gain_correct: bool,
            light_sigma_px: float | None = None, log: FootageLog | None = None) -> Iterator[np.ndarray]:
    """The rectified frames to register; with light_sigma_px, each divided by its own blur
    (sparse_features.flatten_light): without a gain mask the LEDs' light is a pattern fixed in the image while
    the wall moves through it, and it holds the registration back towards no motion (5.5 % short at 50 deg).
    Repeated frames (a stalled link) are skipped."""
    for frame in dataset.frames(gain_correct=gain_correct, log=log):
        if frame.repeated:
            continue
        counter.append(frame.index)
        img = rect(frame.image)
        yield img if light_sigma_px is None else flatten_light(img, light_sigma_px)


def run_dense(dataset_path, out_dir, settings: Settings | None = None, method: str = "dense-hybrid",
              progress: Callable[[int, int], None] | None = None) -> DenseResult:
    """Dense VO on a dataset of a straight pipe seen by a perspective camera looking at the wall;
    writes trajectory.tum, frames.csv, run.json and unrolled/dense_000.{png,json} into `out_dir`
    atomically. progress(done, total) after every frame."""
    settings = settings or Settings()
    dense = settings.dense
    if method not in DENSE_METHODS:
        raise PipemapError(f"unknown dense method {method!r} (expected one of {', '.join(DENSE_METHODS)})",
                           key="method")
    dataset = load_dataset(dataset_path)
    Rectifier(dataset.camera, dense.scale or QUARTER, dataset.yaml_path)  # a fisheye or a bad scale: refused at once
    view = _rectified_view(dataset, settings)
    start = time.perf_counter()
    with result_folder(Path(out_dir)) as tmp:
        reg = _register(dataset, view, settings, method, progress)
        idx, shifts, scores, feed, log = reg.indices, reg.shifts, reg.scores, reg.feed, reg.log
        track = _offset_track(dataset, settings, view, idx, shifts)
        turn = _mean_turn(view, track, dense.rerectify_min_pct)
        if turn is not None:  # the run's mean pipe axis is off the first frames': turn the view to it, register again
            view = replace(_rectified_view(dataset, settings, view.mount, turn), mount_seconds=view.mount_seconds)
            reg = _register(dataset, view, settings, method, progress)
            idx, shifts, scores, feed, log = reg.indices, reg.shifts, reg.scores, reg.feed, reg.log
        t_reg = time.perf_counter() - start - (0.0 if track is None else track.seconds)
        rect = view.rect
        pos = integrate(shifts, view.zeta if view.row_zeta is None else _pair_zeta(view, feed.pair_weights, idx, track))
        traj = Trajectory(dataset.times()[idx], pos, np.tile(rect.rotation, (len(idx), 1, 1)))  # camera -> virtual axes
        t1 = time.perf_counter()
        _write_trajectory_and_frames(tmp, method, traj, dataset, idx, log)
        _write_unrolled(tmp / "unrolled", dataset, view, idx[feed.stitched], pos[feed.stitched], dense, method)
        quality = straight_verdict(method, idx, traj.timestamps, pos[:, 0], view.mount, dataset.radius_m,
                                   settings.quality, scale_source=view.scale["source"])
        seconds = {"mount": view.mount_seconds, "offset_stations": 0.0 if track is None else track.seconds,
                   "registration": t_reg, "write": time.perf_counter() - t1}
        seconds["total"] = time.perf_counter() - start
        write_run_json(tmp, _run_record(method, dataset, settings, view, idx, pos, log, t_reg, quality, seconds, track))
    return DenseResult(method, idx, shifts, scores, view.zeta, view.scale["text"], traj, rect.size, view.rows,
                       seconds, view.mount, quality)


@dataclass
class _RectifiedView:
    """The virtual camera the frames are registered in: the mount it is turned by, and its scale."""

    mount: Mount | None
    mount_seconds: float
    turn: np.ndarray | None  # the rotation the frames are turned by, None for the report's square camera
    reduction: float
    rect: Rectifier
    rows: tuple[int, int]  # the registered band
    zeta: float
    scale: dict  # where zeta came from (_scale)
    row_zeta: np.ndarray | None
    radius_m: float


@dataclass
class _Registration:
    indices: np.ndarray  # frame indices registered
    shifts: np.ndarray
    scores: np.ndarray
    feed: "_RegisteredFrames"
    log: FootageLog


def _register(dataset: Dataset, view: _RectifiedView, settings: Settings, method: str,
              progress: Callable[[int, int], None] | None) -> _Registration:
    """Every frame turned to the view and registered to the one before; refuses a recording with nothing to map."""
    dense = settings.dense
    indices: list[int] = []
    stats = FrameStats.for_settings(settings)
    feed = _RegisteredFrames(view, dense.stitch_min_shift_px, stats, progress, len(dataset))
    corrected = dense.gain_correct and dataset.has_gain_mask
    log = FootageLog()
    frames = _frames(dataset, view.rect, indices, dense.gain_correct, None if corrected else dense.light_sigma_px, log)
    shifts, scores = estimate_shifts(frames, method, dense, view.rows, feed)
    if len(indices) == 0:
        raise PipemapError("no images in the dataset", dataset.root)
    require_mappable(stats, len(indices), len(dataset), len(log.repeated), settings, dataset.root)
    return _Registration(np.array(indices, int), shifts, scores, feed, log)


def _mean_turn(view: _RectifiedView, track: OffsetTrack | None, min_pct: float | None) -> np.ndarray | None:
    """The rotation to the stations' mean pipe axis where turning to it changes the scale by more than `min_pct`:
    a view tilted along the pipe by delta scales its image motion by 2 delta tan(theta) at theta from its principal
    point (0.29 % for the 0.24 deg the first 0.5 m of wall-camera-75 seed 1 were off the run's mean; nothing for a
    camera square to the wall, whose registered band is centred on its principal point)."""
    if track is None or view.turn is None or not min_pct or len(track.axes) < 2:
        return None
    axis = np.mean(track.axes, axis=0)
    axis /= np.linalg.norm(axis)
    delta = np.arccos(np.clip(axis @ view.turn[2], -1.0, 1.0))
    rect = view.rect
    tan_centre = ((rect.size[0] - 1) / 2 - rect.K[0, 2]) / rect.focal_px
    return rotation_from_travel(axis) if 200.0 * delta * abs(tan_centre) > min_pct else None


def _rectified_view(dataset: Dataset, settings: Settings, mount: Mount | None = None,
                    turn: np.ndarray | None = None) -> _RectifiedView:
    """The mount estimate (unless dense.mount says the camera is square, or `mount` is given), the rectifier it
    gives (turned by `turn` where given), and the scale."""
    dense = settings.dense
    t_mount = time.perf_counter()
    if mount is None and dense.mount == "estimate":
        mount = estimate_mount(dataset, settings, dense.gain_correct)
    t_mount = time.perf_counter() - t_mount
    # an offset the images leave undetermined says the rotation is as loose: the report's square camera then
    if turn is None:
        turn = None if mount is None or not mount.determined else mount.rotation
    reduction = dense.scale or reduction_for_wall(dataset.camera, _wall_distance(dense, mount, dataset.radius_m),
                                                  dense.wall_mm_per_px)
    geometry = _scale_geometry(dense, dataset, mount)
    depth = None
    if geometry["source"] != "reference" and dense.resample_rows:
        def depth(v):
            return wall_depth(v, dataset.radius_m, geometry["offset_m"], geometry["side_m"])
    rect = Rectifier(dataset.camera, reduction, dataset.yaml_path, turn, dense.rectify_max_angle_deg, depth)
    rows = band_rows(rect.size[1], dense.band_fraction)
    zeta, scale, row_zeta = _scale(dense, rect, dataset, geometry, rows)
    return _RectifiedView(mount, t_mount, turn, reduction, rect, rows, zeta, scale, row_zeta, dataset.radius_m)


class _RegisteredFrames:
    """Called with each registered frame: its statistics, its pair's zeta (the rows' own zetas weighted by the
    texture of the pair's first frame), whether it goes into the stitched wall, and the progress."""

    def __init__(self, view: _RectifiedView, stitch_min_shift_px: float, stats: FrameStats,
                 progress: Callable[[int, int], None] | None, total: int):
        self.view, self.stats = view, stats
        self.stitch_min_shift = stitch_min_shift_px
        self.stitched: list[int] = []  # registered frames stitched into the wall: the report's 50 px apart
        self._stitched_at = 0.0
        self.progress, self.total = progress, total
        self.content = np.zeros(2)  # the content's displacement from the first frame
        self.weights: np.ndarray | None = None
        self.pair_weights: list[np.ndarray] = []  # each pair's row weights: its first frame's texture

    def __call__(self, k: int, img: np.ndarray, t: np.ndarray) -> None:
        self.stats.add(img)
        self.content = self.content + t
        if self.view.row_zeta is not None:
            if k > 0:
                self.pair_weights.append(self.weights)
            self.weights = texture_weights(img, self.view.rows)
        if not self.stitched or abs(self.content[0] - self._stitched_at) >= self.stitch_min_shift:
            self.stitched.append(k)
            self._stitched_at = self.content[0]
        if self.progress is not None:
            self.progress(k + 1, self.total)


def _write_trajectory_and_frames(tmp: Path, method: str, traj: Trajectory, dataset: Dataset, idx: np.ndarray,
                                 log: FootageLog) -> None:
    write_tum(tmp / "trajectory.tum", traj, header=(
        f"pipemap dense VO ({method}): every frame's T_wc in metres; world = the first frame's camera turned "
        "square to the wall (x along the pipe, z towards the viewed wall)"))
    labels = {int(i): "straight" for i in idx}
    labels.update({i: "repeated" for i in log.repeated})
    write_frames_csv(tmp / "frames.csv", len(dataset), idx, labels)


def _write_unrolled(folder: Path, dataset: Dataset, view: _RectifiedView, idx: np.ndarray, pos: np.ndarray,
                    dense: DenseSettings, method: str) -> None:
    """The stitched frames (report section 6) carried onto the wall, (h, r phi), as every method unrolls it:
    dense_000.png and its sidecar in a new `folder`. Each frame's pose in the pipe frame is the mount (or the
    report's square camera at the offset the scale assumed) moved along the axis by its registered distance."""
    radius = dataset.radius_m
    if view.turn is not None:
        R, offset = view.turn, np.asarray(view.mount.offset_m, float)
    else:
        R, offset = R0, np.array([0.0, radius - _wall_distance(dense, view.mount, radius)])
    C = np.column_stack([np.tile(offset, (len(idx), 1)), pos[:, 0]])
    wall = unroll_poses(frame_images(dataset, idx, dense.gain_correct), dataset.camera, radius,
                        np.broadcast_to(R, (len(idx), 3, 3)), C, dense.unrolled_px_m, dense.unrolled_max_px)
    write_wall(folder, "dense_000", wall, radius, R, C[0], method=method, frames_stitched=len(idx),
               grey="the mean of the frames stitched (at least dense.stitch_min_shift_px apart along the pipe) "
               "that see the wall, stretched to 1..255; 0 = unseen")


def _offset_track(dataset: Dataset, settings: Settings, view: _RectifiedView, idx: np.ndarray,
                  shifts: np.ndarray) -> OffsetTrack | None:
    """Where the scale comes from the estimated mount, its offset measured again at stations along the run
    (stations.py), placed by the travel the run's own mount gives."""
    every = settings.dense.offset_station_m
    if view.scale["source"] != "estimated mount" or not every:
        return None
    along = integrate(shifts, view.zeta)[:, 0]
    starts = station_starts(idx, along, every)
    return offset_track(dataset, settings, settings.dense.gain_correct, view.mount, starts)


def _pair_zeta(view: _RectifiedView, pair_weights: list[np.ndarray], idx: np.ndarray,
               track: OffsetTrack | None) -> np.ndarray:
    """Each pair's zeta: its rows' own zetas (scale.py, at the offset of its part of the run where the offset was
    tracked) weighted by the texture of its first frame."""
    rect, rows, radius = view.rect, view.rows, view.radius_m
    if track is None:
        offsets = np.tile([view.scale["side_m"], view.scale["offset_m"]], (len(pair_weights), 1))
    else:
        offsets = track.at(0.5 * (idx[:-1] + idx[1:]))
    zeta = np.full(len(pair_weights), view.zeta)
    for k, (w, (side, offset)) in enumerate(zip(pair_weights, offsets)):
        if w.sum() > 0:
            zeta[k] = w @ _row_zeta(rect, radius, offset, side, rows) / w.sum()
    return zeta


def _run_record(method: str, dataset: Dataset, settings: Settings, view: _RectifiedView, idx: np.ndarray,
                pos: np.ndarray, log: FootageLog, t_reg: float, quality: RunVerdict, seconds: dict,
                track: OffsetTrack | None) -> dict:
    """run.json of a dense run: the common record, then the rectification and scale."""
    dense, mount, rect = settings.dense, view.mount, view.rect
    problems = []
    if mount is not None and view.turn is None:
        problems.append("the images did not determine the camera's mount: the camera was taken as square to the wall")
    return run_record(
        method, dataset, settings, frames=len(idx), keyframes=len(idx), trajectory="frames",
        mount=None if mount is None else mount.to_dict(), footage=log.to_dict(), problems=problems,
        quality=quality.to_dict(), seconds=seconds,
        stage="dense",
        pixels_per_metre=view.zeta,
        gain_corrected=bool(dense.gain_correct and dataset.has_gain_mask),
        pixels_per_metre_source=view.scale["text"],
        scale_source=view.scale["source"],
        scale=view.scale if track is None else {**view.scale, "offset_along_run": track.to_dict()},
        rectified_by=(("the estimated mount" if np.allclose(view.turn, mount.rotation) else
                       "the mean pipe axis of the offset stations (turning to it changed the scale by more than "
                       "dense.rerectify_min_pct)") if view.turn is not None else
                      "none: the camera taken as square to the wall with image x along the pipe" +
                      ("" if mount is None else " (the images did not determine its mount)")),
        reduction=view.reduction,
        rectified_size=list(rect.size),
        rectified_intrinsics=rect.K.tolist(),
        rectified_rotation=rect.rotation.tolist(),
        registered_rows=list(view.rows),
        frames_per_second=len(idx) / max(t_reg, 1e-9),
        distance_along_pipe_m=float(pos[-1, 0] - pos[0, 0]),
    )


def _wall_distance(dense: DenseSettings, mount: Mount | None, radius: float) -> float:
    """The distance to the wall along the optical axis: from the offset given, the mount the images determined,
    or the axis."""
    if dense.camera_offset_m is not None:
        return radius - float(dense.camera_offset_m)
    if mount is not None and mount.determined:
        return wall_distance(mount.rotation, np.r_[mount.offset_m, 0.0], radius)
    return radius


def _scale_geometry(dense: DenseSettings, dataset: Dataset, mount: Mount | None) -> dict:
    """Where zeta comes from (the reference dense.pixels_per_metre, the offset measured on the robot
    dense.camera_offset_m, the estimated mount's offset, or the axis: the report's square camera, no offset) and,
    unless it is the reference, the camera's offset and side displacement that set it."""
    if dense.pixels_per_metre is not None:
        return {"source": "reference", "text": "reference dense.pixels_per_metre"}
    if dense.camera_offset_m is not None:
        offset, side, source = float(dense.camera_offset_m), 0.0, "given offset"
        text = f"given offset dense.camera_offset_m {offset * 1e3:.2f} mm"
    elif mount is not None:
        if not mount.determined:
            raise PipemapError(
                "the images do not fix the camera's offset from the pipe axis well enough to scale the dense methods "
                "(its standard deviation exceeds sparse.offset_max_sigma of the distance to the wall: a narrow lens "
                "in a large pipe sees the wall nearly flat); give dense.camera_offset_m or dense.pixels_per_metre",
                dataset.yaml_path, "dense.camera_offset_m")
        side, offset, source = float(mount.offset_m[0]), float(mount.offset_m[1]), "estimated mount"
        text = f"estimated mount: C_X {side * 1e3:.2f} mm, C_Y {offset * 1e3:.2f} mm"
    else:
        offset, side, source = 0.0, 0.0, "axis"
        text = "camera assumed on the pipe axis"
    row_pixels_per_metre(1.0, 0.0, dataset.radius_m, offset, None, side)  # a camera outside the pipe: refused here
    return {"source": source, "offset_m": offset, "side_m": side, "text": text}


def _row_zeta(rect: Rectifier, radius: float, offset: float, side: float, rows) -> np.ndarray:
    """Each registered row's pixels per metre of axial motion (scale.py) in the view as resampled (undistort.py)."""
    lo, hi = int(rows[0]), int(rows[1])
    return row_pixels_per_metre(rect.focal_px, rect.K[1, 2], radius, offset, rows, side) / rect.row_gain[lo:hi]


def _scale(dense: DenseSettings, rect: Rectifier, dataset: Dataset, geometry: dict, rows
           ) -> tuple[float, dict, np.ndarray | None]:
    """zeta, where it came from, and, from geometry, each registered row's own zeta."""
    if geometry["source"] == "reference":
        return float(dense.pixels_per_metre), geometry, None
    row_zeta = _row_zeta(rect, dataset.radius_m, geometry["offset_m"], geometry["side_m"], rows)
    zeta = float(np.mean(row_zeta))
    resampled = "resampled to move alike" if np.ptp(rect.row_gain) > 0 else "weighted by their texture"
    return zeta, {**geometry, "rows": "weighted by their texture, pair by pair",
                  "rows_resampled_to_the_wall": bool(np.ptp(rect.row_gain) > 0),
                  "text": f"{geometry['text']} (rectified focal {rect.focal_px:.3f} px, radius {dataset.radius_m} m, "
                          f"rows {rows[0]}..{rows[1]} {resampled})"}, row_zeta
