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
    outside: np.ndarray  # (H, W) ~valid


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
    return Pixels(valid, index, b.copy(), np.ascontiguousarray(b.T), theta, angle.ravel()[index].copy(), ~valid)


class Renderer:
    """Renders frames of `scene` through `camera`; exposure is fixed on the first frame rendered
    (or by `appearance.exposure`), as the robots ran with a fixed exposure."""

    def __init__(self, scene: PipeScene, camera: CameraModel, appearance: Appearance = Appearance(), seed: int = 0):
        self.scene = scene
        self.camera = camera
        self.appearance = appearance
        self.pixels = camera_pixels(camera)
        self.caster = RayCaster(scene, dtype=np.float32)
        self.texture = WallTexture(int(seed), appearance.mm_per_px, appearance.texture_style)
        self.leds = appearance.leds()
        circ = 2 * np.pi * scene.radius
        # each piece samples its surface at h + offset: its own (from the overlap at its start), or its
        # chain's, shared along a run through elbows (wall texture unbroken into a bend)
        self.surfaces, self.h_offsets = [], []
        for p in scene.pieces:
            if p.chain is None:
                self.surfaces.append(self.texture.surface(p.id, p.extend_start + p.length + p.extend_end, circ))
                self.h_offsets.append(np.float32(p.extend_start))
            else:
                key, h0, total = p.chain
                self.surfaces.append(self.texture.surface(key, total, circ))
                self.h_offsets.append(np.float32(h0))
        self.exposure = appearance.exposure
        self._gain = None

    # -- geometry and radiance ------------------------------------------------------------------

    def trace(self, R_wc: np.ndarray, t_wc: np.ndarray):
        """Hits of the valid pixels' rays (raycast.Hits, in the order of pixels.index)."""
        return self.caster.cast_components(R_wc, t_wc, self.pixels.components)

    def surface_points(self, R_wc: np.ndarray, t_wc: np.ndarray):
        """Camera-frame points and inward normals as (3, N) components, texture coordinates h, s
        (N,), and the hits. Caps get h running inwards from the rim (the wall texture folds over)."""
        return self._surface(R_wc, t_wc)[:5]

    def _surface(self, R_wc: np.ndarray, t_wc: np.ndarray):
        """surface_points and the hits' pixels grouped by piece (_groups), which shading reuses."""
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
        K = len(self.scene.pipes)
        groups = _groups(hits.pipe, len(self.scene.pieces))
        for j, idx in groups:
            if j >= K:
                N[:, idx], s[idx] = self._bend_wall(self.scene.bends[j - K], R, origin, P[:, idx])
                continue
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
        return P, N, h, s, hits, groups

    def _bend_wall(self, bend, R: np.ndarray, origin: np.ndarray, P: np.ndarray):
        """Inward normals (3, n) in the camera frame and s = r * phi of camera-frame wall points P on a bend:
        phi from the bend's `up` carried along the arc (the straight pieces' convention, e2 = e1 x tangent)."""
        E = bend.basis
        q = (E @ R) @ P.astype(np.float64) + (E @ (origin - bend.centre))[:, None]  # the bend's frame
        theta = np.arctan2(q[1], q[0])
        c, sn = np.cos(theta), np.sin(theta)
        radial = q - np.stack([bend.bend_radius * c, bend.bend_radius * sn, np.zeros_like(c)])
        # back to the start's cross-section (turn by -theta about the normal), where phi = 0 at `up`
        x0, y0 = c * radial[0] + sn * radial[1], -sn * radial[0] + c * radial[1]
        f1 = E @ bend.up
        f2 = np.cross(f1, [0.0, 1.0, 0.0])  # up x start tangent, as Pipe.frame's e2 = e1 x axis
        x = f1[0] * x0 + f1[1] * y0 + f1[2] * radial[2]
        y = f2[0] * x0 + f2[1] * y0 + f2[2] * radial[2]
        normal = (R.T @ E.T) @ (radial * (-1.0 / self.scene.radius))
        return normal.astype(np.float32), (np.arctan2(y, x) * self.scene.radius).astype(np.float32)

    def radiance(self, R_wc: np.ndarray, t_wc: np.ndarray) -> np.ndarray:
        """(H, W) float32 radiance of one pose."""
        return self.shading(R_wc, t_wc).radiance()

    def shading(self, R_wc: np.ndarray, t_wc: np.ndarray) -> "Shading":
        """The parts of one pose's radiance: the wall's albedo, which moves with the wall, and the
        LED light on it, which moves with the camera; with the wall points and hits."""
        P, N, h, s, hits, groups = self._surface(R_wc, t_wc)
        ap = self.appearance
        B = self.pixels.components
        albedo = np.zeros(P.shape[1], np.float32)
        cos_inc = np.abs(N[0] * B[0] + N[1] * B[1] + N[2] * B[2])
        footprint = hits.t * self.pixels.angle / np.maximum(cos_inc, np.float32(0.1))
        for j, idx in groups:
            albedo[idx] = self.surfaces[j].sample(h[idx] + self.h_offsets[j], s[idx], footprint[idx])
        if hits.cap.any():
            albedo[hits.cap] *= np.float32(ap.cap_albedo)
        irr, spec = self._lighting(P, N, hits)
        return Shading(self, albedo, irr, spec, P, hits)

    def _lighting(self, P: np.ndarray, N: np.ndarray, hits):
        """Irradiance and specular (N,) over the valid pixels.

        LED light varies slowly over a smooth wall, so it is computed exactly on every second pixel
        in each direction (the anchors) and interpolated between neighbouring anchors on the same
        smooth piece of wall; pixels whose anchors straddle a pipe edge, tee opening, end cap or
        depth jump are computed exactly too."""
        H, W = self.camera.height, self.camera.width
        index, lit = self.pixels.index, hits.hit
        key = np.full(H * W, -1, np.int32)
        key[index[lit]] = hits.pipe[lit] * 2 + hits.cap[lit]
        depth = np.zeros(H * W, np.float32)
        depth[index[lit]] = hits.t[lit]
        key, depth = key.reshape(H, W), depth.reshape(H, W)
        ka, da = key[0::2, 0::2], depth[0::2, 0::2]

        def joined(k0, k1, d0, d1):
            return (k0 == k1) & (k0 >= 0) & (np.maximum(d0, d1) < np.float32(1.03) * np.minimum(d0, d1))

        across = joined(ka[:, :-1], ka[:, 1:], da[:, :-1], da[:, 1:])
        down = joined(ka[:-1], ka[1:], da[:-1], da[1:])
        cell = across[:-1] & across[1:] & down[:, :-1] & down[:, 1:]
        # the in-between pixels: (even row, odd col), (odd row, even col), (odd row, odd col)
        parts = [((0, 1), across, ka[:, :-1]), ((1, 0), down, ka[:-1]), ((1, 1), cell, ka[:-1, :-1])]
        smooth = np.zeros((H, W), bool)
        for (r0, c0), ok, k in parts:
            view = smooth[r0::2, c0::2][: ok.shape[0], : ok.shape[1]]
            view[...] = ok & (key[r0::2, c0::2][: ok.shape[0], : ok.shape[1]] == k)
        exact = np.flatnonzero(lit & ~smooth.ravel()[index])
        shininess = self.appearance.shininess if self.appearance.specular_strength else None
        values = self.leds.light(np.ascontiguousarray(P[:, exact].T), np.ascontiguousarray(N[:, exact].T), shininess)
        out = []
        for exact_values in values:
            if exact_values is None:
                out.append(None)
                continue
            img = np.zeros((H, W), np.float32)
            img.ravel()[index[exact]] = exact_values
            a = img[0::2, 0::2]
            means = [(a[:, :-1] + a[:, 1:]) * 0.5, (a[:-1] + a[1:]) * 0.5,
                     (a[:-1, :-1] + a[:-1, 1:] + a[1:, :-1] + a[1:, 1:]) * 0.25]
            for ((r0, c0), ok, _), mean in zip(parts, means):
                view = img[r0::2, c0::2][: ok.shape[0], : ok.shape[1]]
                np.copyto(view, mean, where=smooth[r0::2, c0::2][: ok.shape[0], : ok.shape[1]])
            out.append(img.ravel()[index])
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
            img = sensor.expose(radiance, self.pixels.theta, rng, self._sensor_gain(sensor))
        else:
            e = radiance * sensor.vignetting_factor(self.pixels.theta) * np.float32(sensor.exposure / sensor.full_well)
            img = np.rint(np.clip(e, 0, 1) * 255).astype(np.uint8)
        img[self.pixels.outside] = 0
        return img

    def _sensor_gain(self, sensor: Sensor) -> np.ndarray:
        """The sensor's per-pixel gain, kept while the exposure stays the same (every frame of a run)."""
        if self._gain is None or self._gain[0] != sensor.exposure:
            self._gain = (sensor.exposure, sensor.gain(self.pixels.theta))
        return self._gain[1]

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


@dataclass
class Shading:
    """One pose's radiance in parts, over the valid pixels (pixels.index order): radiance =
    albedo * (irradiance + ambient) + specular_strength * specular on the lit pixels, 0 elsewhere."""

    renderer: Renderer
    albedo: np.ndarray  # (N,) float32
    irradiance: np.ndarray  # (N,) float32
    specular: np.ndarray | None  # (N,) float32
    points: np.ndarray  # (3, N) float32 camera-frame wall points
    hits: object  # raycast.Hits

    def radiance(self, albedo: np.ndarray | None = None) -> np.ndarray:
        """(H, W) float32 radiance; `albedo` (H, W) replaces the pose's own (e.g. resampled along the
        image motion for motion blur) while the light stays where the camera's LEDs put it."""
        r = self.renderer
        ap = r.appearance
        lit = self.hits.hit
        a = self.albedo[lit] if albedo is None else albedo.ravel()[r.pixels.index[lit]]
        rad = np.zeros(r.camera.height * r.camera.width, np.float32)
        value = a * (self.irradiance[lit] + np.float32(ap.ambient))
        if self.specular is not None:
            value += np.float32(ap.specular_strength) * self.specular[lit]
        rad[r.pixels.index[lit]] = value
        return rad.reshape(r.camera.height, r.camera.width)

    def albedo_image(self) -> np.ndarray:
        """(H, W) float32 albedo, 0 where no wall is seen."""
        r = self.renderer
        img = np.zeros(r.camera.height * r.camera.width, np.float32)
        img[r.pixels.index] = np.where(self.hits.hit, self.albedo, 0)
        return img.reshape(r.camera.height, r.camera.width)


def _groups(pipe: np.ndarray, k: int):
    """(piece index, its pixel indices) for every piece that has pixels."""
    counts = np.bincount(pipe + 1, minlength=k + 1)
    return [(j, np.flatnonzero(pipe == j)) for j in np.flatnonzero(counts[1:]) if counts[j + 1]]


def frame_rng(seed: int, index: int) -> np.random.Generator:
    """The sensor noise of frame `index`: reproducible on its own, independent between frames."""
    return np.random.default_rng([int(seed) % 2**63, int(index)])


def with_overrides(appearance: Appearance, **changes) -> Appearance:
    return replace(appearance, **changes)
