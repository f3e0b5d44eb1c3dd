"""The fisheye front end with image flow between keyframes (`frontend.tracking: flow`).

The descriptor tracker (tracker.py) detects, describes and matches corners in every frame, though
most frames only tell it that no keyframe is due yet. Here a frame costs one pyramidal
Lucas-Kanade step: the keyframe's features are followed from the last frame into this one, and
their median flow since the keyframe and the share still followed make the keyframe rule. Only the
frame that becomes a keyframe gets the rest: its lighting flattened, every followed feature
re-located against its track's first patch (the anchor match, which also takes out what the steps
from frame to frame added up), five-point RANSAC on those, the pose refined on all inliers, and
Harris corners where no track continues. The flow follows every keyframe feature, so the
descriptor matches, their ZNCC re-location and the guided search for the features the descriptors
missed are not needed.

Lucas-Kanade runs on the grey image less its local mean (`lighting_sigma_px`), from frame to frame:
the robot's light, fixed in the image, holds features back on the raw image, and the fisheye
stretches a patch too much for one step from the keyframe. On paper-loop at 640x480, 4 frames and
15 px of flow on from a keyframe, RANSAC kept 77 of 800 features followed on the raw image from the
keyframe at once, 491 on the high-passed image, 660 followed frame to frame. A camera finer than
the reference density is followed on its image shrunk by a power of two towards that density, so
that a frame costs the same at any size; the anchor match works at full resolution.

Lucas-Kanade reports features found even in a blank or saturated frame; a sample of them followed
back shows it (they do not come back), and the frame is then not followed. The frame after a bad
one is followed from the keyframe itself.
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
from scipy.spatial import cKDTree

from pipemap.camera import CameraModel
from pipemap.config import FrontendSettings
from pipemap.dataset import Frame
from pipemap.frontend.angular import pixel_scale
from pipemap.frontend.anchor import Anchors, anchor_templates, refine_to_anchors
from pipemap.frontend.flow import local_quadratic_motion
from pipemap.frontend.guided import predict_positions
from pipemap.frontend.keyframes import needs_keyframe
from pipemap.frontend.relpose import essential_from_pose, estimate_relative_pose, refine_pose, sampson_angle
from pipemap.frontend.tracker import FeatureTracker, _Features
from pipemap.frontend.tracks import Keyframe

_LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.03)
# A frame is followed when this many of its features, followed back, land within _BACK_MAX_PX (median) of where
# they came from.
_BACK_SAMPLE = 64
_BACK_MAX_PX = 1.0


@dataclass
class FlowFrame:
    """A frame as Lucas-Kanade takes it: 8-bit grey less its local mean, at about the reference density."""

    frame: Frame
    grey: np.ndarray

    @property
    def index(self) -> int:
        return self.frame.index


@dataclass
class _Followed:
    """The keyframe's features followed into a frame: their rows in the keyframe and positions there."""

    data: FlowFrame
    rows: np.ndarray
    positions: np.ndarray  # (n, 2) float32
    velocities: np.ndarray  # (n, 2) px/s, from the frame they were followed from
    median_flow: float
    tracked_fraction: float


def consistent_with_pose(R: np.ndarray, t: np.ndarray, kf_bearings: np.ndarray, bearings: np.ndarray,
                         limit: float) -> np.ndarray:
    """Which followed features are consistent with the pose refined on RANSAC's inliers: within `limit` (radians,
    Sampson). With `frontend.continue_on_refined_pose` they continue their tracks, as with descriptors; by default
    only those RANSAC's own pose counted as well (README, "Inspection footage": on H.264 the refined pose keeps
    more tracks and the tee loop's turns improve, but clean route A's lap and the junction networks lose)."""
    return sampson_angle(essential_from_pose(R, t), kf_bearings, bearings) < limit


class FlowTracker(FeatureTracker):
    """`process` and `finish` as FeatureTracker's; `extract` only readies the frame for Lucas-Kanade."""

    def __init__(self, camera: CameraModel, settings: FrontendSettings | None = None, seed: int = 0,
                 usable: np.ndarray | None = None):
        super().__init__(camera, settings, seed, usable)
        given = settings or FrontendSettings()
        self._shrink = 2 ** max(0, int(round(np.log2(pixel_scale(camera, given.reference_px_per_deg)))))
        self._kf_data: FlowFrame | None = None  # the keyframe's own frame
        self._last: FlowFrame | None = None  # the last frame the features were followed into
        self._rows = np.zeros(0, np.intp)  # keyframe rows still followed
        self._positions = np.zeros((0, 2), np.float32)  # and where they are in self._last
        self._velocities = np.zeros((0, 2))  # and how fast they moved there (px/s)
        # Runs a keyframe's corner detection beside its anchor match (a thread pool's submit); None: in turn.
        # Either way the same corners.
        self.beside: Callable[..., Future] | None = None

    def extract(self, frame: Frame) -> FlowFrame:
        s = self.s
        image = np.ascontiguousarray(frame.image, np.float32)
        if s.smooth_sigma_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), s.smooth_sigma_px)
        if self._shrink > 1:
            h, w = image.shape
            image = cv2.resize(image, (w // self._shrink, h // self._shrink), interpolation=cv2.INTER_AREA)
        detail = image - cv2.GaussianBlur(image, (0, 0), s.lighting_sigma_px / self._shrink)
        return FlowFrame(frame, cv2.convertScaleAbs(detail, alpha=2.0, beta=128.0))  # uint8, as cv2's LK takes

    # -- per frame ------------------------------------------------------------------------

    def process(self, frame: Frame, features: FlowFrame | None = None) -> list[Keyframe]:
        data = self.extract(frame) if features is None else features
        if self._kf_features is None:
            started = self._start_flow(data)
            return [] if started is None else [started]
        out: list[Keyframe] = []
        for attempt in range(2):
            followed = self._follow(data)
            if followed is not None:
                if not needs_keyframe(followed.median_flow, followed.tracked_fraction, self.s.keyframe_min_flow_px,
                                      self.s.keyframe_min_tracked):
                    self._last, self._rows = data, followed.rows
                    self._positions, self._velocities = followed.positions, followed.velocities
                    self._candidate = followed
                    self._lost = 0
                    return out
                keyframe = self._promote_flow(followed)
                if keyframe is not None:
                    self._lost = 0
                    return out + [keyframe]
            # Not followed or not posed from the keyframe: the last frame that was becomes the keyframe, once.
            if attempt == 0 and self._candidate is not None:
                candidate, self._candidate = self._candidate, None
                keyframe = self._promote_flow(candidate)
                if keyframe is not None:
                    out.append(keyframe)
                    continue
            break
        self._lost += 1
        if self._lost > self.s.max_lost_frames:
            started = self._start_flow(data)
            if started is not None:
                out.append(started)
        return out

    def finish(self) -> list[Keyframe]:
        if self._candidate is None:
            return []
        keyframe = self._promote_flow(self._candidate)
        return [] if keyframe is None else [keyframe]

    def _follow(self, data: FlowFrame) -> _Followed | None:
        """The features followed into `data` from the last frame, searched where their speed takes them or else
        where they were (the robot stopped or turned back), or else from the keyframe; None when fewer than
        min_inliers are."""
        at_rest = np.zeros_like(self._velocities)
        tries = [(self._last, self._rows, self._positions, self._velocities),
                 (self._last, self._rows, self._positions, at_rest)]
        if self._last is not self._kf_data:  # the last frame may have been the bad one
            kf = self._kf_features
            tries.append((self._kf_data, np.arange(len(kf.keypoints)), kf.keypoints, np.zeros((len(kf.keypoints), 2))))
        for last, rows, positions, velocities in tries:
            followed = self._follow_from(last, rows, positions, velocities, data)
            if followed is not None:
                return followed
        return None

    def _follow_from(self, last: FlowFrame, rows: np.ndarray, positions: np.ndarray, velocities: np.ndarray,
                     data: FlowFrame) -> _Followed | None:
        """The features `rows` at `positions` in `last`, moving at `velocities`, followed into `data`: those left
        on the usable image where their patches fit. None when fewer than min_inliers are, or when a sample of them
        followed back does not come back (a blank, saturated or torn frame, on which Lucas-Kanade still reports
        every feature found)."""
        s = self.s
        if len(rows) < s.min_inliers:
            return None
        dt = data.frame.timestamp - last.frame.timestamp
        f = self._shrink
        # a pixel of the shrunk image is the mean of f x f, centred (f - 1) / 2 into them
        start = ((np.asarray(positions, np.float32) - (f - 1) / 2) / f).reshape(-1, 1, 2)
        # Each feature is searched where it would be had it kept its speed: after a stall or a dropped frame the
        # image has moved on several frames' worth, beyond what Lucas-Kanade finds from where it was.
        ahead = (velocities * (dt / f)).astype(np.float32).reshape(-1, 1, 2)
        found, status = self._lucas_kanade(last, data, start, start + ahead)
        sample = slice(None, None, max(1, len(start) // _BACK_SAMPLE))
        back, back_ok = self._lucas_kanade(data, last, np.ascontiguousarray(found[sample]),
                                           np.ascontiguousarray(found[sample] - ahead[sample]))
        back_error = np.linalg.norm(back - start[sample], axis=2).ravel()[back_ok & status[sample]]
        if not len(back_error) or np.median(back_error) > _BACK_MAX_PX:
            return None
        moved = (found - start).reshape(-1, 2) * (f / max(dt, 1e-6))
        found = (found.reshape(-1, 2) * f + (f - 1) / 2).astype(np.float32)
        ok = status & np.all(np.isfinite(found), axis=1)
        ui = np.round(np.where(ok, found[:, 0], 0)).astype(int).clip(0, self.mask.shape[1] - 1)
        vi = np.round(np.where(ok, found[:, 1], 0)).astype(int).clip(0, self.mask.shape[0] - 1)
        ok &= self.mask[vi, ui] > 0
        rows, found = rows[ok], found[ok]
        if len(rows) < s.min_inliers:
            return None
        flow = float(np.median(np.linalg.norm(found - self._kf_features.keypoints[rows], axis=1)))
        self._reference = max(self._reference, len(rows))
        return _Followed(data, rows, found, moved[ok], flow, len(rows) / self._reference)

    def _lucas_kanade(self, a: FlowFrame, b: FlowFrame, points: np.ndarray,
                      guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (n, 1, 2) of a's shrunk image found in b's, searched from `guess` (n, 1, 2):
        (positions (n, 1, 2), found (n,))."""
        s = self.s
        found, status, _ = cv2.calcOpticalFlowPyrLK(a.grey, b.grey, points, guess.copy(),
                                                    winSize=(s.flow_window_px, s.flow_window_px),
                                                    maxLevel=s.flow_levels, criteria=_LK_CRITERIA,
                                                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        return found, status.reshape(-1).astype(bool)

    # -- keyframes ------------------------------------------------------------------------

    def _keyframe_corners(self, frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the frame as the anchor match sees it, Harris corners, their bearings) of a frame that becomes a
        keyframe."""
        image, found = self._keyframe_corners_beside(frame)
        return (image,) + found.result()

    def _keyframe_corners_beside(self, frame: Frame) -> tuple[np.ndarray, Future]:
        """(the frame as the anchor match sees it, the future (Harris corners, their bearings)), the corners
        found beside the caller where `beside` is given."""
        view, image, mask = self.corner_views(frame)
        if self.beside is not None:
            return image, self.beside(self._corner_bearings, view, mask)
        done: Future = Future()
        done.set_result(self._corner_bearings(view, mask))
        return image, done

    def _corner_bearings(self, view: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        points = self.detect(view, mask)
        bearings, _ = self.camera.unproject(points)
        return points, bearings.reshape(-1, 3)

    def _start_flow(self, data: FlowFrame) -> Keyframe | None:
        image, points, bearings = self._keyframe_corners(data.frame)
        if len(points) < self.s.min_inliers:
            return None
        keyframe = self._start(_Features(data.index, data.frame.timestamp, image, None, points, bearings, None))
        self._restart(data, keyframe)
        return keyframe

    def _restart(self, data: FlowFrame, keyframe: Keyframe, velocities: np.ndarray | None = None) -> None:
        """Frames from here on are followed from the new keyframe, its features moving at `velocities` (px/s;
        None: at rest)."""
        n = len(keyframe.keypoints)
        self._kf_data = self._last = data
        self._rows = np.arange(n)
        self._positions = np.asarray(keyframe.keypoints, np.float32)
        self._velocities = np.zeros((n, 2)) if velocities is None else velocities

    def _promote_flow(self, m: _Followed) -> Keyframe | None:
        """The followed frame as the next keyframe; None when its pose cannot be found."""
        s = self.s
        kf = self._kf_features
        image, detected = self._keyframe_corners_beside(m.data.frame)
        rows, positions, velocities = m.rows, m.positions, m.velocities
        carried = None
        if s.anchor_refine:  # the anchor match first: RANSAC then sees each feature where its first patch is
            ok, positions, carried = self._anchor_flow(kf, image, rows, positions)
            saturated = self.saturated(m.data.frame)
            if saturated is not None:
                at = np.clip(np.round(positions).astype(int), 0, [saturated.shape[1] - 1, saturated.shape[0] - 1])
                ok &= ~saturated[at[:, 1], at[:, 0]]
            rows, positions, velocities, carried = rows[ok], positions[ok], velocities[ok], carried.take(ok)
        bearings, _ = self.camera.unproject(positions)
        bearings = bearings.reshape(-1, 3)
        rng = np.random.default_rng([self.seed, kf.index, m.data.index])
        pose = estimate_relative_pose(kf.bearings[rows], bearings, self.threshold, s.ransac_confidence, rng,
                                      s.ransac_max_trials, min_inliers=s.min_inliers, refine=False)
        if pose is None:
            return None
        R, t = refine_pose(pose.R, pose.t, kf.bearings[rows][pose.inliers], bearings[pose.inliers], self.threshold)
        inliers = pose.inliers
        found = self.continue_motion(R, t, inliers, kf.bearings[rows], bearings)
        if found is not None:
            R, t, inliers = found
        if not self.rotation_fits(R, kf.bearings[rows][inliers], bearings[inliers]):
            return None
        consistent = consistent_with_pose(R, t, kf.bearings[rows], bearings, s.track_threshold_factor * self.threshold)
        if not s.continue_on_refined_pose:
            consistent &= inliers
        rows, positions, bearings = rows[consistent], positions[consistent], bearings[consistent]
        velocities = velocities[consistent]
        # Corners of the frame where no track continues start new ones.
        corners, corner_bearings = detected.result()
        if len(positions) and len(corners) and s.duplicate_px > 0:
            d, _ = cKDTree(positions).query(corners, k=1)
            fresh = d > s.duplicate_px
            corners, corner_bearings = corners[fresh], corner_bearings[fresh]
        prev = self.keyframes[-1]
        keypoints = np.concatenate([positions, corners])
        all_bearings = np.concatenate([bearings, corner_bearings])
        n_new = len(corners)
        track_ids = np.concatenate([prev.track_ids[rows], self.ids.new(n_new)])
        inliers = np.r_[np.ones(len(rows), bool), np.zeros(n_new, bool)]
        anchors = None
        if carried is not None:
            anchors = Anchors.concatenate([carried.take(consistent),
                                           anchor_templates(image, corners, s.zncc_patch, self.brightness_terms)])
        frame = m.data.frame
        features = _Features(frame.index, frame.timestamp, image, None, keypoints, all_bearings, None, anchors)
        keyframe = Keyframe(len(self.keyframes), frame.index, frame.timestamp, keypoints, all_bearings, track_ids,
                            inliers, np.zeros(len(keypoints), bool), R, t, True)
        self._emit(features, keyframe)
        # new corners move as the continued tracks nearest them do
        self._restart(m.data, keyframe, np.concatenate([velocities, predict_positions(
            corners, positions, positions + velocities, s.guided_neighbours) - corners]))
        return keyframe

    def _anchor_flow(self, kf: _Features, image: np.ndarray, rows: np.ndarray, positions: np.ndarray):
        """The followed features re-located against their tracks' first patches:
        (matched by the anchor, positions, the anchors carried into the frame)."""
        s = self.s
        anchors = kf.anchors.take(rows)
        if s.anchor_bend_neighbours:
            src = kf.keypoints[rows]
            step_J, step_H, _ = local_quadratic_motion(src, positions, src, s.anchor_bend_neighbours)
            anchors = anchors.carry(step_J, step_H)
        return refine_to_anchors(image, anchors, positions, s.zncc_patch, s.anchor_iterations,
                                 s.anchor_max_shift_px, s.anchor_min_zncc, s.anchor_max_stretch,
                                 self.brightness_terms)
