"""The sparse VO state machine (2010 report 5.3): keyframes in, poses in the pipe frame out.

Each new keyframe inherits the global indices of its RANSAC-inlier matches with the previous
keyframe (new indices for the rest), gets a one-degree-of-freedom pose (5.3.1), has estimates far
from their point's mean cut from the point (mismatches that RANSAC let through), and adds its
estimates to S(g). When the batch of the first `offset_batch_keyframes` keyframes is complete,
their common offset (C_X, C_Y) and heights are optimised on image reprojection (5.3.2) and their
estimates in S(g) recomputed. Every `refine_every` keyframes the previous 2N are refined with six
degrees of freedom, `refine_passes` times (5.3.3); the end of the run gets the same treatment.
Where the batch found the camera's offset beyond what the images determine, the refinement keeps
the camera mount and moves each keyframe only about and along the axis (`refine_dof`), and, unless
the offset was measured, eqs. 45-49 run again over `offset_long_keyframes` keyframes (or the whole
of a shorter run).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipemap.camera import CameraModel
from pipemap.config import SparseSettings
from pipemap.straight.sparse_batch import bundle_batch
from pipemap.straight.sparse_geometry import initial_pose, wall_distance
from pipemap.straight.sparse_keyframes import KeyframeLink, View
from pipemap.straight.sparse_motion import (KeyframeState, estimate_one_dof, gate_outliers, refine_crawler,
                                            refine_six_dof)
from pipemap.straight.sparse_offset import OffsetBatch, optimise_offset
from pipemap.straight.sparse_sums import WallSums

_MAX_OFFSET_FRACTION = 0.9  # a batch that puts the camera nearer the wall than this has failed


@dataclass(frozen=True)
class BatchSummary:
    """What the initial batch found and what the odometry kept."""

    model: str  # "bundle" or "report"
    offset: np.ndarray  # (C_X, C_Y) the batch estimated
    rms_px: float
    observations: int  # observations (bundle) or observation pairs (report) used
    sigma: np.ndarray | None = None  # (2,) standard deviations of the estimate (bundle only)
    determined: bool = True  # sigma within offset_max_sigma of the camera's distance to the wall
    used: str = "batch"  # "batch": the poses of the batch were kept; "given": the measured initial_offset_m;
    # "long batch": eqs. 45-49 over offset_long_keyframes, the batch having left the offset undetermined


class SparseOdometry:
    def __init__(self, camera: CameraModel, radius: float, sparse: SparseSettings):
        self.camera = camera
        self.radius = float(radius)
        self.sparse = sparse
        self.sums = WallSums()
        self.keyframes: list[KeyframeState] = []
        self.offset: BatchSummary | None = None  # None until the batch has run
        self.refined_at = 0  # last keyframe a at which the sliding refinement ran
        self.unconstrained = 0  # keyframes without a single point seen before (pose kept)

    def start(self, view: View) -> None:
        R, C = initial_pose(*self.sparse.initial_offset_m)
        kf = KeyframeState(view.index, view.keypoints.uv, view.bearings, self.sums.new_ids(len(view.bearings)), R, C)
        kf.hr = kf.estimates(self.radius)
        self.sums.add(kf.gid, kf.hr)
        self.keyframes.append(kf)

    def add(self, link: KeyframeLink) -> None:
        if not self.keyframes:
            self.start(link.previous)
        prev = self.keyframes[-1]
        cur = link.current
        gid = np.full(len(cur.bearings), -1)
        gid[link.pairs[:, 1]] = prev.gid[link.pairs[:, 0]]
        fresh = gid < 0
        gid[fresh] = self.sums.new_ids(int(fresh.sum()))
        kf = KeyframeState(cur.index, cur.keypoints.uv, cur.bearings, gid, prev.R.copy(), prev.C.copy())
        _, used = estimate_one_dof(kf, self.sums, self.radius, self.sparse.lm_iterations)
        if used == 0:
            self.unconstrained += 1
        hr = kf.estimates(self.radius)
        out = gate_outliers(kf, self.sums, hr, self.sparse.outlier_mad_k, self.sparse.outlier_floor_m)
        if out.any():
            kf.gid[out] = self.sums.new_ids(int(out.sum()))
            estimate_one_dof(kf, self.sums, self.radius, self.sparse.lm_iterations)
            hr = kf.estimates(self.radius)
        kf.hr = hr
        self.sums.add(kf.gid, kf.hr)
        self.keyframes.append(kf)
        a = len(self.keyframes) - 1
        if self.offset is None and len(self.keyframes) == self.sparse.offset_batch_keyframes:
            self.optimise_offset()
        elif self._wants_long_batch() and len(self.keyframes) == self.sparse.offset_long_keyframes:
            self._long_batch(self.keyframes)
        if a % self.sparse.refine_every == 0:
            self.refine(a)

    def optimise_offset(self) -> None:
        """5.3.2 on the keyframes so far (the first offset_batch_keyframes), by the chosen batch model."""
        kfs = self.keyframes
        if self.sparse.offset_batch_model == "bundle":
            self._bundle_batch(kfs)
        else:
            self._report_batch(kfs)

    def _report_batch(self, kfs: list[KeyframeState]) -> None:
        batch = OffsetBatch.from_keyframes([k.gid for k in kfs], [k.uv for k in kfs], [k.bearings for k in kfs])
        heights = np.array([k.C[2] for k in kfs])
        if len(batch) < len(kfs) + 1:
            return
        res = optimise_offset(batch, self.camera, self.radius, kfs[0].R, kfs[0].C[:2], heights)
        self.offset = BatchSummary("report", res.offset, res.rms_px, res.pairs)
        self._replace_poses(kfs, [k.R for k in kfs], [np.r_[res.offset, h] for h in res.heights])

    def _bundle_batch(self, kfs: list[KeyframeState]) -> None:
        R = np.array([k.R for k in kfs])
        C = np.array([k.C for k in kfs])
        res = bundle_batch([k.gid for k in kfs], [k.uv for k in kfs], [k.bearings for k in kfs], R, C, self.camera,
                           self.radius, wall_sigma_m=self.sparse.offset_wall_sigma_m,
                           iterations=self.sparse.offset_batch_iterations)
        if res is None or not np.hypot(*res.offset) < _MAX_OFFSET_FRACTION * self.radius:
            return  # too little shared structure, or the batch left the pipe: keep the given start
        # the offset sets the scale through the distance to the wall; how well the batch knows it decides
        depth = wall_distance(res.R[0], res.C[0], self.radius)
        determined = bool(np.hypot(*res.offset_sigma) <= self.sparse.offset_max_sigma * depth)
        keep_given = not determined and self.sparse.offset_measured
        self.offset = BatchSummary("bundle", res.offset, res.rms_px, res.observations, res.offset_sigma, determined,
                                   "given" if keep_given else "batch")
        if not keep_given:
            self._replace_poses(kfs, res.R, res.C)

    def _wants_long_batch(self) -> bool:
        """The batch could not determine the offset and none was measured: look again over more keyframes."""
        off = self.offset
        return (off is not None and off.model == "bundle" and not off.determined and off.used == "batch"
                and self.sparse.offset_long_keyframes > self.sparse.offset_batch_keyframes)

    def _long_batch(self, kfs: list[KeyframeState]) -> None:
        """Eqs. 45-49 over `offset_long_keyframes` keyframes: one offset and rotation for all of them (the
        crawler's mount), so the faint curvature of the wall adds up over the whole stretch while the
        robot's wobble, which biases a short batch held at one rotation, averages out."""
        sp = self.sparse
        batch = OffsetBatch.from_keyframes([k.gid for k in kfs], [k.uv for k in kfs], [k.bearings for k in kfs],
                                           max_lag=sp.offset_long_lag)
        R, C0 = kfs[0].R, kfs[0].C
        heights = np.array([k.C[2] - C0[2] for k in kfs])
        if len(batch) < 2 * (len(kfs) + 1):
            return
        res = optimise_offset(batch, self.camera, self.radius, R, C0[:2], heights)
        self.offset = replace(self.offset, offset=res.offset, rms_px=res.rms_px, observations=res.pairs,
                              used="long batch")
        self._replace_poses(kfs, [R for _ in kfs], [np.r_[res.offset, h] for h in res.heights])

    def _replace_poses(self, kfs: list[KeyframeState], R, C) -> None:
        """New poses for the batch's keyframes; their estimates in S(g) follow."""
        for k, r, c in zip(kfs, R, C):
            self.sums.add(k.gid, k.hr, -1.0)
            k.R, k.C = np.array(r, float), np.array(c, float)
            k.hr = k.estimates(self.radius)
            self.sums.add(k.gid, k.hr)

    def refine(self, a: int) -> None:
        """5.3.3: keyframes max(1, a - 2N + 1) .. a, one after the other, `refine_passes` times."""
        lo = max(1, a - 2 * self.sparse.refine_every + 1)
        crawler = self.refine_dof() == "crawler"
        for _ in range(self.sparse.refine_passes):
            for k in range(lo, a + 1):
                if crawler:
                    refine_crawler(self.keyframes[k], self.sums, self.radius)
                else:
                    refine_six_dof(self.keyframes[k], self.sums, self.radius, self.sparse.lm_iterations)
        self.refined_at = a

    def refine_dof(self) -> str:
        """"six" or "crawler" (settings.refine_dof; auto: crawler when the batch left the offset undetermined).

        The images fix the offset through the curvature of the wall they see; where that is too weak
        (narrow lens, large pipe) they are as blind to a keyframe's pitch, which looks like a move along
        the axis (report Figure 10), and to its distance from the wall, which is the scale. Refining
        those one keyframe at a time against its neighbours then lets them wander with the scale."""
        if self.sparse.refine_dof != "auto":
            return self.sparse.refine_dof
        return "crawler" if self.offset is not None and not self.offset.determined else "six"

    def finish(self) -> None:
        if self.offset is None and len(self.keyframes) >= 2:
            self.optimise_offset()
        if self._wants_long_batch() and len(self.keyframes) > self.sparse.offset_batch_keyframes:
            self._long_batch(self.keyframes)  # a run shorter than the long batch: all of it
        a = len(self.keyframes) - 1
        if self.sparse.refine_at_end and a > self.refined_at:
            self.refine(a)

    def poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Image indices (K,), rotations (K, 3, 3) and centres (K, 3) of the keyframes in the pipe frame."""
        idx = np.array([k.index for k in self.keyframes], int)
        R = np.array([k.R for k in self.keyframes]).reshape(-1, 3, 3)
        C = np.array([k.C for k in self.keyframes]).reshape(-1, 3)
        return idx, R, C
