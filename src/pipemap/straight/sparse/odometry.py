"""The sparse VO state machine (2010 report 5.3): keyframes in, poses in the pipe frame out.

Each new keyframe inherits the global indices of its RANSAC-inlier matches with the previous
keyframe (new indices for the rest), gets a one-degree-of-freedom pose (5.3.1), has estimates far
from their point's mean cut from the point (mismatches that RANSAC let through), and adds its
estimates to S(g). When the batch of the first `offset_batch_keyframes` keyframes is complete,
their poses, the wall points and the axis are solved together (5.3.2 as a bundle adjustment,
sparse/batch.py), from the report's square start and from the camera turned to its direction of
travel (any mount), and their estimates in S(g) recomputed; at `offset_long_keyframes` the batch
runs again over every `offset_long_step`-th keyframe, kept where it determines the offset better than
the first; where neither determines it, eqs. 45-49 run over them all and are kept only where they agree
with the better bundle estimate within its own uncertainty (`offset_report_max_z`), else that estimate
is. Every
`refine_every` keyframes the previous 2N are refined (5.3.3, `refine_dof`): together in one bundle
adjustment on the wall where the batch determined the offset, or, where it could not, keeping the
camera mount and moving each keyframe only about and along the axis; the end of the run gets the same
treatment.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipemap.camera import CameraModel
from pipemap.config import SparseSettings
from pipemap.straight.sparse.batch import BatchResult, bundle_batch, bundle_window, mount_of
from pipemap.frontend.relpose import estimate_relative_pose
from pipemap.straight.sparse.geometry import initial_pose, rotation_from_travel, wall_distance
from pipemap.straight.sparse.keyframes import KeyframeLink, View
from pipemap.straight.sparse.motion import (KeyframeState, estimate_one_dof, gate_outliers, refine_crawler,
                                            refine_six_dof)
from pipemap.straight.sparse.offset import OffsetBatch, OffsetResult, optimise_offset
from pipemap.straight.sparse.sums import WallSums

_MAX_OFFSET_FRACTION = 0.9  # a batch that puts the camera nearer the wall than this has failed


@dataclass(frozen=True)
class OffsetEstimate:
    """One estimate of the first camera's offset that the batches made, kept or not (run.json lists them)."""

    source: str  # "batch", "long bundle" or "long batch" (eqs. 45-49)
    offset: np.ndarray  # (C_X, C_Y)
    sigma: np.ndarray | None = None  # (2,) standard deviations (bundle only)
    sigma_fraction: float = np.inf  # hypot(sigma) / the distance to the wall (bundle only)
    z: float | None = None  # eqs. 45-49: distance from the best bundle estimate in its standard deviations
    kept: bool = False

    def to_dict(self) -> dict:
        return {"source": self.source, "C_X_m": float(self.offset[0]), "C_Y_m": float(self.offset[1]),
                "sigma_m": None if self.sigma is None else [float(x) for x in self.sigma],
                "sigma_fraction": float(self.sigma_fraction) if np.isfinite(self.sigma_fraction) else None,
                "z": self.z, "kept": self.kept}


def offset_agreement(offset, best: np.ndarray, sigma: np.ndarray) -> float:
    """How far `offset` lies from the bundle estimate `best` in that estimate's standard deviations `sigma`
    (the Mahalanobis distance with their diagonal covariance)."""
    d = (np.asarray(offset, float) - np.asarray(best, float)) / np.maximum(np.asarray(sigma, float), 1e-12)
    return float(np.hypot(*d))


def report_agrees(offset, best: "BatchSummary", max_z: float) -> tuple[bool, float]:
    """Eqs. 45-49's offset may replace the best bundle estimate `best` only where the bundle's own uncertainty
    admits it: within max_z of its standard deviations (no sigma: nothing says otherwise). Eqs. 45-49 hold every
    keyframe at one rotation, so a robot's wobble biases them where the bundle, which gives every keyframe its
    own pose, is not; where the bundle knows the offset well enough to reject their value, it is kept."""
    if best.sigma is None or not np.all(np.isfinite(best.sigma)):
        return True, np.nan
    z = offset_agreement(offset, best.offset, best.sigma)
    return bool(z <= max_z), z


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
    # "long batch": eqs. 45-49 over offset_long_keyframes, the batches having left the offset undetermined and
    # eqs. 45-49 agreeing with the better of them within offset_report_max_z of its sigma;
    # "long bundle": the bundle batch again over offset_long_keyframes (every offset_long_step-th), which
    # knew it better than the first batch (undetermined too where it ruled out eqs. 45-49)
    mount: np.ndarray | None = None  # (4,) angle, roll (rad), C_X, C_Y (m), the batch's mean (sparse_batch.mount_of)
    mount_covariance: np.ndarray | None = None  # (4, 4) of `mount` (bundle only)
    keyframes: tuple[int, ...] = ()  # image indices of the keyframes the estimate came from
    sigma_fraction: float = np.inf  # hypot(sigma) / the distance to the wall along the optical axis (bundle only)
    # How well the straight-pipe model fits the images: the bundle batch's RMS, kept when the long batch's estimate
    # replaces its offset (eqs. 45-49 hold every keyframe at one rotation, so their RMS also holds the wobble)
    fit_rms_px: float = np.nan
    estimates: tuple[OffsetEstimate, ...] = ()  # every estimate the batches made, in order, the kept one marked


class SparseOdometry:
    def __init__(self, camera: CameraModel, radius: float, sparse: SparseSettings, seed: int = 0):
        self.camera = camera
        self.seed = seed
        self.radius = float(radius)
        self.sparse = sparse
        self.sums = WallSums()
        self.keyframes: list[KeyframeState] = []
        self.offset: BatchSummary | None = None  # None until the batch has run
        self.refined_at = 0  # last keyframe a at which the sliding refinement ran
        self.unconstrained = 0  # keyframes without a single point seen before (pose kept)
        self.long_ran = False  # the long batch has run (once: not again over the whole run at its end)

    def start(self, view: View) -> None:
        R, C = initial_pose(*self.sparse.initial_offset_m)
        kf = KeyframeState(view.index, view.keypoints.uv, view.bearings, self.sums.new_ids(len(view.bearings)), R, C)
        kf.hr = kf.estimates(self.radius)
        self.sums.add(kf.gid, kf.hr)
        self.keyframes.append(kf)

    def add(self, link: KeyframeLink, refine: bool = True) -> None:
        """The next keyframe: its 1-DOF pose, the batches when their keyframes are in, and (with `refine`) the
        sliding refinement every refine_every keyframes."""
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
        if refine and a % self.sparse.refine_every == 0:
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
        self.offset = BatchSummary("report", res.offset, res.rms_px, res.pairs,
                                   mount=mount_of(kfs[0].R, np.r_[res.offset, 0.0]),
                                   keyframes=tuple(int(k.index) for k in kfs), fit_rms_px=res.rms_px)
        self._replace_poses(kfs, [k.R for k in kfs], [np.r_[res.offset, h] for h in res.heights])

    def _travel(self, kfs: list[KeyframeState]) -> np.ndarray | None:
        """Unit direction of travel in the first keyframe's axes from the five-point pose between it and the last
        keyframe that still shares enough tracked points with it (a longer baseline than any keyframe pair);
        None where that fails or says the camera travels along its optical axis."""
        sp = self.sparse
        first = kfs[0]
        for last in reversed(kfs[1:]):
            _, ia, ib = np.intersect1d(first.gid, last.gid, return_indices=True)
            if len(ia) >= 2 * sp.min_inliers:
                break
        else:
            return None
        threshold = sp.ransac_threshold_px / float(np.mean(self.camera.params[:2]))
        rel = estimate_relative_pose(first.bearings[ia], last.bearings[ib], threshold,
                                     rng=np.random.default_rng(self.seed), min_inliers=sp.min_inliers)
        if rel is None:
            return None
        travel = -rel.R.T @ rel.t
        return travel if np.hypot(travel[0], travel[1]) > 0.1 else None

    def _replay(self, kfs: list[KeyframeState], R: np.ndarray) -> None:
        """The one-degree-of-freedom chain of `kfs` again (same points), from a first keyframe turned to R."""
        for k in kfs:
            self.sums.add(k.gid, k.hr, -1.0)
        for i, k in enumerate(kfs):
            k.R = R.copy()
            k.C = np.r_[self.sparse.initial_offset_m, 0.0] if i == 0 else kfs[i - 1].C.copy()
            if i:
                estimate_one_dof(k, self.sums, self.radius, self.sparse.lm_iterations)
            k.hr = k.estimates(self.radius)
            self.sums.add(k.gid, k.hr)

    def _run_bundle(self, kfs: list[KeyframeState]) -> tuple[BatchResult | None, float]:
        """The bundle batch on `kfs`: its result (None when it failed or left the pipe) and the standard deviation
        of its offset as a fraction of the distance to the wall, which is the scale error it brings."""
        R = np.array([k.R for k in kfs])
        C = np.array([k.C for k in kfs])
        res = bundle_batch([k.gid for k in kfs], [k.uv for k in kfs], [k.bearings for k in kfs], R, C, self.camera,
                           self.radius, **self._bundle_options())
        if res is None or not np.hypot(*res.offset) < _MAX_OFFSET_FRACTION * self.radius:
            return None, np.inf  # too little shared structure, or the batch left the pipe
        fraction = np.hypot(*res.offset_sigma) / wall_distance(res.R[0], res.C[0], self.radius)
        return res, float(fraction) if np.isfinite(fraction) else np.inf

    def _summary(self, res: BatchResult, fraction: float, used: str, kfs: list[KeyframeState],
                 earlier: tuple[OffsetEstimate, ...] = ()) -> BatchSummary:
        source = "batch" if used == "given" else used
        mine = OffsetEstimate(source, np.array(res.offset, float), np.array(res.offset_sigma, float), fraction,
                              kept=used != "given")
        return BatchSummary("bundle", res.offset, res.rms_px, res.observations, res.offset_sigma,
                            fraction <= self.sparse.offset_max_sigma, used, res.mount, res.mount_covariance,
                            tuple(int(k.index) for k in kfs), fraction, res.rms_px,
                            tuple(replace(e, kept=False) for e in earlier) + (mine,))

    @staticmethod
    def _noted(summary: BatchSummary, estimate: OffsetEstimate) -> BatchSummary:
        """`summary` with an estimate that was not kept added to its list."""
        return replace(summary, estimates=summary.estimates + (replace(estimate, kept=False),))

    def _bundle_options(self) -> dict:
        """The bundle batch's and the sliding bundle's settings."""
        sp = self.sparse
        return dict(wall_sigma_m=sp.offset_wall_sigma_m, huber_px=sp.offset_huber_px, mad_k=sp.offset_mad_k,
                    outlier_passes=sp.offset_outlier_passes, iterations=sp.offset_batch_iterations,
                    max_incidence_deg=sp.max_incidence_deg)

    def _bundle_batch(self, kfs: list[KeyframeState]) -> None:
        res, fraction = self._from_best_start(kfs, self._run_bundle)
        if res is None:
            return  # keep the given start
        keep_given = fraction > self.sparse.offset_max_sigma and self.sparse.offset_measured
        self.offset = self._summary(res, fraction, "given" if keep_given else "batch", kfs)
        if not keep_given:
            self._replace_poses(kfs, res.R, res.C)

    def _from_best_start(self, kfs: list[KeyframeState], solve):
        """solve(kfs) -> (BatchResult | None, sigma fraction) from the keyframes' poses as they are (the report's
        square start) and, with initial_mount = motion, from the camera turned to travel along the pipe as the
        first and last keyframes say it does (`_replay`). The turned start is kept where its batch alone
        determines the offset, or where it both fits better and determines the offset better: square, a camera
        turned 40 deg towards its travel converges to a wrong mount (55 deg, 60 mm off in C_Y); the travel that
        a 25 deg lens sees over ten keyframes is too uncertain to turn by, and the batch from it fits the
        images a little better with a wrong turn and an offset it knows less well."""
        res, fraction = solve(kfs)
        travel = self._travel(kfs) if self.sparse.initial_mount == "motion" else None
        if travel is None:
            return res, fraction
        start = [(k.R.copy(), k.C.copy()) for k in kfs]
        self._replay(kfs, rotation_from_travel(travel))
        turned, turned_fraction = solve(kfs)
        limit = self.sparse.offset_max_sigma
        if turned is not None and (res is None or (turned_fraction <= limit < fraction) or (
                turned.fit_px < res.fit_px and turned_fraction < fraction)):
            return turned, turned_fraction
        self._replace_poses(kfs, [r for r, _ in start], [c for _, c in start])
        return res, fraction

    def _wants_long_batch(self) -> bool:
        """The bundle batch ran and its poses were kept, and the long batch has not run: look again over more
        keyframes."""
        off = self.offset
        return (off is not None and off.model == "bundle" and off.used == "batch" and not self.long_ran
                and self.sparse.offset_long_keyframes > self.sparse.offset_batch_keyframes)

    def _long_batch(self, kfs: list[KeyframeState]) -> None:
        """The batch again over `offset_long_keyframes` keyframes: the bundle batch on every offset_long_step-th
        of them (the span of the wall seen, not the number of keyframes, is what fixes the offset), kept where
        its offset is better determined than the first batch's and within offset_max_sigma; where neither
        bundle estimate is within it, eqs. 45-49 over all of them (from the keyframes' poses as the bundle
        batches' starts left them), kept only where they agree with the better bundle estimate
        (`report_agrees`), else that estimate is. A 6-inch run whose long bundle knew the offset to 0.48 % of
        the wall distance (its C_Y 0.1 mm off) fell back on eqs. 45-49, which the robot's wobble had put 6 mm
        off: the map 6 % short."""
        self.long_ran = True
        start = [(k.R.copy(), k.C.copy()) for k in kfs]
        pick = self._every(0, len(kfs) - 1, self.sparse.offset_long_step)
        res, fraction = self._long_bundle(kfs, pick)
        if res is not None:
            self.offset = self._noted(self.offset, OffsetEstimate("long bundle", np.array(res.offset, float),
                                                                  np.array(res.offset_sigma, float), fraction))
        better = res is not None and fraction < self.offset.sigma_fraction
        if better and fraction <= self.sparse.offset_max_sigma:
            return self._keep_long_bundle(kfs, pick, res, fraction)
        best = self._summary(res, fraction, "long bundle", [kfs[i] for i in pick]) if better else self.offset
        report = None if self.offset.determined else self._long_report(kfs)
        if report is not None:
            agrees, z = report_agrees(report.offset, best, self.sparse.offset_report_max_z)
            mine = OffsetEstimate("long batch", np.array(report.offset, float), z=None if np.isnan(z) else z)
            if agrees:
                return self._keep_long_report(kfs, report, mine)
            self.offset = self._noted(self.offset, mine)
        if better:
            return self._keep_long_bundle(kfs, pick, res, fraction)
        moved = [i for i, (k, (r, c)) in enumerate(zip(kfs, start))
                 if not (np.array_equal(k.R, r) and np.array_equal(k.C, c))]  # a turned start's replay: undone
        self._replace_poses([kfs[i] for i in moved], [start[i][0] for i in moved], [start[i][1] for i in moved])

    def _long_bundle(self, kfs: list[KeyframeState], pick: list[int]) -> tuple[BatchResult | None, float]:
        """The bundle batch on kfs[pick] (from both starts where the first batch left the offset undetermined);
        the keyframes' poses are left as the starts left them."""
        if self.offset.determined:  # the start is settled
            return self._run_bundle([kfs[i] for i in pick])
        return self._from_best_start(kfs, lambda ks: self._run_bundle([ks[i] for i in pick]))

    def _keep_long_bundle(self, kfs: list[KeyframeState], pick: list[int], res: BatchResult,
                          fraction: float) -> None:
        sub = [kfs[i] for i in pick]
        made = tuple(replace(e, kept=e.source == "long bundle") for e in self.offset.estimates)
        self.offset = replace(self._summary(res, fraction, "long bundle", sub), estimates=made)
        self._replace_poses(sub, res.R, res.C)
        self._follow(kfs, pick)

    def _follow(self, kfs: list[KeyframeState], pick: list[int]) -> None:
        """Keyframes between those a bundle adjustment solved (`pick`, indices into kfs): the pose of the solved
        keyframe before them, moved along the axis by eq. 42 (the robot's wobble is smooth over a few keyframes)
        against the solved keyframes' estimates alone (their own, from the poses before, would pull them back)."""
        chosen = set(pick)
        rest = [k for i, k in enumerate(kfs) if i not in chosen]
        for k in rest:
            self.sums.add(k.gid, k.hr, -1.0)
        for i, k in enumerate(kfs):
            if i in chosen:
                continue
            prev = kfs[max(j for j in pick if j < i)]
            k.R, k.C = prev.R.copy(), prev.C.copy()
            estimate_one_dof(k, self.sums, self.radius, self.sparse.lm_iterations)
            k.hr = k.estimates(self.radius)
            self.sums.add(k.gid, k.hr)

    @staticmethod
    def _every(first: int, last: int, step: int) -> list[int]:
        """first, first + step, ... and always `last`."""
        pick = list(range(first, last + 1, step))
        if pick[-1] != last:
            pick.append(last)
        return pick

    def _long_report(self, kfs: list[KeyframeState]) -> OffsetResult | None:
        """Eqs. 45-49 over `offset_long_keyframes` keyframes: one offset and rotation for all of them (the
        crawler's mount), so the faint curvature of the wall adds up over the whole stretch while the
        robot's wobble, which biases a short batch held at one rotation, averages out. None where the
        keyframes share too few points; the poses are left as they are (`_keep_long_report`)."""
        sp = self.sparse
        batch = OffsetBatch.from_keyframes([k.gid for k in kfs], [k.uv for k in kfs], [k.bearings for k in kfs],
                                           max_lag=sp.offset_long_lag)
        C0 = kfs[0].C
        heights = np.array([k.C[2] - C0[2] for k in kfs])
        if len(batch) < 2 * (len(kfs) + 1):
            return None
        return optimise_offset(batch, self.camera, self.radius, kfs[0].R, C0[:2], heights)

    def _keep_long_report(self, kfs: list[KeyframeState], res: OffsetResult, estimate: OffsetEstimate) -> None:
        R = kfs[0].R
        self.offset = replace(self.offset, offset=res.offset, rms_px=res.rms_px, observations=res.pairs,
                              used="long batch", mount=mount_of(R, np.r_[res.offset, 0.0]), mount_covariance=None,
                              keyframes=tuple(int(k.index) for k in kfs),
                              estimates=tuple(replace(e, kept=False) for e in self.offset.estimates)
                              + (replace(estimate, kept=True),))
        self._replace_poses(kfs, [R for _ in kfs], [np.r_[res.offset, h] for h in res.heights])

    def _replace_poses(self, kfs: list[KeyframeState], R, C) -> None:
        """New poses for the batch's keyframes; their estimates in S(g) follow."""
        for k, r, c in zip(kfs, R, C):
            self.sums.add(k.gid, k.hr, -1.0)
            k.R, k.C = np.array(r, float), np.array(c, float)
            k.hr = k.estimates(self.radius)
            self.sums.add(k.gid, k.hr)

    def refine(self, a: int) -> None:
        """5.3.3: keyframes max(1, a - 2N + 1) .. a, one after the other, `refine_passes` times (or together in one
        bundle adjustment)."""
        lo = max(1, a - 2 * self.sparse.refine_every + 1)
        if self.refine_dof() == "bundle":
            self._refine_bundle(lo - 1, a)
            self.refined_at = a
            return
        crawler = self.refine_dof() == "crawler"
        for _ in range(self.sparse.refine_passes):
            for k in range(lo, a + 1):
                if crawler:
                    refine_crawler(self.keyframes[k], self.sums, self.radius)
                else:
                    refine_six_dof(self.keyframes[k], self.sums, self.radius, self.sparse.lm_iterations)
        self.refined_at = a

    def _refine_bundle(self, lo: int, a: int) -> None:
        """Keyframes lo .. a (every offset_long_step-th) in one bundle adjustment on the wall, the first held where
        the previous window left it. Holding every keyframe that window solved carried its scale on and let it
        drift (+0.34 % over 1.4 m at 90 deg); solved again with the new keyframes, the older half takes its scale
        from the wall over the whole window, as the initial batch does (0.05 %)."""
        kfs = self.keyframes[lo:a + 1]
        pick = self._every(0, len(kfs) - 1, self.sparse.offset_long_step)
        held = 1
        if len(pick) < 3:
            return
        sub = [kfs[i] for i in pick]
        out = bundle_window([k.gid for k in sub], [k.uv for k in sub], [k.bearings for k in sub],
                            np.array([k.R for k in sub]), np.array([k.C for k in sub]), self.camera, self.radius, held,
                            **self._bundle_options())
        if out is None:
            return
        self._replace_poses(sub[held:], out[0][held:], out[1][held:])
        self._follow(kfs, pick)

    def refine_dof(self) -> str:
        """"bundle", "six" or "crawler" (settings.refine_dof; auto: crawler when the batch left the offset
        undetermined, else bundle).

        The images fix the offset through the curvature of the wall they see; where that is too weak
        (narrow lens, large pipe) they are as blind to a keyframe's pitch, which looks like a move along
        the axis (report Figure 10), and to its distance from the wall, which is the scale. Refining
        those one keyframe at a time against its neighbours then lets them wander with the scale.
        Where they do fix it, each keyframe's pitch matters: a camera turned towards its travel sees the
        wall ahead farther off than the wall beside it, so a pitch held wrong (the robot wobbles) makes
        the stored wall estimates of a point disagree with where it is seen next, a scale error that adds
        up keyframe after keyframe (1.4 % over 3 m at 50 deg with the crawler's sweep, 1.7 % with the
        report's per-keyframe six degrees of freedom against S(g)); the windows solve poses and points
        together instead."""
        if self.sparse.refine_dof != "auto":
            return self.sparse.refine_dof
        return "crawler" if self.offset is not None and not self.offset.determined else "bundle"

    def mount_settled(self) -> bool:
        """No later batch will change the first keyframe's pose."""
        return self.offset is not None and not self._wants_long_batch()

    def settle(self) -> None:
        """The batches on the keyframes there are, where the run ended before they ran."""
        if self.offset is None and len(self.keyframes) >= 2:
            self.optimise_offset()
        if self._wants_long_batch() and len(self.keyframes) > self.sparse.offset_batch_keyframes:
            self._long_batch(self.keyframes)  # a run shorter than the long batch: all of it

    def finish(self) -> None:
        self.settle()
        a = len(self.keyframes) - 1
        if self.sparse.refine_at_end and a > self.refined_at:
            self.refine(a)

    def poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Image indices (K,), rotations (K, 3, 3) and centres (K, 3) of the keyframes in the pipe frame."""
        idx = np.array([k.index for k in self.keyframes], int)
        R = np.array([k.R for k in self.keyframes]).reshape(-1, 3, 3)
        C = np.array([k.C for k in self.keyframes]).reshape(-1, 3)
        return idx, R, C
