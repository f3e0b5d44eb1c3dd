"""Keyframe poses from the S(g) sums (2010 report sections 5.3.1 and 5.3.3).

- One degree of freedom (eq. 40-44): a new keyframe keeps the previous keyframe's rotation and
  offset and moves by dh along the axis; Levenberg-Marquardt finds the dh whose wall points best
  agree with the stored estimates of the same points (eq. 42).
- Six degrees of freedom (5.3.3): every N keyframes each of the previous 2N (never the first,
  which fixes the frame) is refined in turn: its own estimates are taken out of S(g), its pose is
  optimised on eq. 42 over all six degrees of freedom, and its new estimates are put back.
- Crawler (two degrees of freedom): the same sweep, but a keyframe only turns about the pipe axis
  and moves along it, as a robot riding the wall does with its camera mount fixed. Both motions
  slide every wall estimate of the keyframe rigidly in (h, rho), so eq. 42's minimum is the
  n-weighted mean difference between the stored means and the keyframe's estimates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipemap.geometry.rotations import exp_so3
from pipemap.geometry.se3 import retract
from pipemap.solvers import levenberg_marquardt, mad_sigma
from pipemap.straight.sparse.geometry import E_H, wall_coords, wall_offset_jacobian, wall_points
from pipemap.straight.sparse.sums import WallSums


@dataclass
class KeyframeState:
    """One keyframe: its image index, keypoints (pixels, bearings, global indices) and pose."""

    index: int
    uv: np.ndarray  # (N, 2)
    bearings: np.ndarray  # (N, 3)
    gid: np.ndarray  # (N,)
    R: np.ndarray  # camera -> pipe axes
    C: np.ndarray  # camera centre in the pipe frame
    hr: np.ndarray = field(default=None)  # (N, 2) estimates currently in S(g); NaN where none

    def estimates(self, radius: float) -> np.ndarray:
        X, valid = wall_points(self.R, self.C, self.bearings, radius)
        hr = wall_coords(np.where(valid[:, None], X, 0.0), radius)
        hr[~valid] = np.nan
        return hr


def _one_dof_residuals(kf: KeyframeState, sums: WallSums, radius: float, used: np.ndarray):
    def evaluate(dh):
        C = kf.C + dh[0] * E_H
        X, valid = wall_points(kf.R, C, kf.bearings[used], radius)
        hr, J_hr = wall_coords(X, radius, jacobian=True)
        J_x = wall_offset_jacobian(X, kf.R, kf.bearings[used]) @ E_H  # (M, 3)
        r, J, _ = sums.residuals(kf.gid[used], hr, np.einsum("nij,nj->ni", J_hr, J_x)[:, :, None])
        return r, J
    return evaluate


def estimate_one_dof(kf: KeyframeState, sums: WallSums, radius: float, iterations: int = 20) -> tuple[float, int]:
    """Eq. 40-44: move kf.C along the axis by the dh that minimises eq. 42; returns (dh, points used)."""
    used = sums.n(kf.gid) > 0
    if used.sum() < 1:
        return 0.0, 0
    dh = levenberg_marquardt(_one_dof_residuals(kf, sums, radius, used), lambda s, d: s + d, np.zeros(1),
                             iterations=iterations).state
    kf.C = kf.C + dh[0] * E_H
    return float(dh[0]), int(used.sum())


def refine_six_dof(kf: KeyframeState, sums: WallSums, radius: float, iterations: int = 20) -> int:
    """5.3.3 for one keyframe: its estimates leave S(g), its pose is optimised (6 DOF), they return."""
    if kf.hr is not None:
        sums.add(kf.gid, kf.hr, -1.0)
    used = sums.n(kf.gid) > 0
    if used.sum() >= 3:
        b = kf.bearings[used]
        g = kf.gid[used]

        def evaluate(pose):
            X, valid, J_x = wall_points(pose[0], pose[1], b, radius, jacobian=True)
            hr, J_hr = wall_coords(X, radius, jacobian=True)
            r, J, _ = sums.residuals(g, hr, J_hr @ J_x)
            return r, J

        kf.R, kf.C = levenberg_marquardt(evaluate, lambda p, d: retract(p[0], p[1], d), (kf.R, kf.C),
                                         iterations=iterations).state
    kf.hr = kf.estimates(radius)
    sums.add(kf.gid, kf.hr)
    return int(used.sum())


def refine_crawler(kf: KeyframeState, sums: WallSums, radius: float) -> int:
    """Eq. 42 over the keyframe's roll psi about the axis and travel dh along it, in closed form: turning by
    psi and moving by dh take every wall estimate (h, rho) to (h + dh, rho + r psi)."""
    if kf.hr is not None:
        sums.add(kf.gid, kf.hr, -1.0)
    hr = kf.estimates(radius)
    used = (sums.n(kf.gid) > 0) & np.all(np.isfinite(hr), axis=1)
    if used.any():
        n = sums.n(kf.gid[used])
        dh, drho = n @ (sums.means(kf.gid[used]) - hr[used]) / n.sum()
        turn = exp_so3(np.array([0.0, 0.0, drho / radius]))
        kf.R, kf.C = turn @ kf.R, turn @ kf.C + dh * E_H
        hr = kf.estimates(radius)
    kf.hr = hr
    sums.add(kf.gid, kf.hr)
    return int(used.sum())


def gate_outliers(kf: KeyframeState, sums: WallSums, hr: np.ndarray, mad_k: float, floor_m: float) -> np.ndarray:
    """Estimates farther from their point's mean than max(mad_k x 1.4826 MAD, floor_m): mismatches
    that passed RANSAC. Returns their mask; the caller gives them new global indices."""
    used = sums.n(kf.gid) > 0
    d = np.full(len(kf.gid), 0.0)
    d[used] = np.linalg.norm(hr[used] - sums.means(kf.gid[used]), axis=1)
    d[~np.all(np.isfinite(hr), axis=1)] = np.inf
    if used.sum() < 3:
        return used & ~np.isfinite(d)
    limit = max(mad_k * mad_sigma(d[used], centre=0.0), floor_m)
    return used & (d > limit)
