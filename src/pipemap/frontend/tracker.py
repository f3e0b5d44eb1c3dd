"""The streaming fisheye front end: frames in, keyframes with tracks and relative poses out.

Every frame is matched against the last keyframe (Harris corners, template descriptors,
five-point RANSAC on bearings). Only when a frame becomes a keyframe does the expensive part
run: descriptor matches are re-located by ZNCC, unmatched keyframe features are searched by
epipolar-guided ZNCC, the pose is refined on all matches, and track ids are carried over.
When a frame cannot be matched (glare, a blank wall), the last frame that could is made the
keyframe and the frame is tried again against it.

All image work runs on the lighting-flattened image (harris.flatten_lighting), still in the
fisheye geometry: the paper's "ZNCC in the original fisheye imagery" means not unwarped.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable, Iterator

import cv2
import numpy as np
from scipy.spatial import cKDTree

from pipemap.camera import CameraModel
from pipemap.config import FrontendSettings
from pipemap.dataset import Frame
from pipemap.frontend.angular import frontend_for, pixel_angle
from pipemap.frontend.anchor import Anchors, anchor_templates, refine_to_anchors
from pipemap.frontend.descriptors import describe, match_descriptors, smooth_for_templates
from pipemap.frontend.flow import local_quadratic_motion
from pipemap.frontend.guided import guided_zncc, predict_positions
from pipemap.frontend.harris import bearing_map, detect_corners, flatten_lighting, log_brightness, valid_mask
from pipemap.frontend.keyframes import needs_keyframe
from pipemap.frontend.relpose import (
    RelativePose,
    continued_motion,
    essential_from_pose,
    estimate_relative_pose,
    refine_pose,
    rotation_fits_motion,
    sampson_angle,
    triangulate_depths,
)
from pipemap.frontend.tracks import Keyframe, TrackIds


# frontend.anchor_lighting -> the brightness terms each anchor patch is compared without
_BRIGHTNESS_TERMS = {"flattened": 1, "plane": 3, "quadratic": 6}


@dataclass
class _Features:
    index: int
    timestamp: float
    image: np.ndarray
    smoothed: np.ndarray
    keypoints: np.ndarray
    bearings: np.ndarray
    descriptors: np.ndarray
    anchors: Anchors | None = None  # keyframes: each track's patch where it was first seen, warp into this one
    anchor_image: np.ndarray | None = None  # the frame as the anchor match sees it (None: `image`)

    @property
    def anchor_view(self) -> np.ndarray:
        return self.image if self.anchor_image is None else self.anchor_image


@dataclass
class _Match:
    """A frame matched against the current keyframe (descriptor inliers only)."""

    frame: _Features
    pose: RelativePose
    kf_idx: np.ndarray
    frame_idx: np.ndarray
    median_flow: float
    tracked_fraction: float


@dataclass
class _Guided:
    """Keyframe features the descriptors did not match, found in the frame by epipolar-guided ZNCC."""

    kf_idx: np.ndarray  # their rows in the keyframe
    keypoints: np.ndarray  # where they are in the frame
    bearings: np.ndarray
    descriptors: np.ndarray

    def take(self, rows) -> "_Guided":
        return _Guided(self.kf_idx[rows], self.keypoints[rows], self.bearings[rows], self.descriptors[rows])


class FeatureTracker:
    """Feed frames in order with `process`; call `finish` at the end. Both return new keyframes."""

    def __init__(self, camera: CameraModel, settings: FrontendSettings | None = None, seed: int = 0,
                 usable: np.ndarray | None = None):
        """`usable`: (H, W) bool, the pixels that show the wall (frontend/usable.py); None: all of the image."""
        self.camera = camera
        self.s = frontend_for(camera, settings or FrontendSettings())
        self.seed = seed
        margin = max(self.s.template_window, self.s.zncc_patch) // 2 + 1
        self.mask = valid_mask(camera, margin)
        self.bearing_map, self.valid = bearing_map(camera)
        if usable is not None:
            self.mask = self.mask & usable.astype(np.uint8)
            self.valid = self.valid & usable  # guided matches land only on the wall
        self.threshold = max(np.radians(self.s.ransac_angle_deg), self.s.ransac_threshold_px * pixel_angle(camera))
        self.ids = TrackIds()
        self.keyframes: list[Keyframe] = []
        self._kf_features: _Features | None = None
        self._candidate: _Match | None = None
        self._lost = 0
        self._reference = 0
        self.refused_poses = 0  # relative poses refused for a rotation their inliers' motion cannot have made
        self.continued_poses = 0  # RANSAC poses replaced by the previous motion continued (continue_motion)
        self.brightness_terms = _BRIGHTNESS_TERMS[self.s.anchor_lighting]
        self._saturated_of: tuple[int | None, np.ndarray | None] = (None, None)  # (frame index, its saturated mask)

    # -- per frame ------------------------------------------------------------------------

    def corners(self, frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frame as matching sees it (blurred as set, lighting flattened), as the anchor match sees it
        (`frontend.anchor_lighting`) and its Harris corners (N, 2)."""
        image, anchor_image, mask = self.corner_views(frame)
        return image, anchor_image, self.detect(image, mask)

    def corner_views(self, frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the frame as matching sees it, as the anchor match sees it, where corners may lie): `corners` less
        the detection, so that the detection can run beside the anchor match."""
        s = self.s
        raw = np.ascontiguousarray(frame.image, dtype=np.float32)
        if s.smooth_sigma_px > 0:
            raw = cv2.GaussianBlur(raw, (0, 0), s.smooth_sigma_px)
        image, mask = raw, self.mask
        saturated = self.saturated(frame)
        if saturated is not None:
            mask = mask & ~saturated
        if s.flatten_lighting:
            image, lit = flatten_lighting(raw, s.lighting_sigma_px, s.dark_level, contrast_limit=s.contrast_limit)
            mask = mask & lit
        anchor_image = image if s.anchor_lighting == "flattened" else log_brightness(raw)
        return image, anchor_image, mask

    def detect(self, image: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Harris corners (N, 2) of a view `corner_views` gave."""
        s = self.s
        return detect_corners(image, mask, tuple(s.regions), s.corners_per_region, s.harris_k, s.harris_block_px,
                              min_distance_px=s.min_distance_px, quality=s.harris_quality)[0]

    def continue_motion(self, R: np.ndarray, t: np.ndarray, inliers: np.ndarray, bearings_i: np.ndarray,
                        bearings_j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(R, t, inliers) of the previous keyframe's motion continued where the pairs cannot tell it from RANSAC's
        pose (relpose.continued_motion), else None."""
        s = self.s
        prev = self.keyframes[-1] if self.keyframes else None
        if (s.continued_motion_share is None or prev is None or not prev.pose_valid
                or np.sum(inliers) > s.continued_motion_max_inliers):
            return None
        found = continued_motion(R, t, inliers, prev.R, prev.t, bearings_i, bearings_j, self.threshold,
                                 s.continued_motion_share, s.continued_motion_apart_deg)
        self.continued_poses += found is not None
        return found

    def rotation_fits(self, R: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray) -> bool:
        """Whether a relative pose's rotation could have moved its inliers as they moved (relpose.rotation_fits_motion;
        always when `frontend.rotation_check_factor` is None)."""
        s = self.s
        if s.rotation_check_factor is None or rotation_fits_motion(R, bearings_i, bearings_j, s.rotation_check_factor,
                                                                   s.rotation_check_slack_deg):
            return True
        self.refused_poses += 1
        return False

    def saturated(self, frame: Frame) -> np.ndarray | None:
        """(H, W) bool: the pixels of `frame` within half a ZNCC patch of a saturated one
        (`frontend.saturation_level`); None when that is off. A keyframe asks twice (corners, followed features)."""
        if self.s.saturation_level is None:
            return None
        if self._saturated_of[0] != frame.index:
            at = (np.asarray(frame.image) >= self.s.saturation_level).astype(np.uint8)
            size = 2 * (self.s.zncc_patch // 2 + 1) + 1
            grown = cv2.dilate(at, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))).astype(bool)
            self._saturated_of = (frame.index, grown)
        return self._saturated_of[1]

    def extract(self, frame: Frame) -> _Features:
        s = self.s
        image, anchor_image, points = self.corners(frame)
        smoothed = smooth_for_templates(image, s.template_size, s.template_window)
        desc, usable = describe(smoothed, points, s.template_size, s.template_window)
        points, desc = points[usable], desc[usable]
        bearings, _ = self.camera.unproject(points)
        return _Features(frame.index, frame.timestamp, image, smoothed, points, bearings.reshape(-1, 3), desc,
                         anchor_image=anchor_image)

    def _match(self, kf: _Features, f: _Features) -> _Match | None:
        s = self.s
        ii, jj, _ = match_descriptors(kf.descriptors, f.descriptors, kf.keypoints, f.keypoints,
                                      s.match_ratio, s.min_similarity, s.max_flow_px)
        if len(ii) < s.min_inliers:
            return None
        rng = np.random.default_rng([self.seed, kf.index, f.index])
        pose = estimate_relative_pose(kf.bearings[ii], f.bearings[jj], self.threshold, s.ransac_confidence, rng,
                                      s.ransac_max_trials, min_inliers=s.min_inliers, refine=False)
        if pose is None:
            return None
        found = self.continue_motion(pose.R, pose.t, pose.inliers, kf.bearings[ii], f.bearings[jj])
        if found is not None:
            R, t, inliers = found
            E = essential_from_pose(R, t)
            pose = RelativePose(E, R, t, inliers, sampson_angle(E, kf.bearings[ii], f.bearings[jj]), pose.trials)
        ii, jj = ii[pose.inliers], jj[pose.inliers]
        if not self.rotation_fits(pose.R, kf.bearings[ii], f.bearings[jj]):
            return None
        flow = float(np.median(np.linalg.norm(f.keypoints[jj] - kf.keypoints[ii], axis=1)))
        # Harris corners recur only partly from frame to frame, and guided features are not corners
        # at all, so "tracked" is measured against the most matches this keyframe has had.
        self._reference = max(self._reference, len(ii))
        return _Match(f, pose, ii, jj, flow, len(ii) / self._reference)

    def process(self, frame: Frame, features: "_Features | None" = None) -> list[Keyframe]:
        """Track one frame; returns the keyframes this frame completed (usually none or one).
        `features`: `extract(frame)` computed beforehand (e.g. on another thread; it reads no
        tracker state that `process` changes)."""
        features = self.extract(frame) if features is None else features
        if self._kf_features is None:
            if len(features.keypoints) < self.s.min_inliers:
                return []
            return [self._start(features)]
        out: list[Keyframe] = []
        match = self._match(self._kf_features, features)
        if match is None and self._candidate is not None:
            out.append(self._promote(self._candidate))
            match = self._match(self._kf_features, features)
        if match is None:
            self._lost += 1
            if self._lost > self.s.max_lost_frames and len(features.keypoints) >= self.s.min_inliers:
                out.append(self._start(features))
            return out
        self._lost = 0
        if needs_keyframe(match.median_flow, match.tracked_fraction, self.s.keyframe_min_flow_px,
                          self.s.keyframe_min_tracked):
            out.append(self._promote(match))
        else:
            self._candidate = match
        return out

    def finish(self) -> list[Keyframe]:
        """Make the last tracked frame a keyframe, so that the keyframes reach the end of the sequence."""
        return [self._promote(self._candidate)] if self._candidate is not None else []

    # -- keyframes ------------------------------------------------------------------------

    def _emit(self, f: _Features, keyframe: Keyframe) -> Keyframe:
        self._kf_features = f
        self._candidate = None
        self._reference = 0
        self.keyframes.append(keyframe)
        return keyframe

    def _start(self, f: _Features) -> Keyframe:
        """A keyframe with no link to the previous one (the first, or after tracking was lost)."""
        n = len(f.keypoints)
        if self.s.anchor_refine:
            f.anchors = anchor_templates(f.anchor_view, f.keypoints, self.s.zncc_patch, self.brightness_terms)
        kf = Keyframe(len(self.keyframes), f.index, f.timestamp, f.keypoints, f.bearings, self.ids.new(n),
                      np.zeros(n, bool), np.zeros(n, bool), np.eye(3), np.zeros(3), False)
        return self._emit(f, kf)

    def _promote(self, m: _Match) -> Keyframe:
        s = self.s
        kf, f = self._kf_features, m.frame
        prev = self.keyframes[-1]
        # The RANSAC pose bounds the epipolar regions well enough; one refinement at the end uses every match.
        R, t, E = m.pose.R, m.pose.t, m.pose.E
        matched_pts, matched_bear = self._relocate_matches(kf, f, m, E)
        guided = self._guided_matches(kf, f, m, matched_pts, R, t, E)
        if s.anchor_refine:
            ok, carried, matched_pts, matched_bear, guided = self._anchor_matches(kf, f, m, matched_pts,
                                                                                  matched_bear, guided)
        # All matches together pin the pose down better than the descriptor matches alone.
        all_i = np.concatenate([kf.bearings[m.kf_idx], kf.bearings[guided.kf_idx]])
        all_j = np.concatenate([matched_bear, guided.bearings])
        R, t = refine_pose(R, t, all_i, all_j, self.threshold)
        # Matches the refined pose (or the anchor match) rejects do not continue their track: a
        # descriptor match's corner starts a new one, a guided match (no corner there) is dropped.
        consistent = sampson_angle(essential_from_pose(R, t), all_i, all_j) < s.track_threshold_factor * self.threshold
        if s.anchor_refine:  # a track that no longer matches its first patch has drifted off its point
            consistent &= ok
        n_desc = len(m.kf_idx)
        d_ok, g_ok = consistent[:n_desc], consistent[n_desc:]
        kf_idx, frame_idx = m.kf_idx[d_ok], m.frame_idx[d_ok]
        matched_pts, matched_bear = matched_pts[d_ok], matched_bear[d_ok]
        guided = guided.take(g_ok)
        kept = carried.take(np.concatenate([d_ok, g_ok])) if s.anchor_refine else None
        return self._emit_continued(f, prev, R, t, kf_idx, frame_idx, matched_pts, matched_bear, guided, kept)

    def _relocate_matches(self, kf: _Features, f: _Features, m: _Match, E: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
        """The frame's keypoints and bearings of the descriptor matches, re-located by ZNCC when
        `refine_matches_px` says so."""
        s = self.s
        matched_pts, matched_bear = f.keypoints[m.frame_idx], f.bearings[m.frame_idx]
        if s.refine_matches_px > 0:
            # Two independent corner detections disagree by ~0.5 px; correlating the keyframe's
            # template around each match halves that (the guided matches are found the same way).
            ok, pos, _ = guided_zncc(kf.image, f.image, kf.keypoints[m.kf_idx], kf.bearings[m.kf_idx], matched_pts, E,
                                     self.bearing_map, self.valid, s.zncc_patch, s.refine_matches_px,
                                     s.epipolar_threshold, s.zncc_min)
            if ok.any():
                matched_pts = np.where(ok[:, None], pos, matched_pts)
                bear, _ = self.camera.unproject(pos[ok])
                matched_bear = matched_bear.copy()
                matched_bear[ok] = bear
        return matched_pts, matched_bear

    def _guided_matches(self, kf: _Features, f: _Features, m: _Match, matched_pts: np.ndarray, R: np.ndarray,
                        t: np.ndarray, E: np.ndarray) -> _Guided:
        """Guided ZNCC for the keyframe features the descriptors did not match: each searched near where its
        matched neighbours moved, kept in front of both cameras and where a descriptor can be taken."""
        s = self.s
        unmatched = np.setdiff1d(np.arange(len(kf.keypoints)), m.kf_idx)
        predicted = predict_positions(kf.keypoints[unmatched], kf.keypoints[m.kf_idx], matched_pts,
                                      s.guided_neighbours)
        found, pos, _ = guided_zncc(kf.image, f.image, kf.keypoints[unmatched], kf.bearings[unmatched], predicted, E,
                                    self.bearing_map, self.valid, s.zncc_patch, s.guided_search_px,
                                    s.epipolar_threshold, s.zncc_min)
        g_kf, g_pos = unmatched[found], pos[found]
        g_bear, g_ok = self.camera.unproject(g_pos)
        g_bear = g_bear.reshape(-1, 3)
        lam_i, lam_j = triangulate_depths(R, t, kf.bearings[g_kf], g_bear)
        keep = g_ok.reshape(-1) & (lam_i > 0) & (lam_j > 0)
        g_kf, g_pos, g_bear = g_kf[keep], g_pos[keep], g_bear[keep]
        g_desc, usable = describe(f.smoothed, g_pos, s.template_size, s.template_window)
        return _Guided(g_kf, g_pos, g_bear, g_desc).take(usable)

    def _anchor_matches(self, kf: _Features, f: _Features, m: _Match, matched_pts: np.ndarray,
                        matched_bear: np.ndarray, guided: _Guided):
        """Every match, descriptor and guided, re-located against its track's first patch:
        (matched by the anchor, the anchors carried into the frame, matched_pts, matched_bear, guided)."""
        s = self.s
        rows = np.concatenate([m.kf_idx, guided.kf_idx])
        anchors = kf.anchors.take(rows)
        found = np.concatenate([matched_pts, guided.keypoints])
        if s.anchor_bend_neighbours:
            src = kf.keypoints[rows]
            step_J, step_H, _ = local_quadratic_motion(src, found, src, s.anchor_bend_neighbours)
            anchors = anchors.carry(step_J, step_H)
        ok, pos, carried = refine_to_anchors(f.anchor_view, anchors, found, s.zncc_patch,
                                             s.anchor_iterations, s.anchor_max_shift_px, s.anchor_min_zncc,
                                             s.anchor_max_stretch, self.brightness_terms)
        if ok.any():
            bear = np.concatenate([matched_bear, guided.bearings])
            new_bear, _ = self.camera.unproject(pos[ok])
            bear[ok] = new_bear.reshape(-1, 3)
            n_desc = len(m.kf_idx)
            matched_pts, matched_bear = pos[:n_desc], bear[:n_desc]
            guided = replace(guided, keypoints=pos[n_desc:], bearings=bear[n_desc:])
        return ok, carried, matched_pts, matched_bear, guided

    def _emit_continued(self, f: _Features, prev: Keyframe, R: np.ndarray, t: np.ndarray, kf_idx: np.ndarray,
                        frame_idx: np.ndarray, matched_pts: np.ndarray, matched_bear: np.ndarray, guided: _Guided,
                        kept: Anchors | None) -> Keyframe:
        """The frame as the next keyframe, continuing `prev`'s tracks. `kept`: the anchors of the matches kept,
        descriptor ones then guided (None without anchor refinement)."""
        s = self.s
        # Harris corners of the frame: matched ones first, then unmatched ones not duplicating a guided match.
        rest = np.setdiff1d(np.arange(len(f.keypoints)), frame_idx)
        if len(guided.keypoints) and len(rest) and s.duplicate_px > 0:
            d, _ = cKDTree(guided.keypoints).query(f.keypoints[rest], k=1)
            rest = rest[d > s.duplicate_px]
        keypoints = np.concatenate([matched_pts, f.keypoints[rest], guided.keypoints])
        bearings = np.concatenate([matched_bear, f.bearings[rest], guided.bearings])
        descriptors = np.concatenate([f.descriptors[frame_idx], f.descriptors[rest], guided.descriptors])
        n_desc, n_rest = len(frame_idx), len(rest)
        track_ids = np.concatenate([prev.track_ids[kf_idx], self.ids.new(n_rest), prev.track_ids[guided.kf_idx]])
        inliers = np.ones(len(keypoints), bool)
        inliers[n_desc:n_desc + n_rest] = False
        is_guided = np.zeros(len(keypoints), bool)
        is_guided[n_desc + n_rest:] = True
        anchors = None
        if kept is not None:  # in the order of the keypoints: continued descriptor matches, new corners, guided
            anchors = Anchors.concatenate([kept.take(slice(0, n_desc)),
                                           anchor_templates(f.anchor_view, f.keypoints[rest], s.zncc_patch,
                                                            self.brightness_terms),
                                           kept.take(slice(n_desc, None))])
        features = _Features(f.index, f.timestamp, f.image, f.smoothed, keypoints, bearings, descriptors, anchors,
                             f.anchor_image)
        keyframe = Keyframe(len(self.keyframes), f.index, f.timestamp, keypoints, bearings, track_ids, inliers,
                            is_guided, R, t, True)
        return self._emit(features, keyframe)


def make_tracker(camera: CameraModel, settings: FrontendSettings | None = None, seed: int = 0,
                 usable: np.ndarray | None = None) -> FeatureTracker:
    """The tracker `settings.tracking` names: flow (flow_tracker.py) or descriptors (this module's)."""
    settings = settings or FrontendSettings()
    if settings.tracking == "flow":
        from pipemap.frontend.flow_tracker import FlowTracker  # it builds on this module's FeatureTracker

        return FlowTracker(camera, settings, seed, usable)
    return FeatureTracker(camera, settings, seed, usable)


def track_frames(frames: Iterable[Frame], camera: CameraModel, settings: FrontendSettings | None = None,
                 seed: int = 0) -> Iterator[Keyframe]:
    """Stream keyframes from a stream of frames."""
    ft = make_tracker(camera, settings, seed)
    for frame in frames:
        yield from ft.process(frame)
    yield from ft.finish()


@dataclass
class TrackingResult:
    keyframes: list[Keyframe]
    image_count: int
    seconds: float

    @property
    def frames_per_second(self) -> float:
        return self.image_count / max(self.seconds, 1e-9)


def run_tracking(dataset_path, out_dir, settings=None, progress=None) -> TrackingResult:
    """Track a dataset and write frames.csv, trajectory.tum, tracks.csv and run.json into `out_dir`.

    `settings` is a config.Settings (its `seed` and `frontend` sections are used). The folder is
    written atomically. `progress(done, total, keyframes)` is called after every frame.
    """
    import json
    import time
    from pathlib import Path

    from pipemap import __version__
    from pipemap.config import Settings
    from pipemap.dataset import load_dataset
    from pipemap.frontend.keyframes import chain_poses
    from pipemap.frontend.tracks_io import write_frames_csv, write_tracks_csv
    from pipemap.output import result_folder
    from pipemap.trajectory import write_tum

    settings = settings or Settings()
    dataset = load_dataset(dataset_path)
    total = len(dataset)
    with result_folder(Path(out_dir)) as tmp:
        ft = make_tracker(dataset.camera, settings.frontend, settings.seed)
        start = time.perf_counter()
        done = 0
        for frame in dataset.frames():
            ft.process(frame)
            done += 1
            if progress is not None:
                progress(done, total, len(ft.keyframes))
        ft.finish()
        seconds = time.perf_counter() - start
        keyframes = ft.keyframes
        write_frames_csv(tmp / "frames.csv", done, [k.index for k in keyframes])
        write_tum(tmp / "trajectory.tum", chain_poses(keyframes),
                  header="pipemap front end: keyframe poses chained from relative poses, one unit per keyframe step")
        write_tracks_csv(tmp / "tracks.csv", keyframes)
        run = {
            "version": __version__,
            "stage": "track",
            "input": str(dataset.root),
            "settings": settings.recorded(),
            "frames": done,
            "keyframes": len(keyframes),
            "lost_keyframes": sum(1 for k in keyframes[1:] if not k.pose_valid),
            "seconds": round(seconds, 3),
            "frames_per_second": round(done / max(seconds, 1e-9), 2),
        }
        (tmp / "run.json").write_text(json.dumps(run, indent=2) + "\n")
    return TrackingResult(keyframes, done, seconds)
