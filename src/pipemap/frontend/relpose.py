"""Relative pose of two views from bearing vectors: five-point RANSAC on the view sphere.

Why our own solver: OpenCV's findEssentialMat, pycolmap's and poselib's camera models work in
pinhole-normalised coordinates, which cannot represent the 190 deg fisheye's rays past 90 deg
(design.md). Here everything is on unit bearings eta (formats.md camera frame):

    eta_j^T E eta_i = 0,   E = [t]_x R,   X_j = R X_i + t,   |t| = 1.

The minimal solver is Stewenius' five-point method (10 x 20 Groebner elimination, action
matrix of x, eigen-decomposition), batched over RANSAC samples in numpy. The error of a
correspondence is the Sampson error on the sphere: the algebraic error divided by the norm of
its gradient in the two tangent planes, i.e. the smallest angular correction (radians) of the
two bearings that satisfies the epipolar constraint.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from pipemap.geometry.rotations import exp_so3
from pipemap.solvers.lm import levenberg_marquardt


def _monomials() -> list[tuple[int, int, int]]:
    cubic = [(3, 0, 0), (2, 1, 0), (2, 0, 1), (1, 2, 0), (1, 1, 1),
             (1, 0, 2), (0, 3, 0), (0, 2, 1), (0, 1, 2), (0, 0, 3)]
    lower = [(2, 0, 0), (1, 1, 0), (1, 0, 1), (0, 2, 0), (0, 1, 1),
             (0, 0, 2), (1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)]
    return cubic + lower


_MONO = _monomials()
_INDEX = {m: i for i, m in enumerate(_MONO)}
_LINEAR = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)]
_QUADRATIC = _MONO[10:]


def _product_table(left, right) -> np.ndarray:
    """(len(left) * len(right), 20): where the product of two monomials lands among the 20."""
    table = np.zeros((len(left), len(right), 20))
    for a, b in product(range(len(left)), range(len(right))):
        m = tuple(x + y for x, y in zip(left[a], right[b]))
        table[a, b, _INDEX[m]] = 1.0
    return table.reshape(len(left) * len(right), 20)


_LIN_LIN = _product_table(_LINEAR, _LINEAR)[:, 10:]  # degree <= 2: lands among the lower 10
_QUAD_LIN = _product_table(_QUADRATIC, _LINEAR)
# Row of the action matrix of x for each lower monomial b: where x * b lands among the 20.
_ACTION_ROWS = np.array([_INDEX[(m[0] + 1, m[1], m[2])] for m in _QUADRATIC])


def _constraints(L: np.ndarray) -> np.ndarray:
    """The 10 cubic constraints (S, 10, 20) on E = x E1 + y E2 + z E3 + E4, E given as L (S, 3, 3, 4).

    Nine from 2 E E^T E - trace(E E^T) E = 0 and one from det(E) = 0.
    """
    s = L.shape[0]
    eet = np.einsum("sakp,sbkq->sabpq", L, L).reshape(s, 3, 3, 16) @ _LIN_LIN  # (S, 3, 3, 10)
    trace = eet[:, 0, 0] + eet[:, 1, 1] + eet[:, 2, 2]
    eete = np.einsum("sakp,skbq->sabpq", eet, L).reshape(s, 3, 3, 40) @ _QUAD_LIN
    tre = np.einsum("sp,sabq->sabpq", trace, L).reshape(s, 3, 3, 40) @ _QUAD_LIN
    trace_rows = (2.0 * eete - tre).reshape(s, 9, 20)
    # det(E) = sum_k E[0, k] * cofactor[0, k]
    cof = np.stack([
        np.einsum("sp,sq->spq", L[:, 1, 1], L[:, 2, 2]) - np.einsum("sp,sq->spq", L[:, 1, 2], L[:, 2, 1]),
        np.einsum("sp,sq->spq", L[:, 1, 2], L[:, 2, 0]) - np.einsum("sp,sq->spq", L[:, 1, 0], L[:, 2, 2]),
        np.einsum("sp,sq->spq", L[:, 1, 0], L[:, 2, 1]) - np.einsum("sp,sq->spq", L[:, 1, 1], L[:, 2, 0]),
    ], axis=1).reshape(s, 3, 16) @ _LIN_LIN  # (S, 3, 10)
    det = np.einsum("skq,skp->spq", L[:, 0], cof).reshape(s, 40) @ _QUAD_LIN
    return np.concatenate([trace_rows, det[:, None, :]], axis=1)


def five_point(bearings_i: np.ndarray, bearings_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Essential matrices of S minimal samples (S, 5, 3) x 2 -> (E (M, 3, 3), sample of each (M,)).

    Each sample gives up to 10 real solutions, normalised to unit Frobenius norm.
    """
    bi = np.asarray(bearings_i, float)
    bj = np.asarray(bearings_j, float)
    s = bi.shape[0]
    q = (bj[:, :, :, None] * bi[:, :, None, :]).reshape(s, 5, 9)
    _, _, vt = np.linalg.svd(q, full_matrices=True)
    basis = vt[:, 5:9, :]  # E = x E1 + y E2 + z E3 + E4
    m = _constraints(basis.reshape(s, 4, 3, 3).transpose(0, 2, 3, 1))
    lead, rest = m[:, :, :10], m[:, :, 10:]
    ok = np.abs(np.linalg.det(lead)) > 1e-14 * np.max(np.abs(lead), axis=(1, 2)) ** 10
    if not np.any(ok):
        return np.zeros((0, 3, 3)), np.zeros(0, int)
    lead, rest, basis = lead[ok], rest[ok], basis[ok]
    sample_ids = np.nonzero(ok)[0]
    reduced = np.linalg.solve(lead, rest)  # cubic_c = -reduced[c] . lower monomials
    action = np.zeros((lead.shape[0], 10, 10))
    for row, target in enumerate(_ACTION_ROWS):
        if target < 10:
            action[:, row] = -reduced[:, target]
        else:
            action[:, row, target - 10] = 1.0
    values, vectors = np.linalg.eig(action)
    real = np.abs(values.imag) <= 1e-8 * np.maximum(1.0, np.abs(values.real))
    vectors = vectors.real
    w = vectors[:, 9, :]
    real &= np.abs(w) > 1e-12
    sample_of, sol = np.nonzero(real)
    x = values.real[sample_of, sol]
    y = vectors[sample_of, 7, sol] / w[sample_of, sol]
    z = vectors[sample_of, 8, sol] / w[sample_of, sol]
    b = basis[sample_of]
    E = x[:, None] * b[:, 0] + y[:, None] * b[:, 1] + z[:, None] * b[:, 2] + b[:, 3]
    E = E.reshape(-1, 3, 3)
    E /= np.linalg.norm(E, axis=(1, 2), keepdims=True)
    return E, sample_ids[sample_of]


def pair_outers(bearings_i: np.ndarray, bearings_j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The outer products (N, 9) eta_j eta_i^T, eta_i eta_i^T, eta_j eta_j^T that `sampson_angle` takes
    its quadratic forms over: computed once where many matrices are scored against the same pairs."""
    n = bearings_i.shape[0]
    outer_ji = (bearings_j[:, :, None] * bearings_i[:, None, :]).reshape(n, 9)
    outer_ii = (bearings_i[:, :, None] * bearings_i[:, None, :]).reshape(n, 9)
    outer_jj = (bearings_j[:, :, None] * bearings_j[:, None, :]).reshape(n, 9)
    return outer_ji, outer_ii, outer_jj


def sampson_angle(E: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray,
                  outers: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Spherical Sampson error (radians) of N pairs under one (3, 3) or H (H, 3, 3) matrices -> (N,) / (H, N).
    `outers`: `pair_outers(bearings_i, bearings_j)`, when the caller has them."""
    # All three terms are quadratic forms, so each is one matrix product over the hypotheses:
    # e = eta_j^T E eta_i, |E eta_i|^2 = eta_i^T E^T E eta_i, |E^T eta_j|^2 = eta_j^T E E^T eta_j.
    E = np.asarray(E, float)
    flat = E.reshape(-1, 9)
    ete = (np.swapaxes(E, -1, -2) @ E).reshape(-1, 9)
    eet = (E @ np.swapaxes(E, -1, -2)).reshape(-1, 9)
    n = bearings_i.shape[0]
    outer_ji, outer_ii, outer_jj = pair_outers(bearings_i, bearings_j) if outers is None else outers
    # einsum rather than BLAS: these products are too thin for threaded GEMM to pay off.
    a2 = np.einsum("hk,nk->hn", flat, outer_ji) ** 2
    # Squared gradients in the two tangent planes: |E eta_i|^2 - e^2 and |E^T eta_j|^2 - e^2.
    norm2 = np.einsum("hk,nk->hn", ete, outer_ii) + np.einsum("hk,nk->hn", eet, outer_jj) - 2.0 * a2
    err = np.sqrt(a2 / np.maximum(norm2, 1e-30))
    return err.reshape(E.shape[:-2] + (n,))


def essential_from_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return tx @ R


def triangulate_depths(R: np.ndarray, t: np.ndarray, bearings_i: np.ndarray,
                       bearings_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depths along the bearings (lambda_i, lambda_j) of the mid-point solution of
    lambda_j eta_j = lambda_i R eta_i + t.

    Valid for bearings past 90 deg: a point is in front when both depths are positive.
    """
    a = bearings_i @ R.T
    b = bearings_j
    ab = np.sum(a * b, axis=1)
    at = a @ t
    bt = b @ t
    denom = 1.0 - ab * ab
    denom = np.where(np.abs(denom) < 1e-12, 1e-12, denom)
    # Normal equations of min |lambda_i a - lambda_j b + t|^2 with |a| = |b| = 1.
    lam_i = (ab * bt - at) / denom
    lam_j = (bt - ab * at) / denom
    return lam_i, lam_j


def decompose_essential(E: np.ndarray, bearings_i: np.ndarray,
                        bearings_j: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """The (R, unit t) of the four decompositions that puts most pairs in front of both views."""
    u, _, vt = np.linalg.svd(E)
    if np.linalg.det(u) < 0:
        u = -u
    if np.linalg.det(vt) < 0:
        vt = -vt
    w = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    best = None
    for R in (u @ w @ vt, u @ w.T @ vt):
        for t in (u[:, 2], -u[:, 2]):
            lam_i, lam_j = triangulate_depths(R, t, bearings_i, bearings_j)
            count = int(np.sum((lam_i > 0) & (lam_j > 0)))
            if best is None or count > best[2]:
                best = (R, t.copy(), count)
    return best


@dataclass(frozen=True)
class RelativePose:
    """X_j = R X_i + t with |t| = 1; `inliers` marks the pairs within the angular threshold."""

    E: np.ndarray
    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray
    errors: np.ndarray  # spherical Sampson error (radians) of every pair
    trials: int


def _tangent_basis(t: np.ndarray) -> np.ndarray:
    helper = np.eye(3)[np.argmin(np.abs(t))]
    e1 = np.cross(t, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(t, e1)])


def signed_sampson(E: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The spherical Sampson errors of N pairs under one E (3, 3), signed as eta_j^T E eta_i, and their
    derivatives (N, 9) with respect to E's entries (row-major)."""
    n = bearings_i.shape[0]
    outer_ji = (bearings_j[:, :, None] * bearings_i[:, None, :]).reshape(n, 9)
    e = outer_ji @ E.ravel()
    e_i = bearings_i @ E.T  # E eta_i
    e_j = bearings_j @ E  # E^T eta_j
    norm2 = np.maximum(np.einsum("nk,nk->n", e_i, e_i) + np.einsum("nk,nk->n", e_j, e_j) - 2.0 * e * e, 1e-30)
    inv = 1.0 / np.sqrt(norm2)
    d_norm2 = 2.0 * ((e_i[:, :, None] * bearings_i[:, None, :]).reshape(n, 9)
                     + (bearings_j[:, :, None] * e_j[:, None, :]).reshape(n, 9)) - 4.0 * e[:, None] * outer_ji
    d_e = outer_ji * inv[:, None] - (0.5 * e * inv / norm2)[:, None] * d_norm2
    return e * inv, d_e


def soft_l1(r: np.ndarray) -> tuple[float, np.ndarray]:
    """The soft-L1 cost 2 (sqrt(1 + r^2) - 1) of residuals in units of the inlier threshold, and its IRLS weights."""
    root = np.sqrt(1.0 + r * r)
    return float(2.0 * np.sum(root - 1.0)), 1.0 / root


def refine_pose(R: np.ndarray, t: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray,
                scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Minimise the spherical Sampson errors over R and the unit t (5 degrees of freedom), robustly.
    The errors' derivatives come in closed form through E; only E's own (9 x 5) by central differences.
    (scipy's least_squares differencing the errors took 11.7 ms a keyframe on paper-loop at 640x480, this 6.3 ms.)"""
    tangent = _tangent_basis(t)
    bi = np.asarray(bearings_i, float)
    bj = np.asarray(bearings_j, float)

    def pose(p):
        Rp = exp_so3(p[:3]) @ R
        tp = t + p[3:] @ tangent
        return Rp, tp / np.linalg.norm(tp)

    def essential(p):
        return essential_from_pose(*pose(p))

    def evaluate(p):
        E = essential(p)
        h = 1e-6
        d_essential = np.stack([(essential(p + dp) - essential(p - dp)).ravel() / (2 * h) for dp in np.eye(5) * h],
                               axis=1)
        r, d_r = signed_sampson(E, bi, bj)
        return r / scale, d_r @ d_essential / scale

    result = levenberg_marquardt(evaluate, lambda p, step: p + step, np.zeros(5), iterations=20, cost=soft_l1)
    return pose(result.state)


def best_rotation(bearings_i: np.ndarray, bearings_j: np.ndarray) -> np.ndarray:
    """The rotation R that best takes bearings_i onto bearings_j (N, 3) by least squares (Kabsch)."""
    U, _, Vt = np.linalg.svd(np.asarray(bearings_i, float).T @ np.asarray(bearings_j, float))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def rotation_fits_motion(R: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray, factor: float,
                         slack_deg: float) -> bool:
    """Whether a relative pose's rotation could have made the image motion of its inliers (bearing pairs (N, 3)).

    The rotation that best turns one set of bearings onto the other differs from the true one only by what the
    translation moves them, which is at most about their own angular motion (a camera moving sideways past a
    wall at one depth: each bearing moves as if turned). A pose turned further from it than `factor` x the 90th
    percentile of that motion plus `slack_deg` is a wrong solution that its inliers do not tell apart: on
    320x240 H.264 CCTV footage the inliers were a few dozen codec flecks in the dark far end of the pipe, whose
    tiny cone of bearings fits a pose turned by 20-80 deg as well as the true one, and the chained heading
    turned a straight pipe into a bend."""
    bi, bj = np.asarray(bearings_i, float), np.asarray(bearings_j, float)
    if len(bi) < 3:
        return True
    moved = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", bi, bj), -1.0, 1.0)))
    off = R @ best_rotation(bi, bj).T
    angle = np.degrees(np.arccos(np.clip((np.trace(off) - 1.0) / 2.0, -1.0, 1.0)))
    return bool(angle <= factor * np.percentile(moved, 90) + slack_deg)


def pose_inliers(R: np.ndarray, t: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray,
                 threshold_rad: float) -> np.ndarray:
    """(N,) bool: the pairs within the angular threshold of the pose's epipolar geometry and in front of both
    cameras."""
    errors = sampson_angle(essential_from_pose(R, t), bearings_i, bearings_j)
    lam_i, lam_j = triangulate_depths(R, t, bearings_i, bearings_j)
    return (errors < threshold_rad) & (lam_i > 0) & (lam_j > 0)


def continued_motion(R: np.ndarray, t: np.ndarray, inliers: np.ndarray, prior_R: np.ndarray, prior_t: np.ndarray,
                     bearings_i: np.ndarray, bearings_j: np.ndarray, threshold_rad: float, share: float,
                     apart_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The pose that continues the previous one's motion, where the pairs cannot tell it from RANSAC's.

    A crawler's motion from keyframe to keyframe changes smoothly. `prior_R`, `prior_t` (the previous relative
    pose) refined on all pairs (robustly) either comes back to RANSAC's pose (R, t), or it is another solution;
    then it is the pose when it has at least `share` of RANSAC's inliers (the trackers ask only where those are
    few: frontend.continued_motion_max_inliers). On 320x240 H.264 CCTV footage of a
    straight pipe the few dozen pairs that survive the codec fitted a pose turned 7 deg with its translation 64 deg
    off the pipe's axis better by a handful of pairs than the straight drive, and the window solves did not undo
    it. Returns (R, t, inliers) of the continued motion, or None to keep RANSAC's."""
    bi, bj = np.asarray(bearings_i, float), np.asarray(bearings_j, float)
    if len(bi) < 5 or not np.all(np.isfinite(prior_t)) or np.linalg.norm(prior_t) < 0.5:
        return None
    Rp, tp = refine_pose(np.asarray(prior_R, float), np.asarray(prior_t, float), bi, bj, threshold_rad)
    turned = np.degrees(np.arccos(np.clip((np.trace(Rp @ R.T) - 1.0) / 2.0, -1.0, 1.0)))
    heading = np.degrees(np.arccos(np.clip(abs(float(tp @ t)), -1.0, 1.0)))
    if turned < apart_deg and heading < 10.0 * apart_deg:
        return None  # the same solution
    ip = pose_inliers(Rp, tp, bi, bj, threshold_rad)
    back = pose_inliers(Rp, -tp, bi, bj, threshold_rad)  # the Sampson error does not tell t from -t
    if back.sum() > ip.sum():
        tp, ip = -tp, back
    if ip.sum() < share * np.sum(inliers):
        return None
    return Rp, tp, ip


def estimate_relative_pose(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    threshold_rad: float,
    confidence: float = 0.999,
    rng: np.random.Generator | None = None,
    max_trials: int = 1000,
    batch: int = 16,
    min_inliers: int = 8,
    refine: bool = True,
    score_subset: int = 300,
) -> RelativePose | None:
    """Five-point MSAC on bearing pairs (N, 3) x 2 with an adaptive trial count; None when it fails."""
    rng = np.random.default_rng(0) if rng is None else rng
    bi = np.asarray(bearings_i, float)
    bj = np.asarray(bearings_j, float)
    n = bi.shape[0]
    if n < max(5, min_inliers):
        return None
    th2 = threshold_rad**2
    # Hypotheses are ranked on a random subset: enough to tell them apart, a fraction of the cost.
    scored = rng.choice(n, score_subset, replace=False) if n > score_subset else np.arange(n)
    bi_scored, bj_scored = bi[scored], bj[scored]
    outers = pair_outers(bi_scored, bj_scored)
    best_cost, best_E, trials, needed = np.inf, None, 0, max_trials
    while trials < min(needed, max_trials):
        # Five distinct indices per sample: argsort of random keys is a batched choice without replacement.
        samples = np.argsort(rng.random((batch, n)), axis=1)[:, :5] if n < 4096 else rng.integers(0, n, (batch, 5))
        trials += batch
        E, _ = five_point(bi[samples], bj[samples])
        if len(E) == 0:
            continue
        err = sampson_angle(E, bi_scored, bj_scored, outers)
        cost = np.minimum(err * err, th2).sum(axis=1)
        h = int(np.argmin(cost))
        if cost[h] < best_cost:
            best_cost, best_E = cost[h], E[h]
            ratio = np.mean(err[h] < threshold_rad)
            miss = 1.0 - ratio**5
            needed = trials if miss <= 0 else int(np.ceil(np.log(1 - confidence) / np.log(max(miss, 1e-12))))
    if best_E is None:
        return None
    inliers = sampson_angle(best_E, bi, bj) < threshold_rad
    if inliers.sum() < min_inliers:
        return None
    R, t, _ = decompose_essential(best_E, bi[inliers], bj[inliers])
    if refine:
        R, t = refine_pose(R, t, bi[inliers], bj[inliers], threshold_rad)
    E = essential_from_pose(R, t)
    errors = sampson_angle(E, bi, bj)
    inliers = errors < threshold_rad
    lam_i, lam_j = triangulate_depths(R, t, bi, bj)
    # A pair behind either camera cannot be the same wall point, whatever its epipolar error.
    inliers &= (lam_i > 0) & (lam_j > 0)
    if inliers.sum() < min_inliers:
        return None
    return RelativePose(E, R, t, inliers, errors, trials)
