"""Exact ray casting of camera bearings against the union of a network's solid cylinders and bends.

The pipe interior is the union of the solid pieces. A camera inside it sees, along each ray,
the first point where the ray leaves the union: the nearest point that lies on a piece's
lateral wall (within the piece's extent) or on a closed end cap, and that is not strictly
inside any other piece. Everything is vectorised over rays; loops run over the few pieces
near the camera only.

Fast path: a ray stays inside a piece that contains the camera until it leaves that piece's
wall, so when that exit point lies in a stretch of wall that no other piece reaches it is the
answer. Only the remaining rays (near tees, joints and ends) are tested against every nearby
piece.

Bends (an elbow's torus piece) are intersected exactly: the ray meets the torus where a quartic
in t vanishes (geometry.torus: Ferrari's method, polished by Newton steps, in float64 whatever the
caster's dtype), and a root counts where it lies within the bend's angle. Hits on a bend report
h = bend radius x theta, the chainage along its arc.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.geometry.torus import ray_torus
from pipemap.sim.network_model import PipeScene
from pipemap.sim.wall_shape import refine_hits, shaped_lines


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
        self.K = len(pipes)
        self.bends = scene.bends
        # geometric tolerances: extents are widened (no cracks at seams), "inside" is strict
        self.eps_h = 1e-4 if self.dtype == np.float32 else 1e-10
        self.inside_tol = 1e-3 if self.dtype == np.float32 else 1e-9
        self.neighbours, self.zones = self._adjacency()
        self.shaped = shaped_lines(scene)

    # -- set-up ---------------------------------------------------------------------------------

    def _adjacency(self):
        """Pieces whose solids may overlap, and per straight piece the h intervals a neighbour may reach.
        A bend counts by points along its arc (16 chords: each within R (1 - cos(angle / 32)) of it)."""
        K = len(self.scene.pipes)
        ends0 = self.start + self.lo[:, None] * self.axis
        ends1 = self.start + self.hi[:, None] * self.axis
        lines = [np.stack([ends0[i], ends1[i]]) for i in range(K)]
        slack = [0.0] * K
        for b in self.bends:
            lines.append(b.axis_point(np.linspace(0.0, b.angle, 17)))
            slack.append(b.bend_radius * (1 - np.cos(b.angle / 32)))
        n = len(lines)
        neighbours: list[list[int]] = [[] for _ in range(n)]
        zones: list[list[tuple[float, float]]] = [[] for _ in range(K)]
        for i in range(n):
            for k in range(n):
                if i == k:
                    continue
                if _polyline_distance(lines[i], lines[k]) < 2 * self.r + 0.02 + slack[i] + slack[k]:
                    neighbours[i].append(k)
                    if i < K:
                        hk = (lines[k] - self.start[i]) @ self.axis[i]
                        zones[i].append((min(hk) - self.r - 1e-3 - slack[k], max(hk) + self.r + 1e-3 + slack[k]))
        return [np.array(nb, int) for nb in neighbours], zones

    def _nearby(self, origin: np.ndarray) -> tuple[np.ndarray, list[int]]:
        """Indices of the pieces to test (straight ones first, then bends at K + m), and the straight
        pieces that contain the camera."""
        q = origin - self.start
        h = np.einsum("kj,kj->k", q, self.axis)
        rad = np.linalg.norm(q - h[:, None] * self.axis, axis=1)
        homes = list(np.flatnonzero((h > self.lo) & (h < self.hi) & (rad < self.r)))
        homes.sort(key=lambda k: rad[k])
        dist = np.linalg.norm(q - np.clip(h, self.lo, self.hi)[:, None] * self.axis, axis=1) - self.r
        if self.bends:
            dist = np.concatenate([dist, [float(b.axis_distance(origin)) - self.r for b in self.bends]])
        near = dist < self.cull
        if not homes:
            return np.flatnonzero(near), homes
        keep = np.zeros(len(dist), bool)
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
        bend_cand = cand[cand >= self.K] - self.K
        cand = cand[cand < self.K]
        t_out = np.full(n, np.inf, self.dtype)
        pipe_out = np.full(n, -1, np.int32)
        cap_out = np.zeros(n, bool)
        h_out = np.zeros(n, self.dtype)
        if (cand.size == 0 and bend_cand.size == 0) or n == 0:
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
        geo.bends = _BendGeometry(self, bend_cand, R, origin)
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
        hits = Hits(t_out, pipe_out, cap_out, h_out)
        if self.shaped:
            refine_hits(self.shaped, self.r, R, origin, B, hits)
        return hits

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
                bend_others = geo.bends.positions(self.neighbours[gj])
                best_sub = best if sub is None else best[sub]
                for t, h, ok, is_cap in cands:
                    ok = ok & (t > 0) & (t < best_sub)
                    idx = np.flatnonzero(ok)
                    if idx.size == 0:
                        continue
                    idx, ti = _outside(geo, rows, idx, t[idx], others, bend_others, dt)
                    hi_ = h[idx]
                    best_sub[idx] = ti
                    out = idx if sub is None else sub[idx]
                    best[out], pipe[out], cap[out], hbest[out] = ti, gj, is_cap, hi_
            if geo.bends.count:
                self._full_bends(geo, B, pos, best, pipe, cap, hbest)
        return best, pipe, cap, hbest

    def _full_bends(self, geo: "_Geometry", B: np.ndarray, pos: dict, best, pipe, cap, hbest) -> None:
        """The bends' share of _full: their torus hits within their angle, not inside a neighbour."""
        bg = geo.bends
        dt = self.dtype
        for m in range(bg.count):
            b = int(bg.cand[m])
            sub = bg.cone_rays(m, B)
            if sub.size == 0:
                continue
            rows = B[:, sub]
            roots, h_all, ok_all = bg.hits(m, rows)
            gk = self.K + b
            others = [pos[k] for k in self.neighbours[gk] if k in pos]
            bend_others = [o for o in bg.positions(self.neighbours[gk]) if o != m]
            best_sub = best[sub]
            for i in range(roots.shape[1]):
                t = roots[:, i].astype(dt)
                ok = ok_all[:, i] & (t > 0) & (t < best_sub)
                idx = np.flatnonzero(ok)
                if idx.size == 0:
                    continue
                idx, ti = _outside(geo, rows, idx, t[idx], others, bend_others, dt)
                best_sub[idx] = ti
                out = sub[idx]
                best[out], pipe[out], cap[out], hbest[out] = ti, gk, False, h_all[idx, i].astype(dt)


def _outside(geo: "_Geometry", rows: np.ndarray, idx: np.ndarray, ti: np.ndarray, others: list[int],
             bend_others: list[int], dt) -> tuple[np.ndarray, np.ndarray]:
    """The candidate hits (rays `idx` of `rows` at distances `ti`) that lie inside none of the neighbouring
    straight pieces `others` and bends `bend_others`: a point inside another solid is not on the boundary."""
    for k in others:
        Bi = rows[:, idx]
        idx_in = geo.inside(k, ti, _dot(Bi, geo.u_c[k], dt), _dot(Bi, geo.a_c[k], dt))
        if idx_in.any():
            idx, ti = idx[~idx_in], ti[~idx_in]
    for k in bend_others:
        idx_in = geo.bends.inside(k, ti, rows[:, idx])
        if idx_in.any():
            idx, ti = idx[~idx_in], ti[~idx_in]
    return idx, ti


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


class _BendGeometry:
    """The candidate bends seen from one camera pose: each bend's frame scaled by its bend radius, so a
    camera-frame ray D maps to o + t * (M @ D) there (float64 whatever the caster's dtype)."""

    def __init__(self, caster: RayCaster, cand: np.ndarray, R_wc: np.ndarray, origin: np.ndarray):
        self.caster = caster
        self.cand = np.asarray(cand, int)
        self.count = len(self.cand)
        self.o, self.M, self.minor, self.eps, self.cone, self.c_unit = [], [], [], [], [], []
        for b in (caster.bends[i] for i in self.cand):
            E = b.basis / b.bend_radius
            self.o.append(E @ (origin - b.centre))
            self.M.append(E @ R_wc)
            self.minor.append(caster.r / b.bend_radius)
            self.eps.append(caster.eps_h / b.bend_radius)
            # bounding sphere about the arc's midpoint: every arc point within 2 R sin(angle / 4)
            mid = b.axis_point(b.angle / 2)
            rho = (2 * b.bend_radius * np.sin(b.angle / 4) + caster.r) * 1.001 + 1e-6
            c = (mid - origin) @ R_wc
            dist = float(np.linalg.norm(c))
            self.cone.append(np.sqrt(max(0.0, 1 - (rho / dist) ** 2)) - 1e-5 if dist > rho else -2.0)
            self.c_unit.append(c / max(dist, 1e-12))

    def positions(self, pieces) -> list[int]:
        """Positions in this list of the bends among `pieces` (indices of the whole union)."""
        where = {int(b) + self.caster.K: m for m, b in enumerate(self.cand)}
        return [where[int(k)] for k in pieces if int(k) in where]

    def cone_rays(self, m: int, B: np.ndarray) -> np.ndarray:
        if self.cone[m] <= -1:
            return np.arange(B.shape[1])
        return np.flatnonzero(_dot(B, self.c_unit[m], self.caster.dtype) >= self.caster.dtype.type(self.cone[m]))

    def _local(self, m: int, rows: np.ndarray) -> np.ndarray:
        return self.M[m] @ np.asarray(rows, float)

    def hits(self, m: int, rows: np.ndarray):
        """Torus roots t (n, 4) in metres (NaN: none), their h along the arc, and whether each lies
        within the bend's angle (widened by the caster's seam tolerance)."""
        b = self.caster.bends[int(self.cand[m])]
        d = self._local(m, rows)
        # rows are unit vectors; in the scaled frame they have length 1 / R: solve there with unit dirs
        t = ray_torus(self.o[m], d * b.bend_radius, self.minor[m])
        p = self.o[m][:, None, None] + d[:, :, None] * (t * b.bend_radius)[None]
        theta = np.arctan2(p[1], p[0])
        with np.errstate(invalid="ignore"):
            ok = (theta >= -self.eps[m]) & (theta <= b.angle + self.eps[m]) & np.isfinite(t)
        return np.where(np.isfinite(t), t * b.bend_radius, np.inf), theta * b.bend_radius, ok

    def inside(self, m: int, t: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Whether the points t * D lie strictly inside candidate bend m."""
        c = self.caster
        b = c.bends[int(self.cand[m])]
        p = self.o[m][:, None] + self._local(m, rows) * np.asarray(t, float)
        theta = np.arctan2(p[1], p[0])
        d2 = (np.hypot(p[0], p[1]) - 1.0) ** 2 + p[2] ** 2
        margin = 10 * self.eps[m]
        return (theta > margin) & (theta < b.angle - margin) & (d2 < self.minor[m] ** 2 * (1 - c.inside_tol))


def _polyline_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Shortest distance between two polylines (see _segment_distance for its accuracy)."""
    return min(_segment_distance(a[i], a[i + 1], b[k], b[k + 1]) for i in range(len(a) - 1) for k in range(len(b) - 1))


def _segment_distance(p0, p1, q0, q1) -> float:
    """Shortest distance between segments p0-p1 and q0-q1: exact point-to-segment distances
    from 1025 points along the first, an overestimate by at most a thousandth of its length."""
    s = np.linspace(0.0, 1.0, 1025)[:, None]
    P = p0 + s * (p1 - p0)
    ab = q1 - q0
    tt = np.clip((P - q0) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return float(np.min(np.linalg.norm(P - (q0 + tt[:, None] * ab), axis=1)))
