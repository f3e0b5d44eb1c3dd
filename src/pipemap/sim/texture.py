"""Wall albedo in wall coordinates: seeded, non-repeating, periodic around the pipe, mip-mapped.

Wall coordinates: h is metres along a segment's axis, s = r * phi the arc length around the
wall, s in [0, circumference). Every image here is indexed [row, col] = [s, h]: rows run around
the wall, columns along the axis. Level 0 has rows = ceil(circumference / px) and
cols = ceil(length / px) for px = mm_per_px / 1000; its row pitch is circumference / rows
(a hair under px) so that the image wraps exactly once around the pipe.

Layers (painted in this order): multi-octave value noise and low-frequency stains, synthesised
on a grid that is periodic in s; for the photo styles, `skimage.data` brick/gravel detail cut
into randomly offset and flipped tiles blended without seams; circumferential weld seams;
corrosion pits; painted lettering, arrows and stripes (dark paint on a light wall). Albedo lies
in [0.05, 0.95].
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from pipemap.errors import PipemapError

STYLES = ("procedural", "brick", "gravel", "white")

# cv2.remap keeps source coordinates in int16, so a source image must stay below this size.
_REMAP_MAX = 32000
_REMAP_TILE = 16384
_MAP_WIDTH = 1024  # remap splits work over destination rows: keep maps 2-D for its threads


class WallSurface:
    """One segment's baked albedo pyramid and its sampler.

    `levels[0]` is (rows, cols) float32 = (s, h) at `mm_per_px`; each further level halves both
    sizes (rounding up, box/area filtered, so each level still wraps exactly in s).
    """

    def __init__(self, levels: list[np.ndarray], length_m: float, circumference_m: float, mm_per_px: float):
        self.levels = levels
        self.length_m = float(length_m)
        self.circumference_m = float(circumference_m)
        self.mm_per_px = float(mm_per_px)
        extent_h = levels[0].shape[1] * self.mm_per_px / 1000.0
        self._pitch_s = [self.circumference_m / lv.shape[0] for lv in levels]
        self._pitch_h = [extent_h / lv.shape[1] for lv in levels]
        self._px0 = self.mm_per_px / 1000.0

    def sample(self, h: np.ndarray, s: np.ndarray, footprint_m: np.ndarray | float | None = None) -> np.ndarray:
        """Albedo at wall points (h, s) metres, float32 with their broadcast shape.

        s wraps modulo the circumference; h is clamped to the segment. `footprint_m` is the
        size on the wall of the image pixel that samples the point: the pyramid level is
        log2(footprint / px) and the two nearest levels are blended (trilinear filtering).
        None samples level 0 only. Bilinear taps come from cv2.remap, whose weights are
        quantised to 1/32 texel: values differ from exact bilinear interpolation by at most
        1/64 of the neighbouring texel difference. Non-finite inputs give some valid albedo.
        """
        h, s = np.broadcast_arrays(np.asarray(h, np.float32), np.asarray(s, np.float32))
        shape = h.shape
        h = h.ravel()
        s = _wrap(s.ravel(), np.float32(self.circumference_m))
        top = len(self.levels) - 1
        if footprint_m is None or np.ndim(footprint_m) == 0:
            lvl = 0.0 if footprint_m is None else _level(float(footprint_m), self._px0, top)
            lo = int(lvl)
            out = self._lookup(lo, h, s)
            if lvl > lo:
                out += np.float32(lvl - lo) * (self._lookup(lo + 1, h, s) - out)
            return out.reshape(shape)
        fp = np.broadcast_to(np.asarray(footprint_m, np.float32), shape).ravel()
        lvl = np.log2(np.maximum(fp, np.float32(1e-9)) * np.float32(1.0 / self._px0))
        np.fmax(lvl, 0.0, out=lvl)  # fmax/fmin also map NaN to a valid level
        np.fmin(lvl, top, out=lvl)
        lo = lvl.astype(np.int8)
        frac = lvl - lo
        out = np.empty(h.size, np.float32)
        for k in range(int(lo.min(initial=0)), int(lo.max(initial=0)) + 1):
            idx = np.flatnonzero(lo == k)
            if idx.size == 0:
                continue
            hk, sk = h[idx], s[idx]
            val = self._lookup(k, hk, sk)
            if k < top:
                val += frac[idx] * (self._lookup(k + 1, hk, sk) - val)
            out[idx] = val
        return out.reshape(shape)

    def _lookup(self, k: int, h: np.ndarray, s: np.ndarray) -> np.ndarray:
        img = self.levels[k]
        rows, cols = img.shape
        n = h.size
        m = -(-n // _MAP_WIDTH) * _MAP_WIDTH
        mx = np.zeros(m, np.float32)
        my = np.zeros(m, np.float32)
        np.multiply(h, np.float32(1.0 / self._pitch_h[k]), out=mx[:n])
        mx[:n] -= 0.5
        # clamping x to pixel centres keeps BORDER_WRAP acting on s alone; fmax/fmin map NaN
        # to a valid coordinate
        np.fmax(mx[:n], 0.0, out=mx[:n])
        np.fmin(mx[:n], cols - 1, out=mx[:n])
        np.multiply(s, np.float32(1.0 / self._pitch_s[k]), out=my[:n])
        my[:n] -= 0.5
        np.fmax(my[:n], -0.5, out=my[:n])
        if cols <= _REMAP_MAX:
            return _remap(img, mx, my)[:n]
        out = np.empty(m, np.float32)
        tile = np.minimum(mx // _REMAP_TILE, (cols - 1) // _REMAP_TILE).astype(np.int32)
        for t in np.unique(tile):
            idx = np.flatnonzero(tile == t)
            c0 = int(t) * _REMAP_TILE
            src = img[:, c0 : min(cols, c0 + _REMAP_TILE + 2)]
            out[idx] = _remap(src, mx[idx] - c0, my[idx])
        return out[:n]


def _wrap(s: np.ndarray, circ: np.float32) -> np.ndarray:
    """s modulo the circumference. Wall points give s in (-circ, circ), where one conditional add
    gives np.mod's values at a quarter of its cost; anything else takes np.mod."""
    if s.size and -circ < s.min() and s.max() < circ:
        return np.where(s < 0, s + circ, s)
    with np.errstate(invalid="ignore"):
        return np.mod(s, circ)


def _remap(img: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
    """Bilinear taps at (mx, my), wrapping in rows. The maps are shaped 2-D, _MAP_WIDTH wide,
    because cv2.remap threads over destination rows and both its sizes must stay < 32767."""
    n = mx.size
    if n % _MAP_WIDTH:
        m = -(-n // _MAP_WIDTH) * _MAP_WIDTH
        mx = np.concatenate([mx, np.zeros(m - n, np.float32)])
        my = np.concatenate([my, np.zeros(m - n, np.float32)])
    out = np.empty(mx.size, np.float32)
    step = _MAP_WIDTH * 16384
    for i in range(0, mx.size, step):
        out[i : i + step] = cv2.remap(
            img, mx[i : i + step].reshape(-1, _MAP_WIDTH), my[i : i + step].reshape(-1, _MAP_WIDTH), cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_WRAP
        ).ravel()
    return out[:n]


def _level(footprint: float, px: float, top: int) -> float:
    return min(max(math.log2(max(footprint, 1e-9) / px), 0.0), float(top))


@dataclass
class WallTexture:
    """Seeded wall albedo for every segment of a network, baked lazily and cached per key.

    The texture of a key depends only on (seed, key, style, mm_per_px, size), through a stable
    CRC-32 of the key, so it is the same in every process. Styles: "procedural"; "brick" and
    "gravel" (procedural layers plus photo detail); "white" (a flat white card, albedo 0.9).
    A segment longer than ~32 m at 1 mm/px is sampled in tiles (cv2.remap's size limit); the
    circumference must stay below 32000 px.
    """

    seed: int
    mm_per_px: float = 1.0
    style: str = "procedural"
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.style not in STYLES:
            raise PipemapError(f"unknown wall texture style {self.style!r} (expected {', '.join(STYLES)})",
                               key="texture.style")
        if not (self.mm_per_px > 0 and math.isfinite(self.mm_per_px)):
            raise PipemapError(f"texture resolution must be positive, got {self.mm_per_px} mm/px",
                               key="texture.mm_per_px")

    def surface(self, key: str, length_m: float, circumference_m: float) -> WallSurface:
        """The baked surface of segment `key` (cached: the same key and size return the same object)."""
        ck = (key, float(length_m), float(circumference_m))
        if ck not in self._cache:
            self._cache[ck] = self._bake(key, float(length_m), float(circumference_m))
        return self._cache[ck]

    def clear_cache(self) -> None:
        self._cache.clear()

    def _bake(self, key: str, length_m: float, circumference_m: float) -> WallSurface:
        if not (length_m > 0 and circumference_m > 0 and math.isfinite(length_m) and math.isfinite(circumference_m)):
            raise PipemapError(f"segment {key!r}: wall size must be positive, got {length_m} m x {circumference_m} m")
        px = self.mm_per_px / 1000.0
        rows, cols = math.ceil(circumference_m / px - 1e-9), math.ceil(length_m / px - 1e-9)
        if rows > _REMAP_MAX:
            raise PipemapError(
                f"segment {key!r}: circumference {circumference_m} m is {rows} px at {self.mm_per_px} mm/px; "
                f"use a coarser texture resolution (at most {_REMAP_MAX} px around)",
                key="texture.mm_per_px",
            )
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed) % 2**64, zlib.crc32(key.encode())]))
        photo = self.style if self.style in ("brick", "gravel") else None
        if self.style == "white":
            albedo = _base(rng, rows, cols, px, contrast=0.004, stains=False, mean=0.9)
        else:
            albedo = _base(rng, rows, cols, px, contrast=0.06 if photo else 0.10, stains=True, mean=0.6)
            if photo:
                _add_photo_detail(albedo, rng, photo, px, amplitude=0.07)
            _paint_welds(albedo, rng, px)
            _paint_pits(albedo, rng, px)
            _paint_markings(albedo, rng, px)
        np.clip(albedo, 0.05, 0.95, out=albedo)
        return WallSurface(_pyramid(albedo), length_m, circumference_m, self.mm_per_px)


def _pyramid(img: np.ndarray) -> list[np.ndarray]:
    levels = [img]
    while min(levels[-1].shape) > 4:
        r, c = levels[-1].shape
        levels.append(cv2.resize(levels[-1], (-(-c // 2), -(-r // 2)), interpolation=cv2.INTER_AREA))
    return levels


# -- procedural layers ------------------------------------------------------------------------


def _up2(g: np.ndarray) -> np.ndarray:
    """Double both sizes exactly (bicubic), periodic in rows: the result still wraps in s."""
    p = 2
    g = np.pad(g, ((p, p), (0, 0)), mode="wrap")
    g = cv2.copyMakeBorder(g, 0, 0, p, p, cv2.BORDER_REFLECT_101)
    return cv2.resize(g, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)[2 * p : -2 * p, 2 * p : -2 * p]


def _fbm(rng, shape0, n_up: int, gain: float, flecks: float = 0.0) -> np.ndarray:
    """Value noise summed over octaves by repeated upsampling; octave k has amplitude gain**k.

    `flecks` adds sparse strong spots of +-flecks to the three finest octaves (2-8 mm at
    1 mm/px): small blobs that give corner detectors something to hold on to.
    """
    g = rng.standard_normal(shape0, dtype=np.float32)
    for k in range(1, n_up + 1):
        g = _up2(g)
        g += rng.standard_normal(g.shape, dtype=np.float32) * np.float32(gain**k)
        if flecks and k > n_up - 3:
            u = rng.random(g.shape, dtype=np.float32)
            g[u < 0.012] -= np.float32(flecks)
            g[u > 0.994] += np.float32(flecks)
    return g


def _smoothstep(x: np.ndarray, a: float, b: float) -> np.ndarray:
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _base(rng, rows: int, cols: int, px: float, contrast: float, stains: bool, mean: float) -> np.ndarray:
    """Noise (finest cell 2 px, coarsest ~0.25 m) and stains on a grid of ~half resolution,
    resampled to (rows, cols) with the s axis mapped to exactly one period."""
    n_up = max(1, round(math.log2(0.25 / (2 * px))))
    coarse = 2 * px * 2**n_up
    ns0 = max(2, round(rows * px / coarse))
    nh0 = math.ceil(cols * px / coarse) + 1
    g = _fbm(rng, (ns0, nh0), n_up, gain=0.85, flecks=2.5 if stains else 0.0)
    g *= np.float32(1.0 / max(float(g.std()), 1e-6))
    g *= np.float32(contrast)
    if stains:
        k = min(2, n_up)
        f = _fbm(rng, (ns0, nh0), k, gain=0.6)
        f *= np.float32(1.0 / max(float(f.std()), 1e-6))
        dark = _smoothstep(f, 0.9, 1.5)
        light = _smoothstep(-f, 1.1, 1.7)
        tide = dark * (1 - dark) * 4  # stains keep a darker rim where the water line dried
        layer = (-0.22 * dark + 0.12 * light - 0.06 * tide).astype(np.float32)
        for _ in range(n_up - k):
            layer = _up2(layer)
        g += layer
    g += np.float32(mean)
    if stains:
        # soft limits keep unpainted wall between 0.2 and 0.92 so that paint stays the darkest thing
        lo, hi = 0.2, 0.92
        g = (np.float32(0.5 * (lo + hi))
             + np.float32(0.5 * (hi - lo)) * np.tanh((g - 0.5 * (lo + hi)) / (0.5 * (hi - lo))))
    g = cv2.copyMakeBorder(g.astype(np.float32), 0, 0, 3, 3, cv2.BORDER_REFLECT_101)

    out = np.empty((rows, cols), np.float32)
    ns = g.shape[0]
    ymap = ((np.arange(rows, dtype=np.float64) + 0.5) * ns / rows - 0.5).astype(np.float32)
    chunk = 1024
    for j0 in range(0, cols, chunk):
        j1 = min(cols, j0 + chunk)
        x = ((np.arange(j0, j1) + 0.5) / 2 - 0.5 + 3).astype(np.float32)
        c0 = int(x[0]) - 2  # the bicubic taps reach floor(x) - 1 .. floor(x) + 2
        c1 = int(x[-1]) + 3
        mx = np.empty((rows, j1 - j0), np.float32)
        my = np.empty_like(mx)
        mx[:] = x - c0
        my[:] = ymap[:, None]
        out[:, j0:j1] = cv2.remap(g[:, c0:c1], mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_WRAP)
    return out


@lru_cache(maxsize=2)
def _photo(name: str) -> np.ndarray:
    """A photo as zero-mean, unit-variance detail (tiles are cut inside it: mirrored copies
    would show their symmetry axes)."""
    from skimage import data

    p = getattr(data, name)().astype(np.float32) / 255.0
    if p.ndim == 3:
        p = p.mean(axis=2)
    p -= cv2.GaussianBlur(p, (0, 0), 16)  # drop the photo's own uneven lighting
    return p / p.std()


def _add_photo_detail(albedo: np.ndarray, rng, name: str, px: float, amplitude: float) -> None:
    """Photo tiles at random offsets and flips, cross-faded with variance-preserving
    (sin/cos) weights, wrapping in s, so that the photo never visibly repeats."""
    rows, cols = albedo.shape
    photo_px = 0.0006  # metres per photo pixel on the wall
    src = cv2.resize(_photo(name), None, fx=photo_px / px, fy=photo_px / px, interpolation=cv2.INTER_AREA)
    step = max(4, round(0.16 / px))
    ov = max(2, round(0.03 / px))
    size = min(step + ov, src.shape[0], src.shape[1])
    ov = min(ov, size - 1)
    step = size - ov
    ts = min(size, rows)
    ramp = np.sin(0.5 * np.pi * (np.arange(ov) + 0.5) / ov).astype(np.float32)
    w1 = np.ones(size, np.float32)
    w1[:ov] = ramp
    w1[-ov:] = ramp[::-1]
    n_s = max(1, round(rows / step))
    starts = [round(i * rows / n_s) for i in range(n_s)]
    ws = w1[:ts] if ts == size else np.ones(ts, np.float32)
    for c0 in range(0, cols, step):
        width = min(size, cols - c0)
        num = np.zeros((rows, width), np.float32)
        den = np.zeros(rows, np.float32)
        for r0 in starts:
            y, x = rng.integers(0, src.shape[0] - size + 1), rng.integers(0, src.shape[1] - size + 1)
            t = src[y : y + ts, x : x + width]
            if rng.random() < 0.5:
                t = t[::-1]
            if rng.random() < 0.5 and width == size:
                t = t[:, ::-1]
            if name == "gravel" and rng.random() < 0.5 and width == ts == size:
                t = t.T
            idx = (r0 + np.arange(ts)) % rows
            num[idx] += ws[:, None] * t
            den[idx] += ws * ws
        num /= np.sqrt(np.maximum(den, 1e-6))[:, None]
        wh = w1[:width].copy()
        if c0 == 0:
            wh[:ov] = 1.0
        albedo[:, c0 : c0 + width] += (amplitude * wh)[None, :] * num


def _wrap_rows(r0: int, n: int, rows: int) -> np.ndarray:
    return (r0 + np.arange(min(n, rows))) % rows


def _paint_welds(albedo: np.ndarray, rng, px: float) -> None:
    """Circumferential joints every 1.5-3 m: a dark bead with a bright rim each side."""
    rows, cols = albedo.shape
    length = cols * px
    h = rng.uniform(0.4, 2.0)
    phase = 2 * np.pi * np.arange(rows) / rows
    while h < length - 0.1:
        half = rng.uniform(0.003, 0.006)
        wobble = 0.0015 * np.sin(phase * rng.integers(1, 4) + rng.uniform(0, 2 * np.pi))
        c0, c1 = max(0, int((h - 0.02) / px)), min(cols, int((h + 0.02) / px) + 1)
        hh = (np.arange(c0, c1) + 0.5) * px
        d = (hh[None, :] - h - wobble[:, None]) / half
        bead = np.exp(-(d**4))
        rim = np.exp(-(((np.abs(d) - 1.6) / 0.5) ** 2))
        region = albedo[:, c0:c1]
        region *= (1 - 0.6 * bead).astype(np.float32)
        region += (0.25 * rim * (0.95 - region)).astype(np.float32)
        h += rng.uniform(1.5, 3.0)


def _blend(albedo: np.ndarray, r0: int, c0: int, alpha: np.ndarray, value: float) -> None:
    """albedo <- albedo + alpha * (value - albedo) over a patch at (r0, c0), wrapping in s."""
    rows, cols = albedo.shape
    lo, hi = max(0, c0), min(cols, c0 + alpha.shape[1])
    if hi <= lo:
        return
    a = alpha[:rows, lo - c0 : hi - c0]
    idx = _wrap_rows(r0, a.shape[0], rows)
    region = albedo[idx, lo:hi]
    region += a * (np.float32(value) - region)
    albedo[idx, lo:hi] = region


def _paint_pits(albedo: np.ndarray, rng, px: float) -> None:
    """Clusters of small dark pits with a faint rust halo."""
    rows, cols = albedo.shape
    area = rows * cols * px * px
    for _ in range(rng.poisson(2.5 * area) + 1):
        size = max(8, round(rng.uniform(0.03, 0.08) / px))
        canvas = np.zeros((size, size), np.float32)
        for _ in range(rng.integers(3, 15)):
            c = (int(rng.integers(0, size)), int(rng.integers(0, size)))
            ax = (max(1, round(rng.uniform(0.001, 0.005) / px)), max(1, round(rng.uniform(0.001, 0.005) / px)))
            cv2.ellipse(canvas, c, ax, float(rng.uniform(0, 180)), 0, 360, float(rng.uniform(0.5, 0.85)), -1,
                        cv2.LINE_AA)
        halo = cv2.GaussianBlur(canvas, (0, 0), size / 6)
        alpha = np.clip(canvas + 0.5 * halo, 0, 0.9)
        _blend(albedo, int(rng.integers(0, rows)), int(rng.integers(-size // 2, cols)), alpha, 0.08)


_TEXTS = ("T{a}-{L} {x:.2f}m", "P{n:02d}", "LNG-{n} 16in", "NDT {n:03d}", "KP {x:.1f}", "SEC {L}{a}", "FLOW",
          "J{a}/{n}")


def _text_mask(text: str, height_px: float, font: int) -> np.ndarray:
    """Anti-aliased text coverage in [0, 1]; small text is drawn large and area-averaged down."""
    render_h = max(32.0, height_px)
    (w, h), base = cv2.getTextSize(text, font, 1.0, 2)
    scale = render_h / h
    thick = max(1, round(scale * 2.2))
    pad = thick + 2
    canvas = np.zeros((int(render_h + base * scale) + 2 * pad, int(w * scale) + 2 * pad), np.uint8)
    cv2.putText(canvas, text, (pad, pad + int(render_h)), font, scale, 255, thick, cv2.LINE_AA)
    mask = canvas.astype(np.float32) / 255.0
    if render_h > height_px:
        f = height_px / render_h
        size = (max(1, round(mask.shape[1] * f)), max(1, round(mask.shape[0] * f)))
        mask = cv2.resize(mask, size, interpolation=cv2.INTER_AREA)
    return mask


def _arrow_mask(length_px: int, width_px: int) -> np.ndarray:
    scale = max(1.0, 24.0 / width_px)
    L, W = int(length_px * scale), max(2, int(width_px * scale))
    canvas = np.zeros((4 * W, L + 2 * W), np.uint8)
    cv2.arrowedLine(canvas, (W, 2 * W), (L + W, 2 * W), 255, W, cv2.LINE_AA, tipLength=min(0.4, 2.5 * W / L))
    mask = canvas.astype(np.float32) / 255.0
    if scale > 1:
        mask = cv2.resize(mask, (max(1, round(mask.shape[1] / scale)), max(1, round(mask.shape[0] / scale))),
                          interpolation=cv2.INTER_AREA)
    return mask


def _paint_markings(albedo: np.ndarray, rng, px: float) -> None:
    """Stencilled codes, flow arrows and painted stripes: worn dark paint on the light wall."""
    rows, cols = albedo.shape
    length = cols * px
    fonts = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_PLAIN)
    marks = []
    for _ in range(1 + rng.poisson(0.6 * length)):
        text = str(rng.choice(_TEXTS)).format(
            a=int(rng.integers(1, 9)), L="ABCDEFGH"[int(rng.integers(0, 8))], n=int(rng.integers(1, 999)),
            x=rng.uniform(0, 9.9)
        )
        mask = _text_mask(text, rng.uniform(0.035, 0.07) / px, fonts[int(rng.integers(0, 3))])
        marks.append(cv2.rotate(mask, cv2.ROTATE_90_CLOCKWISE) if rng.random() < 0.3 else mask)
    for _ in range(rng.poisson(0.3 * length)):
        mask = _arrow_mask(max(8, round(rng.uniform(0.12, 0.3) / px)), max(2, round(rng.uniform(0.008, 0.016) / px)))
        marks.append(mask[:, ::-1] if rng.random() < 0.5 else mask)
    for mask in marks:
        mask = mask[: rows - 1]
        wear = 0.85 + 0.15 * rng.random(mask.shape, dtype=np.float32)
        r0 = int(rng.integers(0, rows))
        c0 = int(rng.integers(0, max(1, cols - mask.shape[1])))
        _blend(albedo, r0, c0, mask * wear * np.float32(rng.uniform(0.92, 0.98)), rng.uniform(0.04, 0.08))
    if rng.random() < 0.35:
        width = max(3, round(rng.uniform(0.015, 0.03) / px))
        a, b = sorted(rng.integers(0, cols + 1, 2))
        if rng.random() < 0.5:
            a, b = 0, cols
        edge = np.minimum(np.arange(width) + 0.5, width - 0.5 - np.arange(width)) / 1.5
        alpha = (np.clip(edge, 0, 1).astype(np.float32)[:, None] * np.float32(0.75)
                 * np.ones((1, max(0, b - a)), np.float32))
        _blend(albedo, int(rng.integers(0, rows)), int(a), alpha, 0.25)
