"""The robot's LED ring and the camera sensor: wall points and normals -> radiance -> 8-bit image.

Camera frame: x right, y down, z forward, camera centre at the origin. Both papers' robots
carry their own light only (8 LEDs round the fisheye lens; 4 on the 2010 rig), so radiance
falls as 1/d^2 down the pipe: the far end of a straight pipe is dark, walls beside the robot
are bright and tee walls that face it saturate (the fisheye paper's specular tees). Units are
arbitrary: radiance = albedo * irradiance (a Lambertian wall's 1/pi is folded into the
exposure) and the exposure converts radiance to electrons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipemap.errors import PipemapError

_MIN_DISTANCE_M = 1e-3
_CHUNK = 8192  # points per pass: the (points x LEDs) temporaries stay in cache


@dataclass(frozen=True)
class LedRing:
    """`n_leds` LEDs evenly on a circle of `ring_radius_m` round the lens in the camera's x-y
    plane (the first at angle `phase_deg` from +x towards +y), each pointing along +z tilted
    outward by `tilt_deg`.

    An LED's radiant intensity is power * cos(a)^m at angle a off its axis (0 behind it), with m
    set so that the intensity halves at `beam_half_angle_deg` (60 deg gives m = 1, a Lambertian
    emitter). The 2010 rig: LedRing(4, phase_deg=45).
    """

    n_leds: int = 8
    ring_radius_m: float = 0.04
    tilt_deg: float = 0.0
    beam_half_angle_deg: float = 60.0
    power: float = 1.0
    phase_deg: float = 0.0

    def __post_init__(self):
        if not (isinstance(self.n_leds, (int, np.integer)) and self.n_leds > 0):
            raise PipemapError(f"the LED ring needs at least one LED, got {self.n_leds}", key="lighting.n_leds")
        if not (self.ring_radius_m >= 0 and math.isfinite(self.ring_radius_m)):
            raise PipemapError(f"LED ring radius must be >= 0, got {self.ring_radius_m}", key="lighting.ring_radius_m")
        if not (0 < self.beam_half_angle_deg < 90):
            raise PipemapError(f"LED beam half angle must lie in (0, 90) deg, got {self.beam_half_angle_deg}",
                               key="lighting.beam_half_angle_deg")
        if not (self.power >= 0 and math.isfinite(self.power)):
            raise PipemapError(f"LED power must be >= 0, got {self.power}", key="lighting.power")
        if not (-90 < self.tilt_deg < 90):
            raise PipemapError(f"LED tilt must lie in (-90, 90) deg, got {self.tilt_deg}", key="lighting.tilt_deg")

    @property
    def positions(self) -> np.ndarray:
        a = np.radians(self.phase_deg) + 2 * np.pi * np.arange(self.n_leds) / self.n_leds
        return self.ring_radius_m * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)

    @property
    def directions(self) -> np.ndarray:
        a = np.radians(self.phase_deg) + 2 * np.pi * np.arange(self.n_leds) / self.n_leds
        t = np.radians(self.tilt_deg)
        return np.stack([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.full_like(a, np.cos(t))], axis=1)

    @property
    def beam_exponent(self) -> float:
        return math.log(0.5) / math.log(math.cos(math.radians(self.beam_half_angle_deg)))

    def irradiance(self, points_cam: np.ndarray, normals_cam: np.ndarray) -> np.ndarray:
        """Irradiance (...) float32 at wall points (..., 3) with unit normals (..., 3) pointing into
        the pipe: sum over LEDs of power * beam * max(cos incidence, 0) / d^2, d >= 1 mm."""
        return _light(self, points_cam, normals_cam, None)[0]

    def light(self, points_cam: np.ndarray, normals_cam: np.ndarray, shininess: float | None = 40.0):
        """Irradiance and (when `shininess` is given) the specular highlight, in one pass."""
        return _light(self, points_cam, normals_cam, None if shininess is None else float(shininess))

    def specular(self, points_cam: np.ndarray, normals_cam: np.ndarray, shininess: float = 40.0) -> np.ndarray:
        """Blinn-Phong highlight (...) float32 seen from the camera centre: sum over LEDs of
        power * beam / d^2 * max(n.h, 0)^shininess on surfaces the LED lights."""
        return _light(self, points_cam, normals_cam, float(shininess))[1]


def _power(x: np.ndarray, exponent: float) -> None:
    """x **= exponent in place for x >= 0; whole exponents by repeated squaring (cheaper than log/exp)."""
    if exponent == 1:
        return
    k = int(round(exponent))
    if abs(exponent - k) > 1e-9 or not 1 <= k <= 256:
        with np.errstate(divide="ignore"):
            np.log(x, out=x)
        x *= np.float32(exponent)
        np.exp(x, out=x)
        return
    base = x.copy()
    result_set = False
    while k:
        if k & 1:
            if result_set:
                x *= base
            else:
                np.copyto(x, base)
                result_set = True
        k >>= 1
        if k:
            base *= base


def _light(leds: LedRing, points, normals, shininess: float | None) -> tuple[np.ndarray, np.ndarray | None]:
    p = np.asarray(points, np.float32)
    n = np.asarray(normals, np.float32)
    if p.shape[-1:] != (3,) or n.shape != p.shape:
        raise ValueError(f"points and normals must both be (..., 3), got {p.shape} and {n.shape}")
    shape = p.shape[:-1]
    p = p.reshape(-1, 3)
    n = n.reshape(-1, 3)
    pos = leds.positions
    dirs = leds.directions
    k = leds.n_leds
    m = leds.beam_exponent
    l2 = np.einsum("ij,ij->i", pos, pos)
    # Every (point, LED) dot product comes out of one small matmul on augmented vectors:
    # [P, |P|^2, 1] -> d^2 = |P|^2 - 2 P.L + |L|^2,  D.(P - L),  and |P|^2 - P.L (for the half
    # vector);  [N, N.P] -> N.(L - P).
    a_d2 = np.vstack([-2 * pos.T, np.ones(k), l2]).astype(np.float32)
    a_off = np.vstack([dirs.T, np.zeros(k), -np.einsum("ij,ij->i", dirs, pos)]).astype(np.float32)
    a_pv = np.vstack([-pos.T, np.ones(k), np.zeros(k)]).astype(np.float32)
    b_inc = np.vstack([pos.T, -np.ones(k)]).astype(np.float32)
    weights = np.full(k, leds.power, np.float32)
    eps = np.float32(_MIN_DISTANCE_M**2)
    irr = np.empty(len(p), np.float32)
    spec = np.empty(len(p), np.float32) if shininess is not None else None
    pa = np.empty((_CHUNK, 5), np.float32)
    na = np.empty((_CHUNK, 4), np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i0 in range(0, len(p), _CHUNK):
            c = min(_CHUNK, len(p) - i0)
            P, N = p[i0 : i0 + c], n[i0 : i0 + c]
            pa_, na_ = pa[:c], na[:c]
            pa_[:, :3] = P
            pa_[:, 3] = np.einsum("ij,ij->i", P, P)
            pa_[:, 4] = 1
            na_[:, :3] = N
            na_[:, 3] = np.einsum("ij,ij->i", N, P)
            d2 = pa_ @ a_d2
            np.maximum(d2, eps, out=d2)
            inv = np.sqrt(d2)
            np.reciprocal(inv, out=inv)
            beam = pa_ @ a_off
            beam *= inv
            np.maximum(beam, 0, out=beam)
            _power(beam, m)
            np.multiply(inv, inv, out=d2)
            beam *= d2  # beam / d^2
            cos_inc = na_ @ b_inc
            cos_inc *= inv
            lit = np.maximum(cos_inc, 0)
            lit *= beam
            irr[i0 : i0 + c] = lit @ weights
            if spec is None:
                continue
            # h = l + v with l = (L - P)/d, v = -P/|P|:  n.h = n.l + n.v,
            # |h|^2 = 2 + 2 l.v = 2 + 2 (|P|^2 - P.L) / (d |P|)
            inv_rp = 1 / np.sqrt(np.maximum(pa_[:, 3], eps))
            h2 = pa_ @ a_pv
            h2 *= inv
            h2 *= (2 * inv_rp)[:, None]
            h2 += 2
            np.maximum(h2, np.float32(1e-12), out=h2)
            np.sqrt(h2, out=h2)
            cos_h = cos_inc - (na_[:, 3] * inv_rp)[:, None]
            cos_h /= h2
            np.maximum(cos_h, 0, out=cos_h)
            np.copyto(cos_h, 0, where=cos_inc <= 0)  # the LED lights the wall from this side only
            _power(cos_h, shininess)
            cos_h *= beam
            spec[i0 : i0 + c] = cos_h @ weights
    return irr.reshape(shape), (spec.reshape(shape) if spec is not None else None)


def shade(
    albedo: np.ndarray,
    points_cam: np.ndarray,
    normals_cam: np.ndarray,
    leds: LedRing,
    specular_strength: float = 0.15,
    ambient: float = 0.0,
    shininess: float = 40.0,
) -> np.ndarray:
    """Radiance float32: albedo * (LED irradiance + ambient) + specular_strength * highlight
    (LedRing.specular with `shininess`), at points (..., 3) with normals into the pipe."""
    irr, spec = leds.light(points_cam, normals_cam, float(shininess) if specular_strength else None)
    rad = np.asarray(albedo, np.float32) * (irr + np.float32(ambient))
    if spec is not None:
        rad += np.float32(specular_strength) * spec
    return rad.astype(np.float32, copy=False)


@dataclass(frozen=True)
class Sensor:
    """A linear sensor: radiance * exposure * vignetting(theta) electrons, shot and read noise,
    clipped at the full well (saturation -> 255), gamma, quantised to `bit_depth` bits.

    vignetting(theta) = 1 - vignetting * (1 - cos theta): 1 on the axis, 1 - vignetting at
    theta = 90 deg, smooth and decreasing in the colatitude theta (clipped at 0).
    """

    exposure: float
    vignetting: float = 0.3
    full_well: float = 6000.0
    read_noise: float = 2.0
    bit_depth: int = 8
    gamma: float = 1.0

    def __post_init__(self):
        if not (self.exposure >= 0 and math.isfinite(self.exposure)):
            raise PipemapError(f"exposure must be >= 0, got {self.exposure}", key="sensor.exposure")
        if not (0 <= self.vignetting <= 1):
            raise PipemapError(f"vignetting must lie in [0, 1], got {self.vignetting}", key="sensor.vignetting")
        if not (self.full_well > 0 and math.isfinite(self.full_well)):
            raise PipemapError(f"full well must be positive, got {self.full_well}", key="sensor.full_well")
        if not (self.read_noise >= 0 and math.isfinite(self.read_noise)):
            raise PipemapError(f"read noise must be >= 0, got {self.read_noise}", key="sensor.read_noise")
        if not (isinstance(self.bit_depth, (int, np.integer)) and 1 <= self.bit_depth <= 16):
            raise PipemapError(f"bit depth must be 1..16, got {self.bit_depth}", key="sensor.bit_depth")
        if not (self.gamma > 0 and math.isfinite(self.gamma)):
            raise PipemapError(f"gamma must be positive, got {self.gamma}", key="sensor.gamma")

    def vignetting_factor(self, theta: np.ndarray) -> np.ndarray:
        v = 1 - np.float32(self.vignetting) * (1 - np.cos(np.asarray(theta, np.float32)))
        return np.maximum(v, 0).astype(np.float32, copy=False)

    def gain(self, theta: np.ndarray) -> np.ndarray:
        """Electrons per unit radiance at bearings of colatitude theta: exposure x vignetting."""
        return np.float32(self.exposure) * self.vignetting_factor(theta)

    def expose(self, radiance: np.ndarray, theta: np.ndarray, rng: np.random.Generator,
               gain: np.ndarray | None = None) -> np.ndarray:
        """Image (uint8, uint16 above 8 bits) of radiance (H, W) at bearings of colatitude theta.

        Noise is Gaussian with variance electrons + read_noise^2: the normal approximation of
        Poisson shot noise plus read noise, drawn once per pixel (rng.poisson is several times
        slower; the approximation is poor only below ~10 electrons, deep in the dark pipe end).
        Non-finite radiance reads as 0. `gain`: this sensor's gain(theta), when the caller keeps it.
        """
        rad = np.asarray(radiance, np.float32)
        e = rad * (self.gain(theta) if gain is None else gain)
        np.nan_to_num(e, copy=False, nan=0.0, posinf=np.float32(self.full_well), neginf=0.0)
        np.maximum(e, 0, out=e)
        sigma = np.sqrt(e + np.float32(self.read_noise**2))
        e += sigma * rng.standard_normal(e.shape, dtype=np.float32)
        np.clip(e, 0, np.float32(self.full_well), out=e)
        e *= np.float32(1.0 / self.full_well)
        if self.gamma != 1.0:
            np.power(e, np.float32(1.0 / self.gamma), out=e)
        top = (1 << self.bit_depth) - 1
        e *= np.float32(top)
        np.rint(e, out=e)
        return e.astype(np.uint8 if self.bit_depth <= 8 else np.uint16)


def auto_exposure(radiance: np.ndarray, theta: np.ndarray, sensor: Sensor, target: float = 0.45,
                  percentile: float = 50) -> float:
    """Exposure that puts the `percentile` of lit, finite pixels at `target` of full scale
    (after vignetting and gamma). Call once per sequence: the robots ran with fixed exposure."""
    if not (0 < target <= 1 and 0 <= percentile <= 100):
        raise PipemapError("auto exposure needs 0 < target <= 1 and a percentile in [0, 100], "
                           f"got {target}, {percentile}")
    r = np.asarray(radiance, np.float32) * sensor.vignetting_factor(theta)
    r = r[np.isfinite(r) & (r > 0)]
    if r.size == 0:
        raise PipemapError("cannot set the exposure: no lit pixels in the frame")
    q = float(np.percentile(r, percentile))
    return sensor.full_well * target**sensor.gamma / q
