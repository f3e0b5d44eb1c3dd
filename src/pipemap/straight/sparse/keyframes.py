"""Keyframe selection and outlier removal (2010 report section 5.1).

Starting with keyframe I_k, every following image I_n is matched with I_k. When the matches fall
below `keyframe_min_matches` or their median flow exceeds `keyframe_max_flow_px`, I_{n-1} becomes
the next keyframe with its matches to I_k, and the search starts again from I_{n-1}. When even
I_{k+1} fails, I_{k+1} itself is taken (the robot moved too far between two images to do better).
The matches of each keyframe pair are cleaned by five-point RANSAC on bearings (seeded).

Each inlier is then placed in the new keyframe by registering the patch around it in the previous keyframe
(affine Lucas-Kanade, frontend/anchor.py), so that a track follows one wall point from keyframe to keyframe.
Harris peaks found afresh in every image do not: where the camera sees the wall obliquely its
foreshortening changes as a corner crosses the image, and the peak moves along the motion with it
(against the simulator's truth at a 50 deg mount: +0.16 % of the image motion at 40-50 deg from the wall's
normal, +1 % at 55-60; registered, +0.02 % and +0.05 %, and 0.15 px RMS instead of 0.5 px).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from pipemap.camera import CameraModel
from pipemap.config import SparseSettings
from pipemap.frontend.anchor import anchor_templates, refine_to_anchors
from pipemap.frontend.relpose import estimate_relative_pose
from pipemap.straight.sparse.features import Keypoints, detect, flatten_light, match


@dataclass(frozen=True)
class View:
    """One image's keypoints and their bearings."""

    index: int
    keypoints: Keypoints
    bearings: np.ndarray
    valid: np.ndarray
    image: np.ndarray | None = None  # float32, as the keypoints were found in it (light flattened or not)


@dataclass(frozen=True)
class KeyframeLink:
    """A new keyframe `current` and its RANSAC-inlier matches (M, 2) with the previous keyframe."""

    previous: View
    current: View
    pairs: np.ndarray
    candidates: int  # matches before RANSAC


def inlier_pairs(previous: View, current: View, pairs: np.ndarray, threshold_rad: float,
                 rng: np.random.Generator, min_inliers: int) -> np.ndarray:
    """The pairs that five-point RANSAC on bearings keeps; none when it finds no model."""
    ok = previous.valid[pairs[:, 0]] & current.valid[pairs[:, 1]]
    pairs = pairs[ok]
    if len(pairs) < max(5, min_inliers):
        return pairs[:0]
    rel = estimate_relative_pose(previous.bearings[pairs[:, 0]], current.bearings[pairs[:, 1]], threshold_rad,
                                 rng=rng, min_inliers=min_inliers, refine=False)
    if rel is None:
        return pairs[:0]
    return pairs[rel.inliers]


class KeyframeSelector:
    """Feeds images in order, yields KeyframeLinks as keyframes are decided."""

    def __init__(self, camera: CameraModel, sparse: SparseSettings, seed: int, flatten_light: bool = False):
        self.camera = camera
        self.sparse = sparse
        self.flatten_light = flatten_light  # the images are not gain-corrected: flatten the light (sparse_features)
        self.rng = np.random.default_rng(seed)
        self.threshold_rad = sparse.ransac_threshold_px / float(np.mean(camera.params[:2]))  # pinhole fx, fy
        self.key: View | None = None
        self.last: tuple[View, np.ndarray] | None = None  # the previous image and its matches with the keyframe
        self.first: View | None = None

    def view(self, index: int, image: np.ndarray) -> View:
        if self.flatten_light and self.sparse.light_sigma_px is not None:
            image = flatten_light(image, self.sparse.light_sigma_px)
        image = np.asarray(image, np.float32)
        kp = detect(image, self.sparse)
        bearings, valid = self.camera.unproject(kp.uv)
        return View(index, kp, bearings, valid, image if self.sparse.match_patch_px else None)

    def _registered(self, previous: View, current: View, pairs: np.ndarray) -> tuple[View, np.ndarray]:
        """The current view with its matched keypoints moved to where the previous keyframe's patches register,
        and the pairs that registered."""
        patch = self.sparse.match_patch_px
        if not patch or len(pairs) == 0 or previous.image is None or current.image is None:
            return current, pairs
        anchors = anchor_templates(previous.image, previous.keypoints.uv[pairs[:, 0]], patch)
        ok, uv, _ = refine_to_anchors(current.image, anchors, current.keypoints.uv[pairs[:, 1]], patch,
                                      iterations=self.sparse.match_iterations)
        pairs, uv = pairs[ok], uv[ok]
        moved = current.keypoints.uv.copy()
        moved[pairs[:, 1]] = uv
        bearings, valid = current.bearings.copy(), current.valid.copy()
        bearings[pairs[:, 1]], valid[pairs[:, 1]] = self.camera.unproject(uv)
        keypoints = Keypoints(moved, current.keypoints.score, current.keypoints.descriptors)
        return View(current.index, keypoints, bearings, valid, current.image), pairs

    def _pass(self, pairs: np.ndarray, a: View, b: View) -> bool:
        if len(pairs) < self.sparse.keyframe_min_matches:
            return False
        flow = np.linalg.norm(b.keypoints.uv[pairs[:, 1]] - a.keypoints.uv[pairs[:, 0]], axis=1)
        return float(np.median(flow)) <= self.sparse.keyframe_max_flow_px

    def _link(self, view: View, pairs: np.ndarray) -> KeyframeLink:
        inl = inlier_pairs(self.key, view, pairs, self.threshold_rad, self.rng, self.sparse.min_inliers)
        view, inl = self._registered(self.key, view, inl)
        link = KeyframeLink(self.key, view, inl, len(pairs))
        self.key, self.last = view, None
        return link

    def push(self, index: int, image: np.ndarray) -> Iterator[KeyframeLink]:
        v = self.view(index, image)
        if self.key is None:
            self.key = self.first = v
            return
        pairs = match(self.key.keypoints, v.keypoints, self.sparse.ambiguity_ratio)
        if self._pass(pairs, self.key, v):
            self.last = (v, pairs)
            return
        if self.last is not None:
            yield self._link(*self.last)
            pairs = match(self.key.keypoints, v.keypoints, self.sparse.ambiguity_ratio)
            if self._pass(pairs, self.key, v):
                self.last = (v, pairs)
                return
        yield self._link(v, pairs)

    def finish(self) -> Iterator[KeyframeLink]:
        """The last image is always a keyframe, so that the trajectory covers the whole run."""
        if self.last is not None:
            yield self._link(*self.last)
