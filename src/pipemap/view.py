"""Which way the camera looks, and so which method maps it (`pipemap run --method auto`).

A camera whose image holds the pipe's far end — the line of travel falls inside its view — looks
along the pipe: the network pipeline maps it, whatever its lens (a fisheye, a forward-looking
CCTV camera). A camera that sees only the wall beside it — the line of travel lies outside its
view — goes to the 2010 report's straight-pipe methods, which register the wall sliding past.

The line of travel is measured, not assumed: the front end tracks the first frames into keyframes,
and the line common to the epipolar planes of the tracked matches is the direction the camera
moved (`travel_direction`). A lens that sees beyond 90 deg from its axis always holds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.config import Settings
from pipemap.dataset import Dataset
from pipemap.errors import PipemapError
from pipemap.frontend.tracker import make_tracker

ALONG = "along"  # the camera looks along the pipe
WALL = "wall"  # the camera looks at the wall beside it

NETWORK_METHOD = "network"
WALL_METHOD = "dense-hybrid"  # the 2010 report's default for a camera looking at the wall

# A camera looking along the pipe must see the wall within this many radii ahead of it (a colatitude of
# 34 deg at the image's widest): farther off, a keyframe step barely moves the wall in the image and the
# scale the pipe radius gives is lost (a 45 deg camera, widest 27 deg: 3 % of distance; 30 deg: 48 %).
WALL_REACH_RADII = 1.5

# Keyframe steps whose directions are averaged, and the frames searched for them.
VIEW_KEYFRAMES = 6
VIEW_MAX_FRAMES = 300


@dataclass(frozen=True)
class ViewReport:
    looks: str  # ALONG or WALL
    travel_deg: float | None  # angle of the line of travel to the optical axis (None: not measured)
    keyframes: int  # keyframe steps measured
    frames: int  # frames read

    @property
    def method(self) -> str:
        return NETWORK_METHOD if self.looks == ALONG else WALL_METHOD

    def reason(self) -> str:
        if self.travel_deg is None:
            return "the lens sees beyond 90 deg from its axis"
        where = "inside" if self.looks == ALONG else "outside"
        return (f"the line of travel, {self.travel_deg:.0f} deg from the optical axis, lies {where} the image "
                f"(measured over {self.keyframes} keyframe steps)")


def travel_direction(keyframes) -> tuple[np.ndarray, int]:
    """The line of travel in the camera's axes (unit, towards +z where it can) and the keyframe steps
    it came from. Each tracked match spans an epipolar plane (its two bearings); when the camera only
    translates, every such plane holds the line of travel, found as the direction closest to all of
    them. The five-point translation is not used: on the nearly flat wall a wall camera sees, it
    trades translation for rotation (a 75 deg mount measured 49 deg), while the robot's rotation
    between keyframes is a few tenths of a degree."""
    normals, steps = [], 0
    for a, b in zip(keyframes[:-1], keyframes[1:]):
        if not b.pose_valid:
            continue
        rows = np.flatnonzero(b.inliers)
        _, ia, ib = np.intersect1d(a.track_ids, b.track_ids[rows], assume_unique=True, return_indices=True)
        n = np.cross(a.bearings[ia], b.bearings[rows[ib]])
        length = np.linalg.norm(n, axis=1)
        ok = length > 1e-6
        if ok.sum() >= 8:
            normals.append(n[ok] / length[ok, None])
            steps += 1
    if not steps:
        return np.zeros(3), 0
    d = np.linalg.svd(np.concatenate(normals), full_matrices=False)[2][-1]
    return (d if d[2] >= 0 else -d), steps


def check_wall_in_view(dataset: Dataset) -> None:
    """One clear error when the camera, looking along the pipe, sees too little of its wall to map it."""
    widest = dataset.camera.view_colatitudes()[1]
    least = np.arctan(1.0 / WALL_REACH_RADII)
    if widest < least:
        raise PipemapError(
            f"the camera sees too little of the pipe wall to map it: its image reaches {np.degrees(widest):.0f} deg "
            f"from the optical axis, so the nearest wall it sees is {1.0 / np.tan(widest):.1f} pipe radii ahead "
            f"(the network pipeline needs {np.degrees(least):.0f} deg, wall within {WALL_REACH_RADII:g} radii)",
            dataset.yaml_path)


def camera_view(dataset: Dataset, settings: Settings | None = None) -> ViewReport:
    """Whether the dataset's camera looks along the pipe or at its wall (see the module docstring)."""
    settings = settings or Settings()
    camera = dataset.camera
    if camera.view_colatitudes()[1] > np.pi / 2:
        return ViewReport(ALONG, None, 0, 0)
    tracker = make_tracker(camera, settings.frontend, settings.seed)
    keyframes, frames = [], 0
    for frame in dataset.frames(stop=min(len(dataset), VIEW_MAX_FRAMES)):
        keyframes += tracker.process(frame)
        frames += 1
        if sum(k.pose_valid for k in keyframes) >= VIEW_KEYFRAMES:
            break
    keyframes += tracker.finish()
    direction, steps = travel_direction(keyframes)
    if frames == 0:
        raise PipemapError("no frame could be read: every one tried is damaged or not an image (`pipemap info` "
                           "counts the readable ones)", dataset.root)
    if steps == 0:
        raise PipemapError(f"cannot tell which way the camera looks: no camera motion could be tracked in the first "
                           f"{frames} frames; choose a method with --method", dataset.root)
    _, inside = camera.project(direction[None, :])
    travel = float(np.degrees(np.arccos(np.clip(direction[2], -1.0, 1.0))))
    return ViewReport(ALONG if bool(inside[0]) else WALL, travel, steps, frames)


__all__ = ["ViewReport", "camera_view", "check_wall_in_view", "travel_direction", "ALONG", "WALL", "NETWORK_METHOD",
           "WALL_METHOD"]
