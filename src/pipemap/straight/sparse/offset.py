"""Batch optimisation of the first camera's offset from the axis (2010 report 5.3.2, eqs. 45-49).

The first keyframes share the initial rotation R0 and offset (C_X, C_Y); keyframe a sits at
(C_X, C_Y, h_a) with h_0 = 0 (eq. 46). A keypoint of world point g seen in keyframe b is carried
to every other keyframe a of the batch that saw g by a two-step mapping via the pipe wall (its
ray meets the wall, eq. 35-39; the wall point is projected into a with the calibrated model,
distortion included) and compared with the keypoint detected there (eq. 47). C_X, C_Y and every
h_a minimise the sum of these squared pixel errors (eqs. 48-49) by Levenberg-Marquardt with the
analytic Jacobian below. The offset acts as an overall scale (report 5.3.2): image errors, unlike
errors on the wall, do not shrink when the camera moves towards the wall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix

from pipemap.camera import CameraModel
from pipemap.solvers import levenberg_marquardt, mad_sigma
from pipemap.straight.sparse.geometry import E_H, wall_offset_jacobian


@dataclass(frozen=True)
class OffsetBatch:
    """Observation pairs of the batch: keyframe a observes pixel uv_a of the point that keyframe b
    sees along bearing eta_b."""

    a: np.ndarray  # (M,) keyframe of the observed pixel
    b: np.ndarray  # (M,) keyframe whose ray is carried over
    uv_a: np.ndarray  # (M, 2)
    eta_b: np.ndarray  # (M, 3)

    @classmethod
    def from_keyframes(cls, gids: list[np.ndarray], uvs: list[np.ndarray], bearings: list[np.ndarray],
                       max_lag: int | None = None) -> "OffsetBatch":
        """Every ordered pair of distinct keyframes that saw the same global index (at most `max_lag`
        keyframes apart when given: a long batch keeps its pairs in proportion to its keyframes)."""
        k = np.concatenate([np.full(len(g), i) for i, g in enumerate(gids)])
        g = np.concatenate(gids)
        uv = np.concatenate(uvs)
        eta = np.concatenate(bearings)
        order = np.argsort(g, kind="stable")
        k, g, uv, eta = k[order], g[order], uv[order], eta[order]
        # all pairs within each run of equal g: compare every observation with every other
        starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
        sizes = np.diff(np.r_[starts, len(g)])
        ia, ib = [], []
        for m in np.unique(sizes[sizes > 1]):  # one vectorised block per track length
            s = starts[sizes == m]
            p, q = np.nonzero(~np.eye(m, dtype=bool))
            a, b = (s[:, None] + p[None, :]).ravel(), (s[:, None] + q[None, :]).ravel()
            near = np.ones(len(a), bool) if max_lag is None else np.abs(k[a] - k[b]) <= max_lag
            ia.append(a[near])
            ib.append(b[near])
        if not ia:
            z = np.zeros(0, int)
            return cls(z, z, np.zeros((0, 2)), np.zeros((0, 3)))
        ia, ib = np.concatenate(ia), np.concatenate(ib)
        return cls(k[ia], k[ib], uv[ia], eta[ib])

    def __len__(self) -> int:
        return len(self.a)

    def subset(self, keep: np.ndarray) -> "OffsetBatch":
        return OffsetBatch(self.a[keep], self.b[keep], self.uv_a[keep], self.eta_b[keep])


def offset_residuals(params: np.ndarray, batch: OffsetBatch, R0: np.ndarray, camera: CameraModel, radius: float,
                     jacobian: bool = False, sparse: bool = False):
    """Eq. 47 residuals (2M,) = detected - predicted pixels for params (C_X, C_Y, h_1 .. h_{K-1});
    with `jacobian`, also d residuals / d params (2M, K + 1), a scipy.sparse matrix with `sparse` (each
    row depends on C_X, C_Y and the two keyframes' heights only)."""
    cx, cy = params[0], params[1]
    h = np.r_[0.0, params[2:]]
    n_kf = len(h)
    Cb = np.stack([np.full(len(batch), cx), np.full(len(batch), cy), h[batch.b]], axis=-1)
    d = batch.eta_b @ R0.T
    X = _wall_from_centres(Cb, d, radius)
    Ca = np.stack([np.full(len(batch), cx), np.full(len(batch), cy), h[batch.a]], axis=-1)
    xc = (X - Ca) @ R0  # R0^T (X - C_a) for every row
    if not jacobian:
        uv = camera.project(xc)[0]
        return (batch.uv_a - uv).ravel()
    uv, Jp, _ = camera.project_jacobian(xc)
    res = (batch.uv_a - uv).ravel()
    dX = wall_offset_jacobian(X, R0, batch.eta_b)  # (M, 3, 3) w.r.t. C_b
    m = len(batch)
    # C_X and C_Y move both cameras; h_b moves the ray's origin, h_a the observing camera
    dxc = np.stack([(dX[:, :, 0] - np.array([1.0, 0.0, 0.0])) @ R0, (dX[:, :, 1] - np.array([0.0, 1.0, 0.0])) @ R0,
                    dX[:, :, 2] @ R0, np.broadcast_to(-E_H @ R0, (m, 3))], axis=-1)  # (M, 3, 4)
    blocks = -np.einsum("mij,mjk->mik", Jp, dxc)  # (M, 2, 4): C_X, C_Y, h_b, h_a
    cols = np.stack([np.zeros(m, int), np.ones(m, int), batch.b + 1, batch.a + 1], axis=-1)  # h_k -> column k + 1
    live = (np.arange(4) < 2) | (cols != 1)
    rows = np.broadcast_to(2 * np.arange(m)[:, None, None] + np.arange(2)[None, :, None], (m, 2, 4))
    cols2 = np.broadcast_to(cols[:, None, :], (m, 2, 4))
    keep = np.broadcast_to(live[:, None, :], (m, 2, 4))  # h_0 = 0 is fixed: no column
    J = csr_matrix((blocks[keep], (rows[keep], cols2[keep])), shape=(2 * m, n_kf + 1))
    return res, (J if sparse else J.toarray())


def _wall_from_centres(C: np.ndarray, d: np.ndarray, radius: float) -> np.ndarray:
    """Wall points of rays from per-row centres C (M, 3) along pipe-frame directions d (M, 3)."""
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (C[:, 0] * d[:, 0] + C[:, 1] * d[:, 1])
    c = C[:, 0] ** 2 + C[:, 1] ** 2 - radius**2
    kappa = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / np.maximum(2 * a, 1e-300)  # the positive root (eq. 37)
    return C + kappa[:, None] * d


@dataclass(frozen=True)
class OffsetResult:
    offset: np.ndarray  # (C_X, C_Y)
    heights: np.ndarray  # (K,) h_a, h_0 = 0
    rms_px: float
    pairs: int


def optimise_offset(batch: OffsetBatch, camera: CameraModel, radius: float, R0: np.ndarray, offset0, heights0,
                    max_offset_fraction: float = 0.9, outlier_px: float = 1.0) -> OffsetResult:
    """Eqs. 45-49 by Levenberg-Marquardt; starts from offset0 (C_X, C_Y) and heights0 (K,)."""
    x0 = np.r_[np.asarray(offset0, float), np.asarray(heights0, float)[1:]]
    if len(batch) < len(x0):
        raise ValueError(f"the offset batch has {len(batch)} observation pairs for {len(x0)} unknowns")
    x = x0
    for _ in range(2):  # solve, drop pairs beyond max(3 x 1.4826 MAD, 1 px) (mismatches), solve again
        fun = lambda x: offset_residuals(x, batch, R0, camera, radius)  # noqa: E731
        jac = lambda x: offset_residuals(x, batch, R0, camera, radius, jacobian=True, sparse=True)[1]  # noqa: E731
        x = levenberg_marquardt(lambda x: (fun(x), jac(x)), lambda x, d: x + d, x, iterations=100).state
        err = np.linalg.norm(fun(x).reshape(-1, 2), axis=1)
        keep = err <= max(3 * mad_sigma(err, centre=0.0), outlier_px)
        if keep.all() or keep.sum() < len(x0):
            break
        batch = batch.subset(keep)
    if np.hypot(x[0], x[1]) > max_offset_fraction * radius or not np.all(np.isfinite(x)):
        x = x0  # the batch left the pipe: keep the start rather than a camera outside the wall
    r = fun(x)
    return OffsetResult(x[:2].copy(), np.r_[0.0, x[2:]], float(np.sqrt(np.mean(r * r))), len(batch))
