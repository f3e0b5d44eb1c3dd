"""Sparse cylinder-constrained VO (2010 report section 5) and its unrolled wall image (section 6.1).

Region Harris keypoints with SIFT descriptors are matched between keyframes, cleaned by five-point
RANSAC, placed on the wall of a pipe of known radius, and the keyframe poses estimated against the
S(g) sums: one degree of freedom per keyframe, a batch for the first camera's offset from the axis,
six degrees of freedom in a sliding window (sparse/odometry.py has the schedule).

Only perspective (pinhole) cameras, as in the report: a fisheye dataset is refused with a clear
error (the fisheye pipeline handles those). World frame of the results = the first keyframe's
camera frame (x down the pipe, z towards the wall the camera looks at), as for the dense methods;
run.json and the unrolled image's sidecar give the estimated pipe axis in that frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from pipemap.camera.pinhole import PinholeCamera
from pipemap.config import Settings
from pipemap.dataset import Dataset, load_dataset
from pipemap.errors import PipemapError
from pipemap.footage import FootageLog
from pipemap.frontend.tracks_io import write_frames_csv
from pipemap.output import result_folder
from pipemap.quality import FrameStats, RunVerdict, require_mappable, straight_verdict
from pipemap.results import run_record, write_run_json
from pipemap.straight.mount import Mount, require_wall_view
from pipemap.straight.sparse.geometry import E_H
from pipemap.straight.sparse.keyframes import KeyframeSelector
from pipemap.straight.sparse.odometry import SparseOdometry
from pipemap.straight.unroll import UnrolledWall, frame_images, unroll_poses, write_wall
from pipemap.trajectory import Trajectory, write_tum

SPARSE_METHOD = "sparse-cylinder"


@dataclass
class SparseResult:
    indices: np.ndarray  # (K,) image index of every keyframe
    rotations_pipe: np.ndarray  # (K, 3, 3) camera -> pipe frame
    centres_pipe: np.ndarray  # (K, 3) camera centres (X, Y, h) in the pipe frame
    offset: np.ndarray  # (C_X, C_Y) of the first keyframe after the batch of eq. 45-49
    offset_rms_px: float
    trajectory: Trajectory  # keyframes in the first keyframe's camera frame
    frames: int
    unrolled: UnrolledWall | None
    seconds: dict = field(default_factory=dict)
    mount: Mount | None = None  # the camera's mount as the initial batch found it
    quality: RunVerdict | None = None  # the self-checks


def to_first_camera(R: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pipe-frame poses -> poses in the first camera's frame: T_c0^-1 T_k."""
    R0, C0 = R[0], C[0]
    return np.einsum("ji,kjl->kil", R0, R), (C - C0) @ R0


def _require_pinhole(dataset: Dataset) -> None:
    if not isinstance(dataset.camera, PinholeCamera):
        raise PipemapError(
            f"sparse-cylinder VO needs a perspective (pinhole) camera looking at the wall; the {dataset.camera.model} "
            "camera is a fisheye model, which the 2010 report's sparse method does not handle "
            "(use the fisheye pipeline)",
            dataset.yaml_path, "camera.model")


def run_sparse(dataset_path, out_dir, settings: Settings | None = None,
               progress: Callable[[int, int], None] | None = None) -> SparseResult:
    """Sparse VO on a dataset of a straight pipe seen by a perspective camera looking at the wall;
    writes trajectory.tum (keyframes), frames.csv, run.json and unrolled/sparse_000.{png,json} into
    `out_dir` atomically. progress(done, total) after every frame."""
    settings = settings or Settings()
    sp = settings.sparse
    dataset = load_dataset(dataset_path)
    _require_pinhole(dataset)
    camera, radius = dataset.camera, dataset.radius_m
    total = len(dataset)
    start = time.perf_counter()
    with result_folder(Path(out_dir)) as tmp:
        tracked = _track_keyframes(dataset, settings, progress)
        mount = _finish_odometry(tracked, dataset, settings)
        odometry, log = tracked.odometry, tracked.log
        idx, R, C = odometry.poses()
        require_mappable(tracked.stats, len(idx), total, len(log.repeated), settings, dataset.root)
        Rw, Cw = to_first_camera(R, C)
        traj = Trajectory(dataset.times()[idx], Cw, Rw)

        t2 = time.perf_counter()
        wall = _unrolled(dataset, camera, radius, idx, R, C, sp)
        t_unroll = time.perf_counter() - t2

        t3 = time.perf_counter()
        axis_origin = (np.array([0.0, 0.0, C[0, 2]]) - C[0]) @ R[0]  # the axis point beside the first camera
        axis_dir = E_H @ R[0]
        _write_keyframes_and_wall(tmp, dataset, tracked, traj, idx, wall, axis_origin, axis_dir, R[0], C[0])
        seconds = {"features": tracked.t_features, "motion": tracked.t_motion, "unroll": t_unroll,
                   "write": time.perf_counter() - t3}
        seconds["total"] = time.perf_counter() - start
        off = odometry.offset
        offset = np.asarray(C[0, :2], float)
        quality = straight_verdict(SPARSE_METHOD, idx, traj.timestamps, C[:, 2], mount, radius, settings.quality,
                                   batch_rms_px=None if off is None else off.fit_rms_px,
                                   unconstrained=odometry.unconstrained)
        write_run_json(tmp, _run_record(dataset, settings, tracked, idx, C, mount, axis_origin, axis_dir, quality,
                                        seconds))
    return SparseResult(idx, R, C, offset, np.nan if off is None else off.rms_px, traj, tracked.frames, wall, seconds,
                        mount, quality)


@dataclass
class _FramePass:
    """The pass over the frames: the keyframe selection and odometry it fed, what it read, and its time."""

    selector: KeyframeSelector
    odometry: SparseOdometry
    log: FootageLog
    stats: FrameStats
    read: list[int] = field(default_factory=list)  # the frames read, repeated ones left out
    frames: int = 0
    t_features: float = 0.0
    t_motion: float = 0.0


def _track_keyframes(dataset: Dataset, settings: Settings, progress: Callable[[int, int], None] | None
                     ) -> _FramePass:
    """Every frame through the keyframe selector, and the keyframe links it gives through the odometry."""
    sp = settings.sparse
    camera, radius = dataset.camera, dataset.radius_m
    selector = KeyframeSelector(camera, sp, settings.seed, not (sp.gain_correct and dataset.has_gain_mask))
    odometry = SparseOdometry(camera, radius, sp, settings.seed)
    tracked = _FramePass(selector, odometry, FootageLog(), FrameStats.for_settings(settings))
    total = len(dataset)
    for frame in dataset.frames(gain_correct=sp.gain_correct, log=tracked.log):
        if frame.repeated:  # a stalled link's copy: nothing new, and no keyframe can come of it
            continue
        tracked.read.append(frame.index)
        tracked.stats.add(frame.image)
        t0 = time.perf_counter()
        links = list(selector.push(frame.index, frame.image))
        t1 = time.perf_counter()
        for link in links:
            odometry.add(link)
        tracked.t_features += t1 - t0
        tracked.t_motion += time.perf_counter() - t1
        tracked.frames += 1
        if progress is not None:
            progress(tracked.frames, total)
    if tracked.frames == 0:
        raise PipemapError("no images in the dataset", dataset.root)
    return tracked


def _finish_odometry(tracked: _FramePass, dataset: Dataset, settings: Settings) -> Mount | None:
    """The last keyframes through the odometry, which then finishes; the camera's mount, checked to see the wall."""
    t1 = time.perf_counter()
    odometry = tracked.odometry
    for link in tracked.selector.finish():
        odometry.add(link)
    if not odometry.keyframes:
        odometry.start(tracked.selector.first)
    odometry.finish()
    mount = Mount.from_odometry(odometry, tracked.frames)
    require_wall_view(dataset, settings, mount)
    tracked.t_motion += time.perf_counter() - t1
    return mount


def _write_keyframes_and_wall(tmp: Path, dataset: Dataset, tracked: _FramePass, traj: Trajectory, idx: np.ndarray,
                              wall: UnrolledWall, axis_origin: np.ndarray, axis_dir: np.ndarray, R_first: np.ndarray,
                              C_first: np.ndarray) -> None:
    """trajectory.tum, frames.csv and the unrolled wall with its sidecar (the first keyframe's pose in the pipe
    frame, R_first and C_first, takes the wall's pipe-frame coordinates to the trajectory's world)."""
    write_tum(tmp / "trajectory.tum", traj, header=(
        "pipemap sparse VO (sparse-cylinder): every keyframe's T_wc in metres; world = first keyframe's camera "
        f"frame; pipe axis through {_fmt(axis_origin)} along {_fmt(axis_dir)}"))
    labels = {i: "straight" for i in tracked.read}
    labels.update({i: "repeated" for i in tracked.log.repeated})
    write_frames_csv(tmp / "frames.csv", len(dataset), idx, labels)
    write_wall(tmp / "unrolled", "sparse_000", wall, dataset.radius_m, R_first, C_first, method=SPARSE_METHOD,
               keyframes=len(idx), grey="the mean of the gain-corrected keyframes that see the wall (report section "
               "6.1), stretched to 1..255; 0 = unseen")


def _run_record(dataset: Dataset, settings: Settings, tracked: _FramePass, idx: np.ndarray, C: np.ndarray,
                mount: Mount | None, axis_origin: np.ndarray, axis_dir: np.ndarray, quality: RunVerdict,
                seconds: dict) -> dict:
    """run.json of a sparse run: the common record, then the camera offset and the pipe axis."""
    sp, odometry, n = settings.sparse, tracked.odometry, tracked.frames
    off = odometry.offset
    offset = np.asarray(C[0, :2], float)
    h = C[:, 2]
    problems = []
    if off is not None and not off.determined:
        problems.append(f"the images did not determine the camera's offset from the axis (kept: {off.used}"
                        + _sigma_text(off, sp.offset_max_sigma) + ")")
    return run_record(
        SPARSE_METHOD, dataset, settings, frames=n, keyframes=len(idx), trajectory="keyframes",
        mount=None if mount is None else mount.to_dict(), footage=tracked.log.to_dict(), problems=problems,
        quality=quality.to_dict(), seconds=seconds,
        stage="sparse",
        gain_corrected=bool(sp.gain_correct and dataset.has_gain_mask),
        frames_per_second=n / max(tracked.t_features + tracked.t_motion, 1e-9),
        camera_offset_m={"C_X": float(offset[0]), "C_Y": float(offset[1]),
                         "batch_model": None if off is None else off.model,
                         "batch_estimate": None if off is None else [float(x) for x in off.offset],
                         "batch_sigma_m": None if off is None or off.sigma is None else [float(x) for x in off.sigma],
                         "determined_by_batch": None if off is None else off.determined,
                         "source": "start" if off is None else off.used,
                         "batch_rms_px": None if off is None else off.rms_px,
                         "fit_rms_px": None if off is None else off.fit_rms_px,
                         "batch_observations": None if off is None else off.observations,
                         **_offset_choice(off, sp.offset_max_sigma)},
        pipe_axis={"origin": axis_origin.tolist(), "direction": axis_dir.tolist(),
                   "frame": "first keyframe's camera frame"},
        distance_along_pipe_m=float(h.max() - h.min()),
        keyframes_without_constraints=odometry.unconstrained,
        refinement_dof=odometry.refine_dof(),
    )


def _kept_fraction(off) -> float | None:
    """The kept offset's standard deviation as a fraction of the wall distance (none for eqs. 45-49, which hold
    every keyframe at one rotation, nor for a measured offset)."""
    if off.model != "bundle" or off.used in ("long batch", "given") or not np.isfinite(off.sigma_fraction):
        return None
    return float(off.sigma_fraction)


def _sigma_text(off, limit: float) -> str:
    fraction = _kept_fraction(off)
    return "" if fraction is None else f", sigma {100 * fraction:.2f} % of the wall distance, limit {100 * limit:.2f} %"


def _offset_choice(off, limit: float) -> dict:
    """run.json: how the kept offset was chosen among the batches' estimates."""
    if off is None:
        return {"sigma_fraction": None, "max_sigma_fraction": limit, "estimates": []}
    return {"sigma_fraction": _kept_fraction(off), "max_sigma_fraction": limit,
            "estimates": [e.to_dict() for e in off.estimates],
            "choice": "the bundle estimate with the smallest sigma (first batch or long bundle); eqs. 45-49 (long "
                      "batch) only where that is beyond max_sigma_fraction and they lie within "
                      "sparse.offset_report_max_z of its sigmas (z)"}


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:.6f}" for x in v) + ")"


def _unrolled(dataset: Dataset, camera, radius: float, idx, R, C, sp) -> UnrolledWall:
    return unroll_poses(frame_images(dataset, idx, sp.gain_correct), camera, radius, R, C, sp.unrolled_px_m,
                        sp.unrolled_max_px)
