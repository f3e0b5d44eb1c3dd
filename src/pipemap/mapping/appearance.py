"""Dense grey-level appearance map of the pipe wall (fisheye paper IV-B, Fig. 7).

Every piece's wall is sampled on a regular (h, r*phi) grid (wall.py). Each grid point is mapped
into every keyframe image, and its grey level is the mean of the bilinear samples over the
keyframes that see it at a colatitude min_theta < theta < max_theta (the paper: 50..90 deg, the
periphery of the fisheye image where its resolution is highest). Keyframe images are read
once each, in order. Points that no keyframe sees are dropped. The sums behind the means are held only
for the wall the keyframes still to come can reach (`_Sums`), so that memory follows the length of the
map at 5 bytes a point rather than 21.

The mean is weighted: a sample's weight rises smoothly from 0 to 1 over `edge_taper_deg` inside
either colatitude limit. Lighting and vignetting change strongly with colatitude, so a plain
mean jumps wherever one more keyframe's band edge starts to count, striping the map at the
keyframe spacing; the taper makes each keyframe's contribution fade in and out instead.

Per keyframe only the grid rows that can lie in the colatitude band are projected (a window
around the camera along each piece's axis), and a point on another piece than the camera's
own (seen through a tee's opening) counts only if the line of sight stays inside the pipes.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator

import cv2
import numpy as np
from plyfile import PlyData

from pipemap.config import AppearanceSettings
from pipemap.dataset import Dataset, Frame
from pipemap.errors import PipemapError
from pipemap.geometry.se3 import as_rt
from pipemap.mapping.exposure import ExposureLevels
from pipemap.mapping.wall import (
    INSIDE_MARGIN_SPACINGS,
    WallGrid,
    WallPiece,
    in_line_of_sight,
    inside_piece,
    opening_mask,
    wall_grid,
)
from pipemap.mapping.unrolled import write_unrolled
from pipemap.output import replacing
from pipemap.inspection.route import piece_start_chainage, route_segment_of

# Wall farther from the camera than this many radii / sin(min_theta) is not sampled. In a straight
# pipe the band ends at (r + offset) / sin(min_theta); farther wall is seen only at grazing angles
# (down the next pipe from a tee), where one pixel covers centimetres and would blur the map.
REACH_RADII = 2.0
REACH_TAPER = 0.25  # fraction of the reach over which samples fade out (with edge_taper_deg > 0)
_REMAP_WIDTH = 1024  # cv2.remap maps are kept 2-D and below its 32767 size limit
ACCUMULATOR_ROWS = 128  # grid rows per block of sums (_Sums): 0.26 m of wall at 2 mm
PLY_ROWS = 256  # grid rows located and written at a time (about 160,000 points of a 400 mm pipe)
LIGHT_FIELD_FRAMES = 40  # keyframes spread along the run whose median is the light field (exposure.py)


@dataclass
class PieceMap:
    """The appearance of one piece on its grid: the weighted mean grey level of every point."""

    grid: WallGrid
    keep_bits: np.ndarray  # (H, ceil(W / 8)) np.packbits of (H, W) bool: False inside another piece's opening
    values: np.ndarray  # (H, W) float32 mean grey level, NaN where unseen or not wall (read-only)

    @classmethod
    def empty(cls, grid: WallGrid, keep: np.ndarray) -> "PieceMap":
        """No grey levels yet; `keep` is held as bits (a byte a grid point had been 80 MB on a 256 m run)."""
        return cls(grid, np.packbits(keep, axis=1), np.full(grid.shape, np.nan, np.float32))

    def keep(self, rows: slice = slice(None)) -> np.ndarray:
        """(rows, W) bool: not inside another piece's opening."""
        return np.unpackbits(self.keep_bits[rows], axis=1, count=self.grid.shape[1]).view(bool)

    @property
    def piece(self) -> WallPiece:
        return self.grid.piece

    @property
    def seen(self) -> np.ndarray:
        return self.seen_rows()

    @property
    def intensity(self) -> np.ndarray:
        """(H, W) float32 mean grey level, NaN where unseen or not wall."""
        return self.values

    def seen_rows(self, rows: slice = slice(None)) -> np.ndarray:
        return np.isfinite(self.values[rows])

    def intensity_rows(self, rows: slice = slice(None)) -> np.ndarray:
        """`intensity` of the grid rows `rows` alone."""
        return self.values[rows]


class _Sums:
    """One piece's weighted sums of grey samples, ACCUMULATOR_ROWS grid rows to a block. A block is made when a
    keyframe first adds to it and turned into the piece's grey levels once the last keyframe that reaches its
    rows has been sampled, so that only the wall around the camera holds sums (on paper-loop route A all of
    them, 21 bytes a point, had been 210 MB; a long run's grew with it)."""

    def __init__(self, pm: PieceMap):
        self.pm = pm
        self.blocks: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def add(self, ii: np.ndarray, jj: np.ndarray, w: np.ndarray, values: np.ndarray) -> None:
        """(ii, jj) pairs are distinct within one keyframe, so fancy-index addition is exact."""
        block = ii // ACCUMULATOR_ROWS
        for b in np.unique(block).tolist():
            sel = block == b
            total, weight = self._block(b)
            i, j = ii[sel] - b * ACCUMULATOR_ROWS, jj[sel]
            total[i, j] += w[sel] * values[sel]
            weight[i, j] += w[sel]

    def _block(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        if b not in self.blocks:
            rows = min(ACCUMULATOR_ROWS, self.pm.grid.shape[0] - b * ACCUMULATOR_ROWS)
            shape = (rows, self.pm.grid.shape[1])
            self.blocks[b] = (np.zeros(shape), np.zeros(shape))
        return self.blocks[b]

    def close(self, b: int) -> None:
        """Block b's sums into mean (exposure-normalised) grey levels: no later keyframe reaches its rows."""
        if b not in self.blocks:
            return
        total, weight = self.blocks.pop(b)
        rows = slice(b * ACCUMULATOR_ROWS, b * ACCUMULATOR_ROWS + len(total))
        with np.errstate(invalid="ignore", divide="ignore"):
            out = (total / weight).astype(np.float32)
        out[~(self.pm.keep(rows) & (weight > 0))] = np.nan
        self.pm.values[rows] = out

    def finish(self, reference: float) -> None:
        """Every block closed, the means scaled to the exposure levels' `reference` grey level (known once every
        keyframe is read) and limited to 255 (a normalised level can pass it)."""
        for b in list(self.blocks):
            self.close(b)
        values = self.pm.values
        for start in range(0, len(values), ACCUMULATOR_ROWS):
            rows = slice(start, start + ACCUMULATOR_ROWS)
            values[rows] = np.minimum(values[rows] * reference, 255.0)
        values.flags.writeable = False


@dataclass
class AppearanceMap:
    pieces: list[PieceMap]
    keyframes: int  # keyframe images used
    projections: int  # grid points projected into keyframes
    samples: int  # of which inside the colatitude band, the image and in sight
    seconds: float
    settings: AppearanceSettings = field(default_factory=AppearanceSettings)
    exposure: dict | None = None  # the keyframes' exposure levels (exposure.py), when normalised

    @property
    def points_per_second(self) -> float:
        return self.projections / self.seconds if self.seconds > 0 else float("nan")

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """The seen grid points (N, 3) and their mean grey level (N,), piece after piece."""
        pts, vals = [], []
        for pm in self.pieces:
            seen = pm.seen
            pts.append(pm.grid.points()[seen])
            vals.append(pm.intensity[seen])
        if not pts:
            return np.zeros((0, 3)), np.zeros(0, np.float32)
        return np.concatenate(pts), np.concatenate(vals)

    def piece(self, name: str) -> PieceMap:
        for pm in self.pieces:
            if pm.piece.name == name:
                return pm
        raise KeyError(name)


def colatitude_band(settings: AppearanceSettings, camera) -> tuple[float, float]:
    """(lowest, highest) colatitude in degrees of the pixels that are sampled. Unset limits follow the
    camera's view: up to 90 deg or the widest colatitude its image holds (the wall nearest the camera,
    seen at its finest), and down from there to 5/9 of it (the paper's 50..90 deg band on its 190 deg
    lens; 32..58 deg on a 100 deg perspective camera)."""
    hi = settings.max_theta_deg
    if hi is None:
        hi = min(90.0, math.degrees(camera.view_colatitudes()[1]))
    lo = settings.min_theta_deg if settings.min_theta_deg is not None else hi * 5.0 / 9.0
    if not lo < hi:
        raise PipemapError(f"min_theta_deg ({lo:g}) must be below max_theta_deg ({hi:g})", key="appearance")
    return float(lo), float(hi)


def build_appearance(dataset: Dataset, keyframe_indices, poses_T_wc, pieces: list[WallPiece],
                     settings: AppearanceSettings | None = None,
                     progress: Callable[[int, int], None] | None = None,
                     usable: np.ndarray | None = None) -> AppearanceMap:
    """The appearance map of `pieces` from the keyframe images `keyframe_indices` (image indices of
    `dataset`) at the poses `poses_T_wc` ((K, 4, 4) or an (R, t) pair, same order). Each keyframe
    image is read once; progress(done, total) after each. `usable`: (H, W) bool, the pixels that show
    the wall (an overlay's are not sampled); None: all."""
    settings = settings or AppearanceSettings()
    band = colatitude_band(settings, dataset.camera)
    start = time.perf_counter()
    idx = np.asarray(keyframe_indices, dtype=np.int64).reshape(-1)
    R, t = as_rt(poses_T_wc)
    R, t = R.reshape(-1, 3, 3), t.reshape(-1, 3)
    if len(R) != len(idx):
        raise PipemapError(f"{len(idx)} keyframe indices but {len(R)} poses", key="appearance")
    n = len(dataset)
    if len(idx) and (idx.min() < 0 or idx.max() >= n):
        raise PipemapError(f"keyframe index {int(idx.max() if idx.max() >= n else idx.min())} is outside the "
                           f"dataset's {n} images", dataset.root)
    margin = INSIDE_MARGIN_SPACINGS * settings.spacing_m
    grids = [wall_grid(p, settings.spacing_m) for p in pieces]
    maps = [PieceMap.empty(g, opening_mask(g, pieces, margin)) for g in grids]
    sampler = _KeyframeSampler(dataset.camera, pieces, settings, usable)
    order = np.argsort(idx, kind="stable")
    exposure = None
    if settings.exposure_normalise:
        spread = np.unique(idx[order][np.linspace(0, len(idx) - 1, min(len(idx), LIGHT_FIELD_FRAMES)).astype(int)]) \
            if len(idx) else idx
        exposure = ExposureLevels(dataset.camera, band, usable)
        spread_frames = _frames_at(dataset, spread, np.arange(len(spread)))
        exposure.use_light(exposure.light_field(f.image for f, _ in spread_frames))
    sums = [_Sums(pm) for pm in maps]
    closing = _closing_order(sampler, grids, R[order], t[order])
    done = 0
    for q, (frame, k) in enumerate(_frames_at(dataset, idx[order], order)):
        image = frame.image if exposure is None else exposure.normalise(frame.image)
        for pm, acc in zip(maps, sums):
            sampler.accumulate(pm, acc, image, R[k], t[k])
        for m, b in closing.get(q, ()):
            sums[m].close(b)
        done += 1
        if progress is not None:
            progress(done, len(idx))
    for acc in sums:
        acc.finish(1.0 if exposure is None else exposure.reference)
    return AppearanceMap(maps, done, sampler.projections, sampler.samples, time.perf_counter() - start, settings,
                         None if exposure is None else exposure.to_dict())


def _closing_order(sampler: "_KeyframeSampler", grids: list[WallGrid], R: np.ndarray, t: np.ndarray
                   ) -> dict[int, list[tuple[int, int]]]:
    """{keyframe position q: [(piece, block)]}: the blocks of sums whose rows no keyframe after the q-th
    (in sampling order, poses R, t) reaches."""
    last: dict[tuple[int, int], int] = {}
    for q in range(len(R)):
        for m, grid in enumerate(grids):
            rows = sampler.reached_rows(grid, R[q], t[q])
            if rows.stop > rows.start:
                for b in range(rows.start // ACCUMULATOR_ROWS, (rows.stop - 1) // ACCUMULATOR_ROWS + 1):
                    last[(m, b)] = q
    closing: dict[int, list[tuple[int, int]]] = {}
    for key, q in last.items():
        closing.setdefault(q, []).append(key)
    return closing


def _frames_at(dataset: Dataset, indices: np.ndarray, rows: np.ndarray) -> Iterator[tuple[Frame, int]]:
    """(frame, pose row) for sorted image indices, each image read once (a video is streamed)."""
    if dataset.image_paths is not None:
        last = None
        for i, k in zip(indices.tolist(), rows.tolist()):
            if i != last:
                frame = dataset.read(i)
                last = i
            yield frame, k
        return
    want: dict[int, list[int]] = {}
    for i, k in zip(indices.tolist(), rows.tolist()):
        want.setdefault(i, []).append(k)
    for frame in dataset.frames_at(want):
        for k in want[frame.index]:
            yield frame, k


class _KeyframeSampler:
    """Projects grid rows into one keyframe and adds their samples to a PieceMap."""

    def __init__(self, camera, pieces: list[WallPiece], settings: AppearanceSettings,
                 usable: np.ndarray | None = None):
        self.camera = camera
        self.usable = usable
        self.pieces = pieces
        lo, hi = colatitude_band(settings, camera)
        self.theta_lo, self.theta_hi = math.radians(lo), math.radians(hi)
        self.taper = math.radians(settings.edge_taper_deg)
        self.spacing = settings.spacing_m
        r_max = max((p.radius for p in pieces), default=0.0)
        self.reach = REACH_RADII * r_max / math.sin(max(self.theta_lo, math.radians(15.0)))
        self.projections = 0
        self.samples = 0

    def _rows(self, grid: WallGrid, R: np.ndarray, c: np.ndarray) -> slice:
        """Grid rows whose points can lie in the colatitude band: a point at angle theta from the
        optical axis is at least theta - alpha off the pipe axis (alpha: optical axis to pipe
        axis), and at most r + d across it (d: camera to axis), so |dh| <= (r + d) / tan(theta - alpha)."""
        p = grid.piece
        if p.kind == "arc":
            return self._arc_rows(grid, c)
        u = p.axis
        z = R[:, 2]
        q = c - p.start
        h_c = float(q @ u)
        d = float(np.linalg.norm(q - h_c * u))
        cos_a = float(z @ u)
        alpha = math.acos(min(1.0, abs(cos_a)))
        lateral = p.radius + d
        eff = self.theta_lo - alpha
        ahead = lateral / math.tan(eff) if eff > 1e-3 else math.inf
        ahead = min(ahead, self.reach) + self.spacing
        behind = ahead
        if self.theta_hi <= math.pi / 2 and alpha < math.pi / 2 - 1e-3:
            # points in front of the camera lie at most lateral * tan(alpha) behind it along the axis
            behind = min(behind, lateral * math.tan(alpha) + self.spacing)
        lo, hi = (h_c - behind, h_c + ahead) if cos_a >= 0 else (h_c - ahead, h_c + behind)
        i0, i1 = np.searchsorted(grid.h, [lo, hi])
        return slice(int(i0), int(i1))

    def _arc_rows(self, grid: WallGrid, c: np.ndarray) -> slice:
        """An elbow's grid rows whose wall can lie within the reach: those whose axis point is within the
        reach plus the radius of the camera."""
        axis, _ = grid.piece.axis_at(grid.h)
        near = np.flatnonzero(np.linalg.norm(axis - c, axis=1) <= self.reach + grid.piece.radius + self.spacing)
        return slice(int(near[0]), int(near[-1]) + 1) if len(near) else slice(0, 0)

    def _weight(self, theta: np.ndarray, dist2: np.ndarray) -> np.ndarray:
        """Smoothstep from 0 to 1 over the taper inside both colatitude limits and over the last
        REACH_TAPER of the reach (never exactly 0 inside: a point seen once keeps its sample)."""
        if self.taper <= 0:
            return np.ones_like(theta)
        x = np.clip(np.minimum(theta - self.theta_lo, self.theta_hi - theta) / self.taper, 0.0, 1.0)
        y = np.clip((self.reach - np.sqrt(dist2)) / (REACH_TAPER * self.reach), 0.0, 1.0)
        return np.maximum(x * x * (3 - 2 * x) * y * y * (3 - 2 * y), 1e-6)

    def reached_rows(self, grid: WallGrid, R: np.ndarray, c: np.ndarray) -> slice:
        """The grid rows a keyframe at (R, c) may sample (empty: none)."""
        p = grid.piece
        if p.axis_distance(c) - p.radius > self.reach:
            return slice(0, 0)
        return self._rows(grid, R, c)

    def accumulate(self, pm: PieceMap, sums: _Sums, image: np.ndarray, R: np.ndarray, c: np.ndarray) -> None:
        p = pm.piece
        rows = self.reached_rows(pm.grid, R, c)
        if rows.stop <= rows.start:
            return
        P = pm.grid.points(rows)
        X = (P - c) @ R  # camera frame: X_c = R^T (X - c)
        self.projections += X.shape[0] * X.shape[1]
        rho = np.hypot(X[..., 0], X[..., 1])
        theta = np.arctan2(rho, X[..., 2])
        ok = (theta > self.theta_lo) & (theta < self.theta_hi) & pm.keep(rows)
        dist2 = np.einsum("...i,...i->...", X, X)
        ok &= dist2 < self.reach * self.reach
        if not ok.any():
            return
        where = np.nonzero(ok)
        uv, valid = self.camera.project(X[where])
        if not (p.wall_in_sight_from_inside and inside_piece(c, p, 0.0, self.spacing)):
            # the camera is in another piece (or in a bend, whose inner wall can hide its far side): the point must
            # be in sight through the pipes
            near = [q for q in self.pieces if q.axis_distance(c) < self.reach + q.radius]
            valid &= in_line_of_sight(c, P[where], near, self.spacing)
        if self.usable is not None and valid.any():
            px = np.clip(np.rint(uv).astype(np.int64), 0, [self.usable.shape[1] - 1, self.usable.shape[0] - 1])
            valid &= self.usable[px[:, 1], px[:, 0]]
        if not valid.any():
            return
        ii, jj = where[0][valid] + rows.start, where[1][valid]
        values = bilinear(image, uv[valid])
        w = self._weight(theta[where][valid], dist2[where][valid])
        sums.add(ii, jj, w, values)
        self.samples += len(values)


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear grey levels (N,) of `image` at pixels uv (N, 2) (OpenCV centres), via cv2.remap."""
    n = len(uv)
    m = -(-n // _REMAP_WIDTH) * _REMAP_WIDTH
    mx = np.zeros(m, np.float32)
    my = np.zeros(m, np.float32)
    mx[:n], my[:n] = uv[:, 0], uv[:, 1]
    out = cv2.remap(np.ascontiguousarray(image, np.float32), mx.reshape(-1, _REMAP_WIDTH), my.reshape(-1, _REMAP_WIDTH),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.ravel()[:n].astype(np.float64)


_PLY_COMMENT = ("pipemap appearance map: wall points (metres, world frame of trajectory.tum), mean grey level over "
                "the keyframes")


def _vertex_bytes(points: np.ndarray, intensity: np.ndarray, coords, fields) -> bytes:
    P = np.asarray(points, float).reshape(-1, 3)
    I = np.asarray(intensity, float).reshape(-1)
    if len(P) != len(I):
        raise ValueError(f"{len(P)} points but {len(I)} intensities")
    ok = np.all(np.isfinite(P), axis=1) & np.isfinite(I)
    P, I = P[ok], I[ok]
    vertex = np.empty(len(P), dtype=fields)
    vertex["x"], vertex["y"], vertex["z"] = P[:, 0], P[:, 1], P[:, 2]
    vertex["intensity"] = np.clip(np.rint(I), 0, 255).astype(np.uint8)
    if coords is not None:
        vertex["chainage"], vertex["clock_deg"] = np.asarray(coords[0])[ok], np.asarray(coords[1])[ok]
    return vertex.tobytes()


def write_appearance_ply_parts(path: str | Path, parts: Iterable[tuple], with_coords: bool = False) -> int:
    """appearance.ply from parts (points (n, 3), intensity (n,), coords or None), each turned into vertices and
    written before the next is made, so that the whole map is never held twice; returns the vertex count.
    Binary little-endian PLY, float32 x y z and uchar intensity; `with_coords`: every part's coords
    (chainage, clock_deg) add float32 properties `chainage` and `clock_deg`. Written atomically; points or
    grey levels that are not finite are left out."""
    path = Path(path)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1")]
    if with_coords:
        fields += [("chainage", "<f4"), ("clock_deg", "<f4")]
    names = {"<f4": "float", "u1": "uchar"}
    with tempfile.TemporaryFile(dir=path.parent) as body:
        count = 0
        for points, intensity, coords in parts:
            data = _vertex_bytes(points, intensity, coords if with_coords else None, fields)
            body.write(data)
            count += len(data) // np.dtype(fields).itemsize
        header = ["ply", "format binary_little_endian 1.0", f"comment {_PLY_COMMENT}", f"element vertex {count}"]
        header += [f"property {names[kind]} {name}" for name, kind in fields] + ["end_header", ""]
        body.seek(0)
        with replacing(path) as tmp, open(tmp, "wb") as out:
            out.write("\n".join(header).encode("ascii"))
            shutil.copyfileobj(body, out, 1 << 22)
    return count


def write_appearance_ply(path: str | Path, points: np.ndarray, intensity: np.ndarray, coords=None) -> None:
    """appearance.ply of one set of points (write_appearance_ply_parts)."""
    write_appearance_ply_parts(path, [(points, intensity, coords)], with_coords=coords is not None)


def read_appearance_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 3), intensity (N,) uint8) of an appearance.ply."""
    path = Path(path)
    try:
        v = PlyData.read(str(path))["vertex"]
        P = np.stack([np.asarray(v[k], float) for k in ("x", "y", "z")], axis=-1)
        return P, np.asarray(v["intensity"], np.uint8)
    except FileNotFoundError:
        raise PipemapError("file not found", path) from None
    except (KeyError, ValueError, OSError) as exc:
        raise PipemapError(f"not an appearance PLY ({exc})", path) from None


def _located_parts(amap: AppearanceMap, route) -> Iterator[tuple]:
    """The seen points, grey levels and, on a route, their (chainage, clock) on its segment, piece after piece
    and PLY_ROWS grid rows at a time: a whole piece's points and their route coordinates at once had made
    writing the map the run's peak of memory (+390 MB on paper-loop route A)."""
    for pm in amap.pieces:
        segment = None if route is None else route_segment_of(route, pm.piece)
        for start in range(0, pm.grid.shape[0], PLY_ROWS):
            rows = slice(start, start + PLY_ROWS)
            seen = pm.seen_rows(rows)
            if not seen.any():
                continue
            points = pm.grid.points(rows)[seen]
            coords = None
            if route is not None:
                chainage, clock, _, _ = route.to_route(points, wall=True, segment=segment)
                coords = (chainage, clock)
            yield points, pm.intensity_rows(rows)[seen], coords


def write_maps(folder: str | Path, dataset: Dataset, keyframe_indices, poses_T_wc, pieces: Iterable[WallPiece],
               settings=None, progress: Callable[[int, int], None] | None = None,
               usable: np.ndarray | None = None, route=None) -> dict:
    """appearance.ply and unrolled/ into `folder`; returns counts and seconds for run.json.
    `settings`: the run's Settings or its AppearanceSettings; `route` (inspection.Route): the map's points get
    their chainage and clock position, the unrolled images the chainage of their first column."""
    folder = Path(folder)
    s = getattr(settings, "appearance", settings) or AppearanceSettings()
    pieces = list(pieces)
    amap = build_appearance(dataset, keyframe_indices, poses_T_wc, pieces, s, progress, usable)
    t0 = time.perf_counter()
    count = write_appearance_ply_parts(folder / "appearance.ply", _located_parts(amap, route),
                                       with_coords=route is not None)
    starts = None if route is None else {pm.piece.name: piece_start_chainage(route, pm.piece) for pm in amap.pieces}
    images = write_unrolled(folder / "unrolled", amap, chainage_of_start=starts)
    return {
        "appearance_points": count,
        "unrolled_images": [p.name for p in images],
        "keyframes": amap.keyframes,
        "colatitude_band_deg": [round(v, 2) for v in colatitude_band(s, dataset.camera)],
        "projections": amap.projections,
        "points_per_second": round(amap.points_per_second, 1),
        "exposure": amap.exposure,
        "seconds": {"appearance": round(amap.seconds, 3), "appearance_write": round(time.perf_counter() - t0, 3)},
    }


__all__ = ["PieceMap", "AppearanceMap", "build_appearance", "colatitude_band", "bilinear", "write_appearance_ply",
           "write_appearance_ply_parts",
           "read_appearance_ply", "write_maps", "write_unrolled"]
