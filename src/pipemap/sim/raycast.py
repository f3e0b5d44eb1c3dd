"""Exact ray casting of camera bearings against the union of a network's solid cylinders.

The pipe interior is the union of the solid pieces. A camera inside it sees, along each ray,
the first point where the ray leaves the union: the nearest point that lies on a piece's
lateral wall (within the piece's extent) or on a closed end cap, and that is not strictly
inside any other piece. Everything is vectorised over rays; loops run over the few pieces
near the camera only.

Fast path: a ray stays inside a piece that contains the camera until it leaves that piece's
wall, so when that exit point lies in a stretch of wall that no other piece reaches it is the
answer. Only the remaining rays (near tees, joints and ends) are tested against every nearby
piece.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.sim.network_model import PipeScene


@dataclass
class Hits:
    """Per ray: distance t along the unit bearing (inf: no hit), piece index (-1: none), whether
    the hit is on an end cap, and h, metres along the piece's axis from its nominal start."""

    t: np.ndarray
    pipe: np.ndarray
    cap: np.ndarray
    h: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.pipe >= 0


class RayCaster:
    """Casts rays from a camera pose into a `PipeScene`.

    `cull_distance_m`: pieces farther than this from the camera are ignored (their walls are
    unlit by the robot's LEDs at such distances anyway); `max_hops`: only pieces within this many
    joints of the piece holding the camera are considered. `dtype` float32 for rendering,
    float64 for exact geometry.
    """

    def __init__(self, scene: PipeScene, *, cull_distance_m: float = 15.0, max_hops: int = 4, dtype=np.float32):
        self.scene = scene
        self.dtype = np.dtype(dtype)
        self.cull = float(cull_distance_m)
        self.max_hops = int(max_hops)
        pipes = scene.pipes
        self.r = float(scene.radius)
        self.start = np.array([p.start for p in pipes], float)
        self.axis = np.array([p.axis for p in pipes], float)
        self.length = np.array([p.length for p in pipes])
        self.lo = -np.array([p.extend_start for p in pipes])
        self.hi = self.length + np.array([p.extend_end for p in pipes])
        self.closed = [(p.closed_start, p.closed_end) for p in pipes]
        # geometric tolerances: extents are widened (no cracks at seams), "inside" is strict
        self.eps_h = 1e-4 if self.dtype == np.float32 else 1e-10
        self.inside_tol = 1e-3 if self.dtype == np.float32 else 1e-9
        self.neighbours, self.zones = self._adjacency()

    # -- set-up ---------------------------------------------------------------------------------

    def _adjacency(self):
        """Pieces whose solids may overlap, and per piece the h intervals a neighbour may reach."""
        K = len(self.scene.pipes)
        ends0 = self.start + self.lo[:, None] * self.axis
        ends1 = self.start + self.hi[:, None] * self.axis
        neighbours: list[list[int]] = [[] for _ in range(K)]
        zones: list[list[tuple[float, float]]] = [[] for _ in range(K)]
        for i in range(K):
            for k in range(K):
                if i == k:
                    continue
                if _segment_distance(ends0[i], ends1[i], ends0[k], ends1[k]) < 2 * self.r + 0.02:
                    neighbours[i].append(k)
                    hk = [(e - self.start[i]) @ self.axis[i] for e in (ends0[k], ends1[k])]
                    zones[i].append((min(hk) - self.r - 1e-3, max(hk) + self.r + 1e-3))
        return [np.array(n, int) for n in neighbours], zones

    def _nearby(self, origin: np.ndarray) -> tuple[np.ndarray, list[int]]:
        """Indices of the pieces to test, and the pieces that contain the camera."""
        q = origin - self.start
        h = np.einsum("kj,kj->k", q, self.axis)
        rad = np.linalg.norm(q - h[:, None] * self.axis, axis=1)
        homes = list(np.flatnonzero((h > self.lo) & (h < self.hi) & (rad < self.r)))
        homes.sort(key=lambda k: rad[k])
        dist = np.linalg.norm(q - np.clip(h, self.lo, self.hi)[:, None] * self.axis, axis=1) - self.r
        near = dist < self.cull
        if not homes:
            return np.flatnonzero(near), homes
        keep = np.zeros(len(h), bool)
        frontier = list(homes)
        keep[frontier] = True
        for _ in range(self.max_hops):
            nxt = [k for i in frontier for k in self.neighbours[i] if not keep[k] and near[k]]
            keep[nxt] = True
            frontier = nxt
        return np.flatnonzero(keep), homes

    # -- casting ----------------------------------------------------------------------------------

    def cast(self, R_wc: np.ndarray, t_wc: np.ndarray, bearings: np.ndarray) -> Hits:
        """Rays from the camera centre t_wc along `bearings` (N, 3), unit vectors in the camera
        frame (x right, y down, z forward); R_wc maps camera to world axes."""
        B = np.ascontiguousarray(np.asarray(bearings, self.dtype).reshape(-1, 3).T)
        return self.cast_components(R_wc, t_wc, B)

    def cast_components(self, R_wc: np.ndarray, t_wc: np.ndarray, B: np.ndarray) -> Hits:
        """As cast(), with the bearings as a (3, N) array of components (renderers cache this
        layout: dot products with a 3-vector are then three fused passes, no BLAS call)."""
        R = np.asarray(R_wc, float)
        origin = np.asarray(t_wc, float)
        B = np.asarray(B, self.dtype)
        n = B.shape[1]
        cand, homes = self._nearby(origin)
        t_out = np.full(n, np.inf, self.dtype)
        pipe_out = np.full(n, -1, np.int32)
        cap_out = np.zeros(n, bool)
        h_out = np.zeros(n, self.dtype)
        if cand.size == 0 or n == 0:
            return Hits(t_out, pipe_out, cap_out, h_out)
        # Each candidate in the camera frame, re-based at its axis point nearest the camera so
        # that the quadratic's constant term keeps its precision in float32.
        h0 = np.clip(np.einsum("kj,kj->k", origin - self.start[cand], self.axis[cand]), self.lo[cand], self.hi[cand])
        base_w = self.start[cand] + h0[:, None] * self.axis[cand]
        a_c = (base_w - origin) @ R  # rows: R^T (base - origin)
        u_c = self.axis[cand] @ R
        geo = _Geometry(a_c, u_c, h0, self, cand)
        # bounding sphere of each piece: rays from outside it must lie in a cone around it
        mid = (self.lo[cand] + self.hi[cand]) / 2
        c_c = (self.start[cand] + mid[:, None] * self.axis[cand] - origin) @ R
        rho = np.hypot((self.hi[cand] - self.lo[cand]) / 2, self.r) * 1.001 + 1e-6
        dist = np.linalg.norm(c_c, axis=1)
        geo.cone = np.where(dist > rho, np.sqrt(np.maximum(0.0, 1 - (rho / np.maximum(dist, 1e-12)) ** 2)) - 1e-5, -2.0)
        geo.order = np.argsort(dist - rho)  # near pieces first: later ones are pruned by t < best
        geo.c_unit = c_c / np.maximum(dist, 1e-12)[:, None]
        rest = None
        if homes:
            j = int(np.flatnonzero(cand == homes[0])[0])
            du, da = _dot(B, u_c[j], self.dtype), _dot(B, a_c[j], self.dtype)
            t2 = geo.exit_root(j, du, da)
            h = t2 * du + self.dtype.type(geo.h_off[j])
            free = (h >= self.lo[homes[0]]) & (h <= self.hi[homes[0]])
            for z0, z1 in self.zones[homes[0]]:
                free &= (h < z0) | (h > z1)
            t_out[free], pipe_out[free], h_out[free] = t2[free], homes[0], h[free]
            rest = np.flatnonzero(~free)
        if rest is None:
            t_out, pipe_out, cap_out, h_out = self._full(geo, B)
        elif rest.size:
            t, p, c, h = self._full(geo, B[:, rest])
            t_out[rest], pipe_out[rest], cap_out[rest], h_out[rest] = t, p, c, h
        return Hits(t_out, pipe_out, cap_out, h_out)

    def cast_world(self, origin: np.ndarray, directions: np.ndarray) -> Hits:
        """Rays from a world point along world directions (normalised here)."""
        d = np.asarray(directions, float)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return self.cast(np.eye(3), origin, d)

    def _full(self, geo: "_Geometry", B: np.ndarray):
        """Nearest valid boundary point over every candidate piece, for the rays B (3, M).

        A ray is tested against a piece only when it passes through the piece's bounding
        sphere (a cone test on D.c)."""
        m = B.shape[1]
        f = self.dtype.type
        dt = self.dtype
        best = np.full(m, np.inf, dt)
        pipe = np.full(m, -1, np.int32)
        cap = np.zeros(m, bool)
        hbest = np.zeros(m, dt)
        pos = {int(c): i for i, c in enumerate(geo.cand)}
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for j in geo.order:
                gj = int(geo.cand[j])
                cos_min = geo.cone[j]
                sub = None if cos_min <= -1 else np.flatnonzero(_dot(B, geo.c_unit[j], dt) >= f(cos_min))
                if sub is not None and sub.size == 0:
                    continue
                rows = B if sub is None else B[:, sub]
                du, da = _dot(rows, geo.u_c[j], dt), _dot(rows, geo.a_c[j], dt)
                offs = f(geo.h_off[j])
                lo, hi = self.lo[gj] - self.eps_h, self.hi[gj] + self.eps_h
                cands = []
                for t in geo.roots(j, du, da):
                    h = t * du + offs
                    cands.append((t, h, (h >= lo) & (h <= hi), False))
                for end, closed in enumerate(self.closed[gj]):
                    if not closed:
                        continue
                    hc = f(0.0 if end == 0 else self.length[gj])
                    t = (hc - offs) / du
                    rad2 = t * t - 2 * t * da + f(geo.aa[j]) - (hc - f(geo.h0[j])) ** 2
                    cands.append((t, np.full(rows.shape[1], hc, dt), rad2 <= f(self.r**2), True))
                others = [pos[k] for k in self.neighbours[gj] if k in pos]
                best_sub = best if sub is None else best[sub]
                for t, h, ok, is_cap in cands:
                    ok = ok & (t > 0) & (t < best_sub)
                    idx = np.flatnonzero(ok)
                    if idx.size == 0:
                        continue
                    ti = t[idx]
                    for k in others:
                        Bi = rows[:, idx]
                        idx_in = geo.inside(k, ti, _dot(Bi, geo.u_c[k], dt), _dot(Bi, geo.a_c[k], dt))
                        if idx_in.any():
                            keep = ~idx_in
                            idx, ti = idx[keep], ti[keep]
                    hi_ = h[idx]
                    best_sub[idx] = ti
                    out = idx if sub is None else sub[idx]
                    best[out], pipe[out], cap[out], hbest[out] = ti, gj, is_cap, hi_
        return best, pipe, cap, hbest


def _dot(B: np.ndarray, v: np.ndarray, dtype) -> np.ndarray:
    """(3, N) components . 3-vector, without BLAS (whose threads stall beside a busy writer thread)."""
    f = dtype.type
    out = B[0] * f(v[0])
    out += B[1] * f(v[1])
    out += B[2] * f(v[2])
    return out


class _Geometry:
    """The candidate pieces in the camera frame (rows of a_c, u_c) and their quadratic terms."""

    def __init__(self, a_c, u_c, h0, caster: RayCaster, cand):
        self.caster = caster
        self.cand = cand
        self.a_c, self.u_c = a_c, u_c
        self.au = np.einsum("kj,kj->k", a_c, u_c)  # ~0 by construction (base nearest camera)
        self.aa = np.einsum("kj,kj->k", a_c, a_c)
        self.C = self.aa - self.au**2 - caster.r**2
        self.h0 = h0
        self.h_off = h0 - self.au  # h = t * (D.u) + h_off
        self.dtype = caster.dtype

    def roots(self, j, du, da):
        f = self.dtype.type
        A = 1 - du * du
        Bh = da - du * f(self.au[j])
        C = f(self.C[j])
        disc = Bh * Bh - A * C
        s = np.sqrt(np.maximum(disc, 0))
        q = Bh + np.copysign(s, Bh)
        ta, tb = q / A, C / q
        real = disc >= 0
        t1 = np.where(real, np.minimum(ta, tb), np.nan)
        t2 = np.where(real, np.maximum(ta, tb), np.nan)
        return t1, t2

    def exit_root(self, j, du, da):
        """The far root for a piece that contains the camera (C < 0: always real)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.roots(j, du, da)[1]

    def inside(self, k, t, du, da) -> np.ndarray:
        """Whether the points t * D lie strictly inside candidate piece k."""
        f = self.dtype.type
        c = self.caster
        g = int(self.cand[k])
        h = t * du + f(self.h_off[k])
        # |P - a|^2 - ((P - a).u)^2 with P = t D, a the re-based axis point
        hr = t * du - f(self.au[k])
        rad2 = t * t - 2 * t * da + f(self.aa[k]) - hr * hr
        margin = c.eps_h * 10
        return (h > c.lo[g] + margin) & (h < c.hi[g] - margin) & (rad2 < f(c.r**2 * (1 - c.inside_tol)))


def _segment_distance(p0, p1, q0, q1) -> float:
    """Shortest distance between segments p0-p1 and q0-q1: exact point-to-segment distances
    from 1025 points along the first, an overestimate by at most a thousandth of its length."""
    s = np.linspace(0.0, 1.0, 1025)[:, None]
    P = p0 + s * (p1 - p0)
    ab = q1 - q0
    tt = np.clip((P - q0) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return float(np.min(np.linalg.norm(P - (q0 + tt[:, None] * ab), axis=1)))
