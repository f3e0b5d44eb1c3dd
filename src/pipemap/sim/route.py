"""Crawler trajectories: the robot drives along the pipe axis, turns through tees on circular arcs.

The axis path is a polyline of joint vertices and junction centroids whose corners are replaced
by circular arcs (fillets): `turn_radius` at tees (about a pipe radius), a large radius at the
slight kinks of misaligned joints. The camera rides `offset_down_m` below the axis (the robot
sits on the pipe floor; world z is up), looks along the path tangent ('forward', the fisheye
robot) or up at the wall with image x along the pipe ('up', the 2010 report's cameras; `mount_deg`
turns it from square to the wall towards the direction of travel), and wobbles smoothly (a
function of distance driven, so a stopped robot is still).
Frames are spaced by distance (about `spacing_m`, varied smoothly: the speed changes); a
forward-and-reverse run drives to the end, stops, and drives back in reverse still facing
forward (the 2010 report's forward & reverse datasets).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.errors import PipemapError
from pipemap.geometry.rotations import exp_so3, look_rotation
from pipemap.trajectory import Trajectory

_UP = np.array([0.0, 0.0, 1.0])


class AxisPath:
    """Arc-length parametrised path: lines joined by circular arcs at every interior vertex."""

    def __init__(self, vertices: np.ndarray, turn_radius: float, kink_radius: float = 2.0, turn_deg: float = 10.0,
                 radii: np.ndarray | None = None):
        """`radii`: per vertex, a fillet radius that overrides the others (NaN: none), e.g. an elbow's
        bend radius, so the path follows its arc exactly; it must fit between the neighbouring vertices."""
        v = np.asarray(vertices, float)
        radii = np.full(len(v), np.nan) if radii is None else np.asarray(radii, float)
        if len(v) < 2:
            raise PipemapError("a route needs at least two points")
        seg = np.diff(v, axis=0)
        seg_len = np.linalg.norm(seg, axis=1)
        if np.any(seg_len <= 0):
            raise PipemapError("a route has repeated points")
        dirs = seg / seg_len[:, None]
        # tangent length of each interior corner's fillet
        tang = np.zeros(len(v))
        self._arcs = {}
        for k in range(1, len(v) - 1):
            d0, d1 = dirs[k - 1], dirs[k]
            alpha = float(np.arccos(np.clip(d0 @ d1, -1.0, 1.0)))
            if alpha < 1e-6:  # straight on (arccos is only good to ~1e-8 near 0)
                continue
            rho = turn_radius if np.degrees(alpha) >= turn_deg else kink_radius
            T = rho * np.tan(alpha / 2)
            if np.isfinite(radii[k]):
                T = radii[k] * np.tan(alpha / 2)
            else:
                T = min(T, 0.45 * seg_len[k - 1], 0.45 * seg_len[k])
            tang[k] = T
            self._arcs[k] = (alpha, T / np.tan(alpha / 2))
        if np.any(tang[:-1] + tang[1:] > seg_len + 1e-9):
            raise PipemapError("a route's bends overlap: a straight stretch is shorter than its arcs need")
        self.pieces = []  # ("line", p0, d, length) | ("arc", A, d0, n_in, rho, alpha)
        vertex_s = [0.0]
        s = 0.0
        for k in range(len(v) - 1):
            p0 = v[k] + tang[k] * dirs[k]
            L = seg_len[k] - tang[k] - tang[k + 1]
            self.pieces.append(("line", p0, dirs[k], L))
            s += L
            if k + 1 in self._arcs:
                alpha, rho = self._arcs[k + 1]
                d0, d1 = dirs[k], dirs[k + 1]
                n_in = d1 - (d1 @ d0) * d0
                n_in /= np.linalg.norm(n_in)
                A = v[k + 1] - tang[k + 1] * d0
                self.pieces.append(("arc", A, d0, n_in, rho, alpha))
                vertex_s.append(s + rho * alpha / 2)
                s += rho * alpha
            elif k + 1 < len(v) - 1:
                vertex_s.append(s)
        vertex_s.append(s)
        self.vertices = v
        self.vertex_s = np.array(vertex_s)  # arc length at which the path passes each vertex
        self.length = s
        self._starts = np.cumsum([0.0] + [self._plen(p) for p in self.pieces])[:-1]

    @staticmethod
    def _plen(p) -> float:
        return p[3] if p[0] == "line" else p[4] * p[5]

    def evaluate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and unit tangents (n, 3) at arc lengths s (clamped to the path)."""
        s = np.clip(np.atleast_1d(np.asarray(s, float)), 0.0, self.length)
        k = np.clip(np.searchsorted(self._starts, s, side="right") - 1, 0, len(self.pieces) - 1)
        pos = np.empty((len(s), 3))
        tan = np.empty((len(s), 3))
        for i, piece in enumerate(self.pieces):
            m = k == i
            if not m.any():
                continue
            x = s[m] - self._starts[i]
            if piece[0] == "line":
                _, p0, d, _ = piece
                pos[m] = p0 + x[:, None] * d
                tan[m] = d
            else:
                _, A, d0, n_in, rho, _ = piece
                phi = (x / rho)[:, None]
                C = A + rho * n_in
                pos[m] = C + rho * (-n_in * np.cos(phi) + d0 * np.sin(phi))
                tan[m] = d0 * np.cos(phi) + n_in * np.sin(phi)
        return pos, tan


def _smooth(x: np.ndarray, rng: np.random.Generator, periods: tuple[float, float], n: int = 3) -> np.ndarray:
    """Smooth zero-mean noise in [-1, 1]: a few sinusoids with random periods and phases."""
    p = rng.uniform(*periods, n)
    a = rng.uniform(0.5, 1.0, n)
    a /= a.sum()
    ph = rng.uniform(0, 2 * np.pi, n)
    return np.sum(a[:, None] * np.sin(2 * np.pi * np.asarray(x)[None, :] / p[:, None] + ph[:, None]), axis=0)


@dataclass(frozen=True)
class Drive:
    """How the robot drives: frame spacing, speed changes, camera mount and wobble."""

    spacing_m: float = 0.01
    speed_variation: float = 0.2  # +- fraction of the spacing, smooth over tens of frames
    ramp_frames: int = 10  # frames to reach full speed from a stop
    pause_frames: int = 8  # frames standing at the far end of a forward-and-reverse run
    offset_down_m: float = 0.04  # camera below the pipe axis
    offset_side_m: float = 0.0
    look: str = "forward"  # "forward" | "up"
    mount_deg: float = 90.0  # look "up": angle of the optical axis to the pipe axis (90: square to the wall,
    # less: turned towards the direction of travel, as wall cameras are mounted to see ahead)
    wobble_deg: float = 0.5
    wobble_m: float = 0.002
    turn_radius_m: float = 0.2
    start_m: float = 0.0  # distance along the path where the drive starts ...
    end_m: float | None = None  # ... and ends (None: the path's end; negative: from the end)
    reverse: bool = False  # forward and reverse: drive back to the start facing forward
    turns_m: tuple[float, ...] = ()  # on the way from start_m to end_m, stop at each of these and drive on back
    # to the next (an inspector backing up to look again at something passed), facing forward throughout

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def drive_distances(length: float, drive: Drive, seed: int, max_frames: int | None = None) -> np.ndarray:
    """Arc length of every frame: accelerate, cruise with smooth speed changes, stop at the end
    (and, for a forward-and-reverse run, pause and come back); at each of `turns_m` pause and drive on the other way."""
    if not drive.spacing_m > 0:
        raise PipemapError(f"frame spacing must be positive, got {drive.spacing_m}", key="spacing_m")
    rng = np.random.default_rng([int(seed) % 2**63, 7])
    s0 = drive.start_m
    s1 = length if drive.end_m is None else min(drive.end_m if drive.end_m >= 0 else length + drive.end_m, length)
    if not s1 > s0:
        raise PipemapError(f"the route is empty ({s0:.3f} m to {s1:.3f} m)")
    stops = [s0, *drive.turns_m, s1] + ([s0] if drive.reverse else [])
    if any(not s0 <= t <= s1 for t in drive.turns_m):
        raise PipemapError(f"turning points {list(drive.turns_m)} must lie on the route ({s0:.3f} m to {s1:.3f} m)")
    legs = [(a, b) for a, b in zip(stops[:-1], stops[1:]) if a != b]
    out: list[float] = []
    for leg, (a, b) in enumerate(legs):
        total = abs(b - a)
        est = int(total / (drive.spacing_m * (1 - drive.speed_variation)) + drive.ramp_frames + 2)
        k = np.arange(est)
        speed = 1 + drive.speed_variation * _smooth(k, rng, (40.0, 300.0))
        ramp = np.minimum(1.0, (k + 1) / max(1, drive.ramp_frames))
        steps = drive.spacing_m * speed * ramp
        d = np.concatenate([[0.0], np.cumsum(steps)])
        d = d[: np.searchsorted(d, total) + 1]
        d[-1] = min(d[-1], total)
        if len(d) > 1 and total - d[-2] < 0.25 * drive.spacing_m:
            d = np.concatenate([d[:-2], [total]])  # no tiny last step
        pos = a + np.sign(b - a) * d
        if leg:
            out += [a] * drive.pause_frames
            pos = pos[1:]
        out += list(pos)
        if max_frames is not None and len(out) >= max_frames:
            break
    s = np.array(out)
    return s if max_frames is None else s[:max_frames]


def camera_trajectory(path: AxisPath, s: np.ndarray, drive: Drive, fps: float, seed: int) -> Trajectory:
    """T_wc of the camera at arc lengths s; timestamps index / fps."""
    pos, tan = path.evaluate(s)
    up = _UP - (tan @ _UP)[:, None] * tan
    flat = np.linalg.norm(up, axis=1) < 1e-6
    up[flat] = np.cross(tan[flat], [0.0, 1.0, 0.0])
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    side = np.cross(tan, up)
    rng = np.random.default_rng([int(seed) % 2**63, 11])
    wob = [_smooth(s, rng, (0.3, 1.5)) for _ in range(5)]
    lateral = drive.offset_side_m + drive.wobble_m * wob[0]
    vertical = -drive.offset_down_m + drive.wobble_m * wob[1]
    centres = pos + lateral[:, None] * side + vertical[:, None] * up
    if drive.look == "forward":
        R_path = look_rotation(tan, up)
    elif drive.look == "up":
        # x along the pipe, z up at the wall, then turned about y so that z leans towards the travel
        a = np.radians(90.0 - drive.mount_deg)
        x_cam = np.cos(a) * tan - np.sin(a) * up
        z_cam = np.cos(a) * up + np.sin(a) * tan
        R_path = np.stack([x_cam, np.cross(z_cam, x_cam), z_cam], axis=-1)
    else:
        raise PipemapError(f"unknown camera direction {drive.look!r} (expected forward or up)")
    w = np.radians(drive.wobble_deg) * np.stack(wob[2:], axis=-1)
    R = R_path @ exp_so3(w)
    return Trajectory(np.arange(len(s)) / float(fps), centres, R)


def visits(path: AxisPath, s: np.ndarray, junctions) -> list[str]:
    """Junction ids in the order the camera passes them (the path vertex at each centroid)."""
    out = []
    if len(s) == 0:
        return out
    passed = np.zeros(len(path.vertices), bool)
    for k in range(1, len(path.vertices) - 1):
        sv = path.vertex_s[k]
        passed[k] = np.any((s[:-1] - sv) * (s[1:] - sv) <= 0) if len(s) > 1 else False
    for k in np.flatnonzero(passed):
        for j in junctions:
            if np.linalg.norm(path.vertices[k] - j.centroid) < 1e-6:
                out.append(j.id)
    return out
