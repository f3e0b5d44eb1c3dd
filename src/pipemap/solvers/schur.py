"""The damped normal equations of bundle adjustment, solved by eliminating the 3x3 point blocks.

Unknowns: free camera poses (6 each), an optional small global block (the cylinder's 4 parameters)
and points (3 each). With H = [[U, W], [W^T, V]] (U over cameras + global block, V block-diagonal over
points), the Schur complement S = U - W V^-1 W^T is dense but small (6 N + 4), so it is factorised with
a dense Cholesky; the points follow by back-substitution. Everything is vectorised over observations:
per-observation blocks are summed into cameras and points with `np.bincount`, and the camera-camera
part of W V^-1 W^T is summed over all pairs of observations of the same point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import LinAlgError, cho_factor, cho_solve


def transposed(blocks: np.ndarray) -> np.ndarray:
    """Each block (..., m, n) transposed, laid out contiguously: numpy's stacked matrix products with it run two
    to four times faster than with a transposed view, and give the same values."""
    return np.ascontiguousarray(np.swapaxes(blocks, -1, -2))


def block_sum(index: np.ndarray, blocks: np.ndarray, n: int) -> np.ndarray:
    """Sum blocks (K, ...) into n bins by index (K,): out[i] = sum of blocks[index == i]."""
    shape = blocks.shape[1:]
    size = int(np.prod(shape)) if shape else 1
    flat = blocks.reshape(len(blocks), size)
    idx = (np.asarray(index, np.int64)[:, None] * size + np.arange(size)).ravel()
    return np.bincount(idx, weights=flat.ravel(), minlength=n * size).reshape((n,) + shape)


class BlockSummer:
    """`block_sum` for a fixed index, as a product with a sparse 0/1 matrix: built once per set of
    observations, it sums 2-7x faster than `np.bincount` (no index arithmetic per call)."""

    def __init__(self, index: np.ndarray, n: int):
        index = np.asarray(index, np.int64)
        self.n, self.k = n, len(index)
        self.A = sp.csr_matrix((np.ones(self.k), (index, np.arange(self.k))), shape=(n, self.k))

    def __call__(self, blocks: np.ndarray) -> np.ndarray:
        if self.k == 0:  # e.g. no pair of distinct free cameras shares a point
            return np.zeros((self.n,) + blocks.shape[1:])
        out = self.A @ np.ascontiguousarray(blocks).reshape(self.k, -1)
        return np.asarray(out).reshape((self.n,) + blocks.shape[1:])


class RunSummer:
    """`BlockSummer`'s sums of blocks formed on demand, at most `max_items` items' blocks at a time: the pairs of
    observations of a point run to a million in a long section's solve, and their 6x6 products with the two
    factors gathered for them had taken most of its memory (0.6 GB). The bins are taken in runs whose items fit the
    budget; each bin sums its items in the order `BlockSummer` does (ascending), so the sums are the same to the
    last bit."""

    def __init__(self, index: np.ndarray, n: int, max_items: int = 1 << 16):
        index = np.asarray(index, np.int64)
        self.n = n
        self.order = np.argsort(index, kind="stable")
        ends = np.cumsum(np.bincount(index, minlength=n))
        self.runs = []  # (first bin, bin after the last, first item, item after the last, CSR row pointers)
        first = 0
        while first < n:
            start = int(ends[first - 1]) if first else 0
            last = min(max(int(np.searchsorted(ends, start + max_items, side="right")), first + 1), n)
            self.runs.append((first, last, start, int(ends[last - 1]), np.r_[0, ends[first:last] - start]))
            first = last

    def __call__(self, blocks_of, shape: tuple[int, ...]) -> np.ndarray:
        """(n,) + shape: per bin, the sum of blocks_of(items) (len(items),) + shape over its items."""
        size = int(np.prod(shape))
        out = np.zeros((self.n, size))
        for first, last, i0, i1, indptr in self.runs:
            if i1 > i0:
                blocks = np.ascontiguousarray(blocks_of(self.order[i0:i1])).reshape(i1 - i0, size)
                A = sp.csr_matrix((np.ones(i1 - i0), np.arange(i1 - i0), indptr), shape=(last - first, i1 - i0))
                out[first:last] = A @ blocks
        return out.reshape((self.n,) + tuple(shape))


class SchurStructure:
    """What stays fixed while the inlier set does: observation pairs and the summing operators.

    obs_cam: free camera index (0..C-1) of each observation by a free camera; obs_pt: its point.
    """

    def __init__(self, obs_cam: np.ndarray, obs_pt: np.ndarray, n_cams: int, n_points: int):
        self.obs_cam, self.obs_pt = np.asarray(obs_cam, np.int64), np.asarray(obs_pt, np.int64)
        self.C, self.M = n_cams, n_points
        self.a, self.b = observation_pairs(self.obs_pt)
        self.to_cam = BlockSummer(self.obs_cam, n_cams)
        self.to_point = BlockSummer(self.obs_pt, n_points)
        self.cam_runs = RunSummer(self.obs_cam, n_cams)
        self.pair_runs = RunSummer(self.obs_cam[self.a] * n_cams + self.obs_cam[self.b], n_cams * n_cams)
        self._rows6: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def cam_rows(self, blocks: np.ndarray) -> sp.csr_matrix:
        """The observations' rows (Kf, 6) as a sparse (6 C, M) matrix, row 6 c + i holding row i of camera c's
        observations in their order, each in its point's column: its product with a (M, q) matrix is to_cam of the
        outer products of the rows with the (Kf, q) rows of their points, summed in the same order (the same
        values), without the (Kf, 6, q) products or the (Kf, q) rows themselves. The entries stay in that order
        (a camera sees a point once, so no two share a column), which the sparse product follows."""
        if self._rows6 is None:
            by_cam = np.argsort(self.obs_cam, kind="stable")
            counts = np.repeat(np.bincount(self.obs_cam, minlength=self.C), 6)  # per row (c, i)
            indptr = np.r_[0, np.cumsum(counts)]
            row = np.repeat(np.arange(6 * self.C), counts)
            # entry j of row (c, i) is camera c's j-th observation, whose block starts at indptr[6 c] / 6
            cols = by_cam[indptr[row - row % 6] // 6 + np.arange(len(row)) - indptr[row]]
            self._rows6 = cols * 6 + row % 6, self.obs_pt[cols], indptr
        take, points, indptr = self._rows6
        return sp.csr_matrix((blocks.reshape(-1)[take], points, indptr), shape=(6 * self.C, self.M))


def observation_pairs(point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All pairs (a, b), a != b listed once, of observations (indices into `point`) of the same point."""
    point = np.asarray(point, np.int64)
    order = np.argsort(point, kind="stable")
    sp = point[order]
    if len(sp) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts = np.r_[0, np.flatnonzero(np.diff(sp)) + 1]
    ends = np.r_[starts[1:], len(sp)]
    group_end = np.repeat(ends, ends - starts)
    n_after = group_end - np.arange(len(sp)) - 1
    first = np.repeat(np.arange(len(sp)), n_after)
    offset = np.arange(len(first)) - np.repeat(np.cumsum(n_after) - n_after, n_after)
    return order[first], order[first + 1 + offset]


@dataclass
class NormalEquations:
    """H delta = -g in blocks. Cameras are the free ones, numbered 0..n_cams-1."""

    U: np.ndarray  # (C, 6, 6)
    gc: np.ndarray  # (C, 6)
    V: np.ndarray  # (M, 3, 3)
    gp: np.ndarray  # (M, 3)
    W: np.ndarray  # (Kf, 6, 3) per observation by a free camera
    obs_cam: np.ndarray  # (Kf,) free camera index
    obs_pt: np.ndarray  # (Kf,) point index
    Ux: np.ndarray  # (q, q) global block (q = 0 without one)
    gx: np.ndarray  # (q,)
    Wx: np.ndarray | None  # (M, q, 3) global-point coupling, or None with Wx_rank1
    H_extra: np.ndarray | None = None  # (6C + q, 6C + q) added to the reduced system (priors)
    g_extra: np.ndarray | None = None  # (6C + q,)
    # Wx[m] = outer(A[m], P[m]) given as (A (M, q), P (M, 3)): one scalar residual per point (a wall
    # distance) couples it to the global block. The solve then never forms (M, q, 3) arrays, which
    # with a bent cylinder's dozens of parameters cost more than the rest of the step.
    Wx_rank1: tuple[np.ndarray, np.ndarray] | None = None

    def global_point_coupling(self) -> np.ndarray:
        """Wx (M, q, 3), formed from its factors when given as Wx_rank1."""
        if self.Wx_rank1 is None:
            return self.Wx
        A, P = self.Wx_rank1
        return A[:, :, None] * P[:, None, :]


def solve_damped(eq: NormalEquations, structure: SchurStructure, lam: float):
    """Levenberg-Marquardt step (H + lam diag(H)) delta = -g. Returns (d_cams (C, 6), d_global (q,), d_points (M, 3))
    or None when the reduced system is not positive definite.

    `structure` is `SchurStructure(eq.obs_cam, eq.obs_pt, C, M)`.
    """
    st = structure
    C, q = len(eq.U), len(eq.gx)
    eye3 = np.eye(3)
    diagV = np.einsum("mii->mi", eq.V)
    V = eq.V + (lam * diagV + 1e-12 * (diagV.max(initial=0.0) + 1.0))[:, :, None] * eye3
    Vinv = np.linalg.inv(V)
    Y = eq.W @ Vinv[eq.obs_pt]  # (Kf, 6, 3): W_a V^-1
    n = 6 * C + q
    S = np.zeros((n, n))
    if C:
        diagU = np.einsum("cii->ci", eq.U)
        Ud = eq.U + (lam * diagU)[:, :, None] * np.eye(6)
        diag_blocks = Ud - st.cam_runs(lambda i: Y[i] @ transposed(eq.W[i]), (6, 6))
        cross = st.pair_runs(lambda i: Y[st.a[i]] @ transposed(eq.W[st.b[i]]), (6, 6))
        cross = cross.reshape(C, C, 6, 6).transpose(0, 2, 1, 3).reshape(6 * C, 6 * C)
        np.add(cross, cross.T, out=S[: 6 * C, : 6 * C])
        np.negative(S[: 6 * C, : 6 * C], out=S[: 6 * C, : 6 * C])
        del cross
        idx = np.arange(C)
        S6 = S[: 6 * C, : 6 * C].reshape(C, 6, C, 6)
        S6[idx, :, idx, :] += diag_blocks
    rhs = np.zeros(n)
    if C:
        rhs[: 6 * C] = (-eq.gc + st.to_cam(np.einsum("kij,kj->ki", Y, eq.gp[eq.obs_pt]))).ravel()
    if q and eq.Wx_rank1 is not None:
        A, P = eq.Wx_rank1
        r = np.einsum("mij,mj->mi", Vinv, P)  # V^-1 P (V is symmetric)
        S[6 * C:, 6 * C:] = eq.Ux + lam * np.diag(np.diag(eq.Ux)) - (A * np.einsum("mi,mi->m", r, P)[:, None]).T @ A
        if C:
            a = np.einsum("kij,kj->ki", Y, P[eq.obs_pt])
            cx = st.cam_rows(a) @ A
            S[: 6 * C, 6 * C:] = -cx
            S[6 * C:, : 6 * C] = -cx.T
        rhs[6 * C:] = -eq.gx + A.T @ np.einsum("mi,mi->m", r, eq.gp)
    elif q:
        Yx = eq.Wx @ Vinv  # (M, q, 3)
        S[6 * C:, 6 * C:] = eq.Ux + lam * np.diag(np.diag(eq.Ux)) - np.einsum("mij,mkj->ik", Yx, eq.Wx)
        if C:
            cx = st.to_cam(Y @ np.swapaxes(eq.Wx[eq.obs_pt], 1, 2)).reshape(6 * C, q)
            S[: 6 * C, 6 * C:] = -cx
            S[6 * C:, : 6 * C] = -cx.T
        rhs[6 * C:] = -eq.gx + np.einsum("mij,mj->i", Yx, eq.gp)
    if eq.H_extra is not None:
        S += eq.H_extra
        rhs -= eq.g_extra
    try:
        delta = cho_solve(cho_factor(S, check_finite=True), rhs) if n else rhs
    except (LinAlgError, ValueError):
        return None
    dc = delta[: 6 * C].reshape(C, 6)
    dx = delta[6 * C:]
    back = -eq.gp
    if C:
        back = back - st.to_point(np.einsum("kji,kj->ki", eq.W, dc[eq.obs_cam]))
    if q and eq.Wx_rank1 is not None:
        back = back - eq.Wx_rank1[1] * (eq.Wx_rank1[0] @ dx)[:, None]
    elif q:
        back = back - np.einsum("mji,j->mi", eq.Wx, dx)
    dp = np.einsum("mij,mj->mi", Vinv, back)
    return dc, dx, dp
