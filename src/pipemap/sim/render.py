"""Frames of a pipe scene: ray-cast wall points, textured, LED-lit and exposed by a noisy sensor.

The camera's bearings are unprojected once (pipemap's own models, valid past 90 deg) and only
the pixels inside the image circle are traced. Per frame: ray cast (raycast.py), wall
coordinates (h along the piece, s = r * phi around it), albedo from the piece's WallSurface with
a footprint = distance * pixel angle / cos(incidence) (trilinear mip-mapping), radiance from
the LED ring (LedRing.light on a stencil), then the sensor. Pixels outside the image circle are black;
rays that leave every nearby piece (far down the network) see nothing and are black too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipemap.camera import CameraModel
from pipemap.sim.lighting import LedRing, Sensor, auto_exposure
from pipemap.sim.network_model import PipeScene
from pipemap.sim.raycast import RayCaster
from pipemap.sim.texture import WallTexture

_ROWS_PER_CHUNK = 64  # bounds the float64 temporaries of unprojecting a large image


@dataclass(frozen=True)
class Appearance:
    """Wall, light and sensor settings of one sequence (defaults: the fisheye robot)."""

    texture_style: str = "procedural"
    mm_per_px: float = 1.0  # texture resolution on the wall
    cap_albedo: float = 0.5  # closed pipe ends: the wall texture folded onto the end plate, darkened
    n_leds: int = 8
    led_ring_radius_m: float = 0.04
    led_phase_deg: float = 0.0
    led_tilt_deg: float = 0.0
    led_beam_half_angle_deg: float = 60.0
    specular_strength: float = 0.15
    shininess: float = 40.0  # Blinn-Phong exponent of the wall's highlight
    ambient: float = 0.0
    vignetting: float = 0.3
    full_well: float = 6000.0
    read_noise: float = 2.0
    gamma: float = 1.0
    exposure_target: float = 0.45  # auto exposure on the first frame: this percentile ...
    exposure_percentile: float = 50.0  # ... of lit pixels lands at target of full scale
    exposure: float | None = None  # fixed exposure (skips auto exposure)
    noise: bool = True  # False: the noiseless, rounded image (for tests)

    def leds(self) -> LedRing:
        return LedRing(self.n_leds, self.led_ring_radius_m, self.led_tilt_deg, self.led_beam_half_angle_deg,
                       1.0, self.led_phase_deg)

    def sensor(self, exposure: float) -> Sensor:
        return Sensor(exposure, self.vignetting, self.full_well, self.read_noise if self.noise else 0.0, 8, self.gamma)

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class Pixels:
    """The camera's per-pixel constants, computed once."""

    valid: np.ndarray  # (H, W) inside the field of view
    index: np.ndarray  # (N,) flat indices of the valid pixels
    bearings: np.ndarray  # (N, 3) float32 unit bearings
    components: np.ndarray  # (3, N) float32, the same bearings component-wise
    theta: np.ndarray  # (H, W) float32 colatitude (for vignetting)
    angle: np.ndarray  # (N,) float32 angular size of the pixel, radians


def camera_pixels(camera: CameraModel) -> Pixels:
    W, H = camera.width, camera.height
    bearings = np.empty((H, W, 3), np.float32)
    valid = np.empty((H, W), bool)
    angle = np.empty((H, W), np.float32)
    us = np.arange(W, dtype=float)
    for r0 in range(0, H, _ROWS_PER_CHUNK):
        vs = np.arange(r0, min(H, r0 + _ROWS_PER_CHUNK), dtype=float)
        grid = np.stack(np.meshgrid(us, vs), axis=-1)
        b, ok = camera.unproject(grid)
        b1, _ = camera.unproject(grid + [0.5, 0.5])
        b0, _ = camera.unproject(grid - [0.5, 0.5])
        # a pixel's diagonal spans sqrt(2) pixel sizes
        ang = np.arccos(np.clip(np.sum(b0 * b1, axis=-1), -1.0, 1.0)) / np.sqrt(2.0)
        bearings[r0 : r0 + len(vs)], valid[r0 : r0 + len(vs)], angle[r0 : r0 + len(vs)] = b, ok, ang
    theta = np.arccos(np.clip(bearings[..., 2], -1.0, 1.0)).astype(np.float32)
    index = np.flatnonzero(valid)
    b = bearings.reshape(-1, 3)[index]
    return Pixels(valid, index, b.copy(), np.ascontiguousarray(b.T), theta, angle.ravel()[index].copy())


@dataclass(frozen=True)
class LightingStencil:
    """LED lighting varies slowly over a smooth wall, so it is computed exactly on every second pixel
    in each direction (the anchors) and interpolated bilinearly between them, except where a pixel's
    four anchors do not lie on the same smooth piece of wall (pipe edges, tee openings, end caps)."""

    anchor: np.ndarray  # (N,) bool over the valid pixels
    complete: np.ndarray  # (N,) bool: all four anchors are valid pixels
    corners: np.ndarray  # (4, N) valid-pixel indices of the surrounding anchors (own index if none)
    weights: np.ndarray  # (4, N) float32 bilinear weights


def lighting_stencil(pixels: Pixels) -> LightingStencil:
    H, W = pixels.valid.shape
    n = len(pixels.index)
    lookup = np.full(H * W, -1, np.int64)
    lookup[pixels.index] = np.arange(n)
    r, c = np.divmod(pixels.index, W)
    fr, fc = (r % 2) * 0.5, (c % 2) * 0.5
    r0, c0 = r - r % 2, c - c % 2
    r1, c1 = r0 + 2 * (r % 2), c0 + 2 * (c % 2)
    rows = np.stack([r0, r0, r1, r1])
    cols = np.stack([c0, c1, c0, c1])
    inside = (rows < H) & (cols < W)
    corners = np.where(inside, lookup[np.minimum(rows, H - 1) * W + np.minimum(cols, W - 1)], -1)
    complete = (corners >= 0).all(0)
    corners = np.where(corners >= 0, corners, np.arange(n)).astype(np.int32)
    weights = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc]).astype(np.float32)
    return LightingStencil((r % 2 == 0) & (c % 2 == 0), complete, corners, weights)


class Renderer:
    """Renders frames of `scene` through `camera`; exposure is fixed on the first frame rendered
    (or by `appearance.exposure`), as the robots ran with a fixed exposure."""

    def __init__(self, scene: PipeScene, camera: CameraModel, appearance: Appearance = Appearance(), seed: int = 0):
        self.scene = scene
        self.camera = camera
        self.appearance = appearance
        self.pixels = camera_pixels(camera)
        self.stencil = lighting_stencil(self.pixels)
        self.caster = RayCaster(scene, dtype=np.float32)
        self.texture = WallTexture(int(seed), appearance.mm_per_px, appearance.texture_style)
        self.leds = appearance.leds()
        circ = 2 * np.pi * scene.radius
        self.surfaces = [self.texture.surface(p.id, p.extend_start + p.length + p.extend_end, circ) for p in scene.pipes]
        self.exposure = appearance.exposure

    # -- geometry and radiance ------------------------------------------------------------------

    def trace(self, R_wc: np.ndarray, t_wc: np.ndarray):
        """Hits of the valid pixels' rays (raycast.Hits, in the order of pixels.index)."""
        return self.caster.cast_components(R_wc, t_wc, self.pixels.components)

    def surface_points(self, R_wc: np.ndarray, t_wc: np.ndarray):
        """Camera-frame points and inward normals as (3, N) components, texture coordinates h, s
        (N,), and the hits. Caps get h running inwards from the rim (the wall texture folds over)."""
        R = np.asarray(R_wc, float)
        origin = np.asarray(t_wc, float)
        hits = self.trace(R, origin)
        B = self.pixels.components
        n = B.shape[1]
        f32 = np.float32
        r = f32(self.scene.radius)
        h = hits.h.copy()
        t = np.where(hits.hit, hits.t, 0).astype(f32)
        P = B * t
        N = np.zeros((3, n), f32)
        s = np.zeros(n, f32)
        for j, idx in _groups(hits.pipe, len(self.scene.pipes)):
            pipe = self.scene.pipes[j]
            u = (pipe.axis @ R).astype(f32)
            a = ((pipe.start - origin) @ R).astype(f32)
            e1, e2 = ((e @ R).astype(f32) for e in pipe.frame)
            hj = h[idx]
            w = P[:, idx]
            w -= a[:, None]
            w -= u[:, None] * hj  # radial vector from the axis
            x = w[0] * e1[0] + w[1] * e1[1] + w[2] * e1[2]
            y = w[0] * e2[0] + w[1] * e2[1] + w[2] * e2[2]
            s[idx] = np.arctan2(y, x) * r
            w *= f32(-1.0) / r
            cap = hits.cap[idx]
            if cap.any():
                at_start = hj[cap] < f32(pipe.length / 2)
                w[:, cap] = np.where(at_start, u[:, None], -u[:, None])
                inward = r - np.sqrt(x[cap] ** 2 + y[cap] ** 2)
                hj[cap] = np.where(at_start, inward, f32(pipe.length) - inward)
                h[idx] = hj
            N[:, idx] = w
        return P, N, h, s, hits

    def radiance(self, R_wc: np.ndarray, t_wc: np.ndarray) -> np.ndarray:
        """(H, W) float32 radiance of one pose."""
        P, N, h, s, hits = self.surface_points(R_wc, t_wc)
        ap = self.appearance
        B = self.pixels.components
        albedo = np.zeros(P.shape[1], np.float32)
        cos_inc = np.abs(N[0] * B[0] + N[1] * B[1] + N[2] * B[2])
        footprint = hits.t * self.pixels.angle / np.maximum(cos_inc, np.float32(0.1))
        for j, idx in _groups(hits.pipe, len(self.scene.pipes)):
            pipe = self.scene.pipes[j]
            albedo[idx] = self.surfaces[j].sample(h[idx] + np.float32(pipe.extend_start), s[idx], footprint[idx])
        if hits.cap.any():
            albedo[hits.cap] *= np.float32(ap.cap_albedo)
        irr, spec = self._lighting(P, N, hits)
        lit = hits.hit
        rad = np.zeros(self.camera.height * self.camera.width, np.float32)
        value = albedo[lit] * (irr[lit] + np.float32(ap.ambient))
        if spec is not None:
            value += np.float32(ap.specular_strength) * spec[lit]
        rad[self.pixels.index[lit]] = value
        return rad.reshape(self.camera.height, self.camera.width)

    def _lighting(self, P: np.ndarray, N: np.ndarray, hits):
        """Irradiance and specular (N,) over the valid pixels: exact on anchors and on pixels whose
        anchors straddle an edge, interpolated elsewhere."""
        st, lit = self.stencil, hits.hit
        # one key per smooth piece of wall: the pipe, and whether it is the end cap
        key = np.where(lit, hits.pipe * 2 + hits.cap, -1)
        depth = hits.t.astype(np.float32, copy=False)
        smooth = st.complete & lit & ~st.anchor
        dmin = dmax = depth
        for ci in st.corners:
            smooth &= key[ci] == key
            dc = depth[ci]
            dmin, dmax = np.minimum(dmin, dc), np.maximum(dmax, dc)
        smooth &= dmax < np.float32(1.03) * dmin
        exact = np.flatnonzero(lit & ~smooth)
        between = np.flatnonzero(smooth)
        shininess = self.appearance.shininess if self.appearance.specular_strength else None
        e_irr, e_spec = self.leds.light(np.ascontiguousarray(P[:, exact].T), np.ascontiguousarray(N[:, exact].T),
                                        shininess)
        out = []
        for exact_values in (e_irr, e_spec):
            if exact_values is None:
                out.append(None)
                continue
            v = np.zeros(len(lit), np.float32)
            v[exact] = exact_values
            acc = np.zeros(len(between), np.float32)
            for ci, wi in zip(st.corners, st.weights):
                acc += wi[between] * v[ci[between]]
            v[between] = acc
            out.append(v)
        return out[0], out[1]

    # -- images ---------------------------------------------------------------------------------

    def fix_exposure(self, radiance: np.ndarray) -> float:
        ap = self.appearance
        if self.exposure is None:
            self.exposure = auto_exposure(radiance, self.pixels.theta, ap.sensor(1.0), ap.exposure_target,
                                          ap.exposure_percentile)
        return self.exposure

    def expose(self, radiance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """uint8 image of a radiance image; the exposure is fixed by the first call."""
        sensor = self.appearance.sensor(self.fix_exposure(radiance))
        if self.appearance.noise:
            img = sensor.expose(radiance, self.pixels.theta, rng)
        else:
            e = radiance * sensor.vignetting_factor(self.pixels.theta) * np.float32(sensor.exposure / sensor.full_well)
            img = np.rint(np.clip(e, 0, 1) * 255).astype(np.uint8)
        img[~self.pixels.valid] = 0
        return img

    def render(self, poses, rng: np.random.Generator) -> np.ndarray:
        """uint8 image; `poses` is one (R_wc, t_wc) or a list of them averaged (motion blur)."""
        if isinstance(poses, tuple):
            poses = [poses]
        rad = self.radiance(*poses[0])
        for R, t in poses[1:]:
            rad += self.radiance(R, t)
        if len(poses) > 1:
            rad *= np.float32(1.0 / len(poses))
        return self.expose(rad, rng)


def _groups(pipe: np.ndarray, k: int):
    """(piece index, its pixel indices) for every piece that has pixels."""
    counts = np.bincount(pipe + 1, minlength=k + 1)
    return [(j, np.flatnonzero(pipe == j)) for j in np.flatnonzero(counts[1:]) if counts[j + 1]]


def frame_rng(seed: int, index: int) -> np.random.Generator:
    """The sensor noise of frame `index`: reproducible on its own, independent between frames."""
    return np.random.default_rng([int(seed) % 2**63, int(index)])


def with_overrides(appearance: Appearance, **changes) -> Appearance:
    return replace(appearance, **changes)
