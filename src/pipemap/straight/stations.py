"""The camera's offset from the pipe axis along the run, for the dense methods' scale.

The dense methods turn image shifts into metres with zeta = f / (distance to the wall), and the report takes
that distance as constant. A crawler's camera rides up and down and sideways by millimetres as the robot rolls
over the invert (0.6 mm is 0.25 % of the distance in a 388 mm pipe), so one estimate at the start of the run
scales the whole run by where the robot happened to sit there. Here the sparse method's bundle batch is run
again at stations every `dense.offset_station_m` of registered travel, each over its first
`sparse.offset_batch_keyframes` keyframes only (a few frames: the batch alone, no long batch), and the offset
(C_X, C_Y) between stations is interpolated in frame index, so that every pair is scaled by the wall distance
of its own part of the run. A station whose images do not fix the offset (a wall too little seen), whose pipe
axis is turned from the run's mount by more than the robot wobbles (a batch over the few frames of a
turnaround, where the robot hardly moves, found the axis 36 deg off), or whose offset is far from all the
others' is left out and listed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from pipemap.config import Settings
from pipemap.dataset import Dataset
from pipemap.errors import PipemapError
from pipemap.straight.mount import Mount, estimate_mount


@dataclass(frozen=True)
class OffsetTrack:
    """(C_X, C_Y) at each station's frame (the mean index of its keyframes), interpolated between them."""

    frames: np.ndarray  # (S,) increasing frame indices
    offsets: np.ndarray  # (S, 2) C_X, C_Y in metres
    sigmas: np.ndarray  # (S,) standard deviation of C_Y in metres (nan where unknown)
    spans: np.ndarray  # (S, 2) first and last keyframe (frame index) of each station's batch
    axes: np.ndarray  # (S, 3) the pipe axis in camera axes, the run's sense
    skipped: tuple[tuple[int, str], ...] = ()  # (start frame, why) of the stations left out
    seconds: float = 0.0

    def at(self, frames) -> np.ndarray:
        """(N, 2) C_X, C_Y at frame indices `frames`: piecewise linear between stations, held beyond the ends."""
        f = np.asarray(frames, float)
        return np.column_stack([np.interp(f, self.frames, self.offsets[:, i]) for i in range(2)])

    def to_dict(self) -> dict:
        return {
            "stations": [{"frame": float(f), "keyframes": [int(a), int(b)], "C_X_m": float(o[0]), "C_Y_m": float(o[1]),
                          "C_Y_sigma_m": float(s) if np.isfinite(s) else None}
                         for f, (a, b), o, s in zip(self.frames, self.spans, self.offsets, self.sigmas)],
            "skipped": [{"start_frame": int(k), "why": why} for k, why in self.skipped],
            "seconds": self.seconds,
            "note": "the camera's offset from the pipe axis measured at stations along the run (the sparse bundle "
                    "batch over a few keyframes from each station's frame) and interpolated between them: each "
                    "registered pair is scaled by the wall distance of its own part of the run",
        }


def _span(mount: Mount) -> tuple[int, int]:
    return int(mount.keyframes[0]), int(mount.keyframes[-1])


def _c_y_sigma(mount: Mount) -> float:
    return float(mount.sigma[3]) if mount.sigma is not None and np.isfinite(mount.sigma[3]) else float("nan")


def station_starts(indices: np.ndarray, along_m: np.ndarray, every_m: float) -> list[int]:
    """Frame indices where the registered travel (forward and back both count) passes each multiple of
    `every_m`, the first frame excluded (the run's mount is its station)."""
    travel = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(np.asarray(along_m, float))))])
    if every_m <= 0 or len(travel) < 2:
        return []
    marks = np.arange(every_m, travel[-1], every_m)
    at = np.searchsorted(travel, marks)
    return sorted({int(indices[k]) for k in at if 0 < k < len(indices)})


def offset_track(dataset: Dataset, settings: Settings, gain_correct: bool, first: Mount,
                 starts: list[int]) -> OffsetTrack:
    """The offset at `first` (the run's mount) and at a short batch from each of `starts`."""
    t0 = time.perf_counter()
    short = settings.model_copy(deep=True)
    short.sparse.offset_long_keyframes = short.sparse.offset_batch_keyframes  # the batch alone
    frames = [float(np.mean(first.keyframes))]
    offsets = [np.asarray(first.offset_m, float)]
    sigmas = [_c_y_sigma(first)]
    spans = [_span(first)]
    axes = [np.asarray(first.rotation[2], float)]
    skipped: list[tuple[int, str]] = []
    for start in starts:
        try:
            mount = estimate_mount(dataset, short, gain_correct, start=start)
        except PipemapError as exc:
            skipped.append((start, str(exc).split(":")[0]))
            continue
        if not mount.determined:
            skipped.append((start, "the images there do not fix the offset"))
            continue
        tilt = np.degrees(np.arccos(min(1.0, abs(float(mount.rotation[2] @ first.rotation[2])))))
        if tilt > settings.dense.offset_station_max_tilt_deg:  # too little travel there to find the axis
            skipped.append((start, f"its pipe axis is {tilt:.1f} deg from the run's mount"))
            continue
        off = np.asarray(mount.offset_m, float).copy()  # Y is where the camera looks, at every station
        axis = np.asarray(mount.rotation[2], float)
        if axis @ first.rotation[2] < 0:  # that batch took the pipe axis the other way round
            off[0], axis = -off[0], -axis
        frames.append(float(np.mean(mount.keyframes)))
        offsets.append(off)
        sigmas.append(_c_y_sigma(mount))
        spans.append(_span(mount))
        axes.append(axis)
    keep = consistent(np.array(offsets), sigmas)
    for k in np.flatnonzero(~keep):
        skipped.append((spans[k][0], f"an outlier: C_X {offsets[k][0] * 1e3:.2f} mm, C_Y {offsets[k][1] * 1e3:.2f} mm "
                                     "against the other stations'"))
    order = [k for k in np.argsort(frames, kind="stable") if keep[k]]
    return OffsetTrack(np.array(frames)[order], np.array(offsets)[order], np.array(sigmas)[order],
                       np.array(spans, int)[order], np.array(axes)[order], tuple(sorted(skipped)),
                       time.perf_counter() - t0)


def consistent(offsets: np.ndarray, sigmas: list[float], k: float = 5.0) -> np.ndarray:
    """The stations within k robust standard deviations (1.4826 MAD, at least each station's own sigma) of the
    median in both C_X and C_Y: a short batch can settle on a wrong offset (10 mm off, seen once in 120
    stations), which would scale its part of the run by 4 %. The run's own mount (the first) is always kept."""
    if len(offsets) < 4:
        return np.ones(len(offsets), bool)
    dev = np.abs(offsets - np.median(offsets, axis=0))
    spread = 1.4826 * np.median(dev, axis=0)
    own = np.nan_to_num(np.asarray(sigmas, float), nan=0.0)[:, None]
    keep = np.all(dev <= k * np.maximum(spread[None, :], own), axis=1)
    keep[0] = True
    return keep
