"""Trajectory and map error metrics against ground truth: pure functions over numpy arrays.

Sign conventions follow the papers: the distance-travelled table (2010 report, Table 2) uses
error = ground truth - estimate; junction distances (fisheye paper, Table I) and path length
use error = estimate - ground truth. Lengths are metres; percentages are of the ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations
from typing import Mapping, Sequence

import numpy as np

from pipemap.evaluation.align import Alignment, umeyama

ASSOCIATION_TOLERANCE_S = 1e-4


def percent(value: float, reference: float) -> float:
    """100 * value / reference, NaN where the reference is zero."""
    return 100.0 * value / reference if reference != 0 else math.nan


def associate(
    est_timestamps: np.ndarray, gt_timestamps: np.ndarray, tol: float = ASSOCIATION_TOLERANCE_S
) -> tuple[np.ndarray, np.ndarray]:
    """Match each estimated timestamp to the nearest ground-truth one within `tol` seconds.

    Returns index arrays `(est_index, gt_index)` in increasing estimate time; the matching is
    one-to-one (if two estimates fall on one ground-truth pose, the earlier one keeps it).
    """
    est_t = np.asarray(est_timestamps, float).ravel()
    gt_t = np.asarray(gt_timestamps, float).ravel()
    if len(est_t) == 0 or len(gt_t) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    order = np.argsort(gt_t, kind="stable")
    sorted_t = gt_t[order]
    pos = np.searchsorted(sorted_t, est_t)
    left = np.clip(pos - 1, 0, len(sorted_t) - 1)
    right = np.clip(pos, 0, len(sorted_t) - 1)
    d_left = np.abs(est_t - sorted_t[left])
    d_right = np.abs(sorted_t[right] - est_t)
    nearest = np.where(d_right < d_left, right, left)
    ok = np.minimum(d_left, d_right) <= tol
    est_index = np.nonzero(ok)[0]
    est_index = est_index[np.argsort(est_t[est_index], kind="stable")]
    gt_index = order[nearest[est_index]]
    _, first = np.unique(gt_index, return_index=True)
    keep = np.sort(first)
    return est_index[keep], gt_index[keep]


def path_length(positions: np.ndarray) -> float:
    """Length of the polyline through (N, 3) positions."""
    p = np.asarray(positions, float)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error: position residuals after aligning the estimate to ground truth."""

    rmse: float
    max: float
    mean: float
    median: float
    scale: float  # s in gt ≈ s R est + t: 1/1.01 for an estimate 1 % too large
    alignment: Alignment
    errors: np.ndarray  # (N,) per-pose residuals, metres

    def as_dict(self) -> dict:
        return {
            "rmse_m": self.rmse,
            "max_m": self.max,
            "mean_m": self.mean,
            "median_m": self.median,
            "scale": self.scale,
            "rotation": self.alignment.rotation.tolist(),
            "translation_m": self.alignment.translation.tolist(),
        }


def ate(est_positions: np.ndarray, gt_positions: np.ndarray, with_scale: bool = False) -> AteResult:
    """ATE of associated (N, 3) positions after Umeyama alignment (Sim(3) if `with_scale`)."""
    est = np.asarray(est_positions, float)
    gt = np.asarray(gt_positions, float)
    alignment = umeyama(est, gt, with_scale=with_scale)
    errors = np.linalg.norm(alignment.apply(est) - gt, axis=1)
    return AteResult(
        rmse=float(np.sqrt(np.mean(errors**2))),
        max=float(errors.max()),
        mean=float(errors.mean()),
        median=float(np.median(errors)),
        scale=float(alignment.scale),
        alignment=alignment,
        errors=errors,
    )


# --- Distance travelled down a straight pipe (2010 report, Table 2, eqs. 50-51) -------------


@dataclass(frozen=True)
class DistanceRow:
    """One block of Table 2: ground truth, estimate, error = gt - estimate, |error| in %."""

    ground_truth: float
    estimate: float
    error: float
    abs_error_pct: float

    @classmethod
    def of(cls, ground_truth: float, estimate: float, reference: float | None = None) -> "DistanceRow":
        error = ground_truth - estimate
        ref = ground_truth if reference is None else reference
        return cls(float(ground_truth), float(estimate), float(error), abs(percent(error, ref)))

    def as_dict(self) -> dict:
        return {
            "ground_truth_m": self.ground_truth,
            "estimate_m": self.estimate,
            "error_m": self.error,
            "abs_error_pct": self.abs_error_pct,
        }


@dataclass(frozen=True)
class DistanceTravelled:
    """Table 2 of the 2010 report. For a forward-only run `forward` is first -> last pose and
    `reverse`/`total` are None; for a forward-and-reverse run `forward` is first -> turnaround,
    `reverse` turnaround -> last, and `total` the net displacement forward - reverse (truth
    forward_gt - reverse_gt, 0 for a return to the start) with eq. 51's percentage
    100 |error| / (forward_gt + reverse_gt), i.e. / (2 x ground truth) when both legs are equal."""

    forward: DistanceRow
    reverse: DistanceRow | None
    total: DistanceRow | None
    gt_turnaround_index: int  # into the positions passed in
    est_turnaround_index: int

    @property
    def forward_and_reverse(self) -> bool:
        return self.reverse is not None

    def as_dict(self) -> dict:
        return {
            "forward_and_reverse": self.forward_and_reverse,
            "forward": self.forward.as_dict(),
            "reverse": None if self.reverse is None else self.reverse.as_dict(),
            "total": None if self.total is None else self.total.as_dict(),
        }


def principal_axis(positions: np.ndarray) -> np.ndarray:
    """Unit direction of largest spread of (N, 3) positions (first principal component)."""
    p = np.asarray(positions, float)
    _, _, Vt = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)
    return Vt[0]


def along_axis(positions: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Signed distance of each pose from the first along `axis`, oriented so that the pose
    farthest from the start lies on the positive side (a fitted axis has no intrinsic sign)."""
    p = np.asarray(positions, float)
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    s = (p - p[0]) @ a
    far = int(np.argmax(np.abs(s)))
    return -s if s[far] < 0 else s


def distance_travelled(
    est_positions: np.ndarray,
    gt_positions: np.ndarray,
    gt_axis: np.ndarray,
    reverse_min_fraction: float = 0.01,
) -> DistanceTravelled:
    """Distance travelled down a straight pipe, estimated vs true, on associated poses.

    Ground truth is measured along the pipe's axis `gt_axis` (the network's segment). The
    estimate is measured along its *own* principal axis, never through an alignment to ground
    truth, so that its metric scale is judged independently. The run counts as forward and
    reverse when the true return leg exceeds `reverse_min_fraction` of the forward leg; each
    trajectory's turnaround is its own pose farthest along its axis.
    """
    s_gt = along_axis(gt_positions, gt_axis)
    s_est = along_axis(est_positions, principal_axis(est_positions))
    k_gt, k_est = int(np.argmax(s_gt)), int(np.argmax(s_est))
    fwd_gt, rev_gt = s_gt[k_gt] - s_gt[0], s_gt[k_gt] - s_gt[-1]
    fwd_est, rev_est = s_est[k_est] - s_est[0], s_est[k_est] - s_est[-1]
    if rev_gt <= reverse_min_fraction * fwd_gt:
        row = DistanceRow.of(s_gt[-1] - s_gt[0], s_est[-1] - s_est[0])
        return DistanceTravelled(row, None, None, len(s_gt) - 1, len(s_est) - 1)
    return DistanceTravelled(
        forward=DistanceRow.of(fwd_gt, fwd_est),
        reverse=DistanceRow.of(rev_gt, rev_est),
        total=DistanceRow.of(fwd_gt - rev_gt, fwd_est - rev_est, reference=fwd_gt + rev_gt),
        gt_turnaround_index=k_gt,
        est_turnaround_index=k_est,
    )


# --- Junction centre-to-centre distances (fisheye paper, Table I) ---------------------------


@dataclass(frozen=True)
class JunctionPair:
    truth_ids: tuple[str, str]
    estimate_ids: tuple[str, str]
    ground_truth: float
    estimate: float
    error: float  # estimate - ground truth
    error_pct: float

    def as_dict(self) -> dict:
        return {
            "truth_ids": list(self.truth_ids),
            "estimate_ids": list(self.estimate_ids),
            "ground_truth_m": self.ground_truth,
            "estimate_m": self.estimate,
            "error_m": self.error,
            "error_pct": self.error_pct,
        }


@dataclass(frozen=True)
class ElbowRow:
    """An elbow's angle and bend radius, true and estimated (None: the result does not estimate it)."""

    truth_id: str
    estimate_id: str
    truth_angle_deg: float
    truth_bend_radius_m: float
    estimate_angle_deg: float | None
    estimate_bend_radius_m: float | None

    @property
    def angle_error_deg(self) -> float | None:
        return None if self.estimate_angle_deg is None else self.estimate_angle_deg - self.truth_angle_deg

    @property
    def bend_radius_error_m(self) -> float | None:
        return None if self.estimate_bend_radius_m is None else self.estimate_bend_radius_m - self.truth_bend_radius_m

    @property
    def bend_radius_error_pct(self) -> float | None:
        e = self.bend_radius_error_m
        return None if e is None else percent(e, self.truth_bend_radius_m)

    def as_dict(self) -> dict:
        return {
            "truth_id": self.truth_id, "estimate_id": self.estimate_id,
            "angle_deg": {"ground_truth": self.truth_angle_deg, "estimate": self.estimate_angle_deg,
                          "error": self.angle_error_deg, "estimated": self.estimate_angle_deg is not None},
            "bend_radius_m": {"ground_truth": self.truth_bend_radius_m, "estimate": self.estimate_bend_radius_m,
                              "error": self.bend_radius_error_m, "error_pct": self.bend_radius_error_pct,
                              "estimated": self.estimate_bend_radius_m is not None},
        }


@dataclass(frozen=True)
class JunctionTable:
    """Pairwise centroid distances; junctions matched by order of first visit. Every junction type
    counts (an elbow by its vertex); `types` gives (truth type, estimate type) per match, `elbows` the
    matched true elbows' angle and bend radius beside the estimate's."""

    matches: tuple[tuple[str, str], ...]  # (truth id, estimate id)
    pairs: tuple[JunctionPair, ...]
    estimated_count: int
    truth_count: int
    types: tuple[tuple[str, str], ...] = ()
    elbows: tuple[ElbowRow, ...] = ()

    @property
    def counts_agree(self) -> bool:
        return self.estimated_count == self.truth_count

    @property
    def max_abs_error(self) -> float:
        return max((abs(p.error) for p in self.pairs), default=math.nan)

    @property
    def max_abs_error_pct(self) -> float:
        return max((abs(p.error_pct) for p in self.pairs), default=math.nan)

    def as_dict(self) -> dict:
        types = self.types or tuple((None, None) for _ in self.matches)
        return {
            "estimated_count": self.estimated_count,
            "ground_truth_count": self.truth_count,
            "counts_agree": self.counts_agree,
            "matches": [{"truth_id": t, "estimate_id": e, "truth_type": tt, "estimate_type": et}
                        for (t, e), (tt, et) in zip(self.matches, types)],
            "pairs": [p.as_dict() for p in self.pairs],
            "max_abs_error_m": self.max_abs_error,
            "max_abs_error_pct": self.max_abs_error_pct,
            "elbows": [e.as_dict() for e in self.elbows],
        }


def first_visits(visits: Sequence[str]) -> list[str]:
    """Junction ids in order of first visit (a route T4 T3 T2 T1 T4 gives T4 T3 T2 T1)."""
    return list(dict.fromkeys(visits))


def route_pairs(visits: Sequence[str]) -> list[tuple[str, str]]:
    """All unordered pairs of visited junctions: first those consecutive along the route
    (T1-T2, T2-T3, T3-T4, T4-T1 for a closed loop), then the rest, as in Table I."""
    visits = list(visits)
    seen: set[frozenset] = set()
    pairs = []
    for a, b in list(zip(visits[:-1], visits[1:])) + list(combinations(first_visits(visits), 2)):
        key = frozenset((a, b))
        if a != b and key not in seen:
            seen.add(key)
            pairs.append((a, b))
    return pairs


def junction_table(
    est_ids: Sequence[str],
    est_centroids: np.ndarray,
    visits: Sequence[str],
    truth_centroids: Mapping[str, np.ndarray],
    truth: Mapping | None = None,
    estimated: Sequence | None = None,
) -> JunctionTable:
    """Table I replica. The i-th estimated junction (listed in order of first passage) is matched
    to the i-th distinct junction of the true route `visits`; extra junctions on either side are
    left unmatched and reported through the counts. Distances are frame-independent, so no
    alignment is needed. `truth` (id -> network Junction) and `estimated` (the result's junctions in
    order, with type, angle_deg, bend_radius_m) add the types and the elbows' angles and bend radii."""
    order = first_visits(visits)
    est_c = np.asarray(est_centroids, float).reshape(-1, 3)
    n = min(len(order), len(est_ids))
    truth_to_est = {order[i]: i for i in range(n)}
    pairs = []
    for a, b in route_pairs(visits):
        if a not in truth_to_est or b not in truth_to_est:
            continue
        ia, ib = truth_to_est[a], truth_to_est[b]
        d_gt = float(np.linalg.norm(np.asarray(truth_centroids[a], float) - np.asarray(truth_centroids[b], float)))
        d_est = float(np.linalg.norm(est_c[ia] - est_c[ib]))
        error = d_est - d_gt
        pairs.append(JunctionPair((a, b), (est_ids[ia], est_ids[ib]), d_gt, d_est, error, percent(error, d_gt)))
    matches = tuple((order[i], str(est_ids[i])) for i in range(n))
    types, elbows = (), ()
    if truth is not None:
        est = list(estimated) if estimated is not None else [None] * n
        types = tuple((truth[t].type, None if est[i] is None else est[i].type) for i, (t, _) in enumerate(matches))
        elbows = tuple(_elbow_row(truth[t], e, est[i]) for i, (t, e) in enumerate(matches) if truth[t].type == "elbow")
    return JunctionTable(matches, tuple(pairs), len(est_ids), len(order), types, elbows)


def _elbow_row(truth, estimate_id: str, estimate) -> ElbowRow:
    angle = getattr(estimate, "angle_deg", None)
    bend = getattr(estimate, "bend_radius_m", None)
    return ElbowRow(truth.id, estimate_id, float(truth.angle_deg), float(truth.bend_radius_m),
                    None if angle is None else float(angle), None if bend is None else float(bend))
