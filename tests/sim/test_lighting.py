"""LED ring and sensor: analytic irradiance, inverse square law, specular mirror peak, noise, saturation."""

import math

import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.sim.lighting import LedRing, Sensor, auto_exposure, shade


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def analytic_irradiance(leds, p, n):
    """Float64 reference: sum over LEDs of power * cos(off axis)^m * max(n.l, 0) / d^2."""
    total = 0.0
    for pos, axis in zip(leds.positions, leds.directions):
        v = np.asarray(p, float) - pos
        d = np.linalg.norm(v)
        cos_off = max(v @ axis / d, 0.0)
        total += leds.power * cos_off**leds.beam_exponent * max(-(n @ v) / d, 0.0) / d**2
    return total


def test_point_on_the_axis_facing_the_led_gets_power_over_d_squared():
    led = LedRing(n_leds=1, ring_radius_m=0.0, power=2.5)
    d = np.array([0.05, 0.2, 1.0, 3.0])
    points = np.stack([np.zeros(4), np.zeros(4), d], axis=1)
    normals = np.tile([0.0, 0.0, -1.0], (4, 1))
    assert np.allclose(led.irradiance(points, normals), 2.5 / d**2, rtol=1e-5, atol=0)


def test_irradiance_follows_the_inverse_square_law():
    leds = LedRing()
    direction = unit([0.3, -0.2, 1.0])
    normal = -direction
    e = [leds.irradiance(direction * d, normal) for d in (1.0, 2.0, 4.0)]
    # the ring is 4 cm across: at metres the LEDs are nearly a point source
    assert e[1] / e[0] == pytest.approx(0.25, rel=2e-3)
    assert e[2] / e[1] == pytest.approx(0.25, rel=5e-4)


@pytest.mark.parametrize("leds", [LedRing(), LedRing(4, 0.03, 15.0, 40.0, 3.0, phase_deg=45.0),
                                  LedRing(6, 0.05, -10.0, 75.0)])
def test_irradiance_matches_the_analytic_sum_over_leds(leds):
    rng = np.random.default_rng(3)
    phi = rng.uniform(0, 2 * np.pi, 300)
    z = rng.uniform(-0.3, 2.0, 300)
    # inside a 400 mm pipe whose axis is tilted against the camera's
    points = np.stack([0.2 * np.cos(phi) + 0.02, 0.2 * np.sin(phi) - 0.01, z], axis=1)
    normals = unit(np.stack([-np.cos(phi), -np.sin(phi), 0.1 * np.ones(300)], axis=1))
    got = leds.irradiance(points.astype(np.float32), normals.astype(np.float32))
    expected = np.array([analytic_irradiance(leds, p, n) for p, n in zip(points, normals)])
    assert got.dtype == np.float32 and got.shape == (300,)
    assert np.allclose(got, expected, rtol=1e-5, atol=1e-6 * expected.max())
    behind_all = np.all((points[:, None] - leds.positions) @ leds.directions.T * np.eye(leds.n_leds) <= 0, axis=(1, 2))
    assert behind_all.sum() >= 10 and np.all(got[behind_all] == 0)


def test_tilted_led_points_outward_and_light_falls_off_with_its_beam():
    led = LedRing(n_leds=1, ring_radius_m=0.04, tilt_deg=30.0, beam_half_angle_deg=30.0)
    axis = np.array([math.sin(math.radians(30)), 0.0, math.cos(math.radians(30))])
    on_axis = led.positions[0] + 0.5 * axis
    assert led.irradiance(on_axis, -axis) == pytest.approx(1 / 0.25, rel=1e-5)
    # at the half angle off the axis, at the same distance and incidence, half the light
    off = np.array([math.sin(math.radians(60)), 0.0, math.cos(math.radians(60))])
    assert led.irradiance(led.positions[0] + 0.5 * off, -off) == pytest.approx(0.5 / 0.25, rel=1e-4)


def test_nothing_blows_up_at_the_leds():
    leds = LedRing()
    e = leds.irradiance(leds.positions.astype(np.float32), np.tile([0.0, 0.0, -1.0], (8, 1)))
    s = leds.specular(leds.positions.astype(np.float32), np.tile([0.0, 0.0, -1.0], (8, 1)))
    assert np.all(np.isfinite(e)) and np.all(np.isfinite(s))
    assert np.all(e <= 8 * leds.power / 1e-6)  # distance clamped at 1 mm


def test_specular_peaks_at_the_mirror_normal():
    led = LedRing(n_leds=1, ring_radius_m=0.04, beam_half_angle_deg=60.0, power=1.0)
    p = np.array([0.15, 0.05, 0.4])
    to_led = unit(led.positions[0] - p)
    to_cam = unit(-p)
    mirror = unit(to_led + to_cam)
    # normals swept through the mirror normal in two directions
    ortho = unit(np.cross(mirror, [0.0, 0.0, 1.0]))
    ortho2 = np.cross(mirror, ortho)
    angles = np.radians(np.linspace(-10, 10, 201))
    for o in (ortho, ortho2):
        normals = np.cos(angles)[:, None] * mirror + np.sin(angles)[:, None] * o
        spec = led.specular(np.tile(p, (201, 1)), normals, shininess=60.0)
        assert np.argmax(spec) == 100
    d = np.linalg.norm(led.positions[0] - p)
    beam = (p - led.positions[0]) @ led.directions[0] / d
    assert led.specular(p, mirror, 60.0) == pytest.approx(beam / d**2, rel=1e-4)
    # the LED behind the surface gives no highlight
    assert led.specular(p, -mirror, 60.0) == 0.0


def test_shade_combines_albedo_irradiance_specular_and_ambient():
    leds = LedRing()
    rng = np.random.default_rng(0)
    phi = rng.uniform(0, 2 * np.pi, (20, 30))
    points = np.stack([0.2 * np.cos(phi), 0.2 * np.sin(phi), rng.uniform(0.05, 1.0, phi.shape)],
                      axis=-1).astype(np.float32)
    normals = np.stack([-np.cos(phi), -np.sin(phi), np.zeros_like(phi)], axis=-1).astype(np.float32)
    albedo = rng.uniform(0.1, 0.9, phi.shape).astype(np.float32)
    rad = shade(albedo, points, normals, leds, specular_strength=0.2, ambient=0.5)
    expected = albedo * (leds.irradiance(points, normals) + 0.5) + 0.2 * leds.specular(points, normals, 40.0)
    assert rad.shape == (20, 30) and rad.dtype == np.float32
    assert np.allclose(rad, expected, rtol=1e-5)
    assert np.allclose(shade(albedo, points, normals, leds, 0.0), albedo * leds.irradiance(points, normals), rtol=1e-6)


def test_shapes_are_checked():
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        LedRing().irradiance(np.zeros((4, 3)), np.zeros((5, 3)))
    out = LedRing().irradiance(np.ones((2, 3, 4, 3)), -np.ones((2, 3, 4, 3)))
    assert out.shape == (2, 3, 4)


def flat_field(electrons, sensor, size=300):
    return np.full((size, size), electrons / sensor.exposure, np.float32), np.zeros((size, size), np.float32)


def test_sensor_noise_is_shot_plus_read_noise():
    sensor = Sensor(exposure=1000.0, read_noise=8.0)
    gain = 255 / sensor.full_well  # DN per electron
    for electrons in (300.0, 3000.0):
        radiance, theta = flat_field(electrons, sensor)
        img = sensor.expose(radiance, theta, np.random.default_rng(7)).astype(float)
        assert img.mean() == pytest.approx(gain * electrons, rel=0.01)
        # quantisation adds 1/12 DN^2
        assert img.var() == pytest.approx(gain**2 * (electrons + 8.0**2) + 1 / 12, rel=0.1)


def test_sensor_saturates_at_full_well_and_quantises():
    sensor = Sensor(exposure=1.0)
    radiance, theta = flat_field(2 * sensor.full_well, sensor, 50)
    img = sensor.expose(radiance, theta, np.random.default_rng(0))
    assert img.dtype == np.uint8 and np.all(img == 255)
    dark = sensor.expose(np.zeros((50, 50), np.float32), theta, np.random.default_rng(0))
    assert dark.max() <= 1
    deep = Sensor(exposure=1.0, bit_depth=12).expose(radiance, theta, np.random.default_rng(0))
    assert deep.dtype == np.uint16 and np.all(deep == 4095)
    nan = sensor.expose(np.full((4, 4), np.nan, np.float32), np.zeros((4, 4)), np.random.default_rng(0))
    assert nan.max() <= 1


def test_vignetting_falls_smoothly_with_colatitude():
    sensor = Sensor(exposure=1.0, vignetting=0.3)
    theta = np.radians(np.linspace(0, 100, 201))
    v = sensor.vignetting_factor(theta)
    assert v[0] == pytest.approx(1.0) and sensor.vignetting_factor(np.pi / 2) == pytest.approx(0.7, abs=1e-6)
    assert np.all(np.diff(v) < 0)
    assert np.abs(np.diff(v, 2)).max() < 1e-4  # no kinks
    radiance = np.full((1, 201), 3000.0, np.float32)
    img = Sensor(exposure=1.0, read_noise=0.0).expose(radiance, theta[None], np.random.default_rng(0))
    assert img[0, 0] > img[0, 100] > img[0, -1]


def test_exposure_is_deterministic_for_a_seed():
    sensor = Sensor(exposure=20.0)
    radiance = np.random.default_rng(0).uniform(0, 300, (60, 80)).astype(np.float32)
    theta = np.random.default_rng(1).uniform(0, 1.6, (60, 80)).astype(np.float32)
    a = sensor.expose(radiance, theta, np.random.default_rng(42))
    b = sensor.expose(radiance, theta, np.random.default_rng(42))
    c = sensor.expose(radiance, theta, np.random.default_rng(43))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("gamma", [1.0, 2.2])
def test_auto_exposure_puts_the_median_at_the_target(gamma):
    rng = np.random.default_rng(5)
    radiance = rng.lognormal(0.0, 1.5, (120, 160)).astype(np.float32)
    radiance[:10] = 0.0  # outside the image circle: not counted
    theta = rng.uniform(0, 1.6, radiance.shape).astype(np.float32)
    sensor = Sensor(exposure=1.0, read_noise=0.0, gamma=gamma)
    exposure = auto_exposure(radiance, theta, sensor, target=0.45)
    # the same exposure relative to a 1e9 electron well: shot noise becomes negligible
    deep_well = Sensor(exposure * 1e9 / sensor.full_well, read_noise=0.0, gamma=gamma, full_well=1e9)
    img = deep_well.expose(radiance, theta, rng)
    assert np.median(img[10:]) == pytest.approx(0.45 * 255, abs=1.5)
    with pytest.raises(PipemapError, match="no lit pixels"):
        auto_exposure(np.zeros((4, 4)), np.zeros((4, 4)), sensor)


def test_bad_settings_fail_with_one_clear_error():
    for kwargs, word in [(dict(n_leds=0), "LED"), (dict(beam_half_angle_deg=95), "half angle"),
                         (dict(power=-1), "power")]:
        with pytest.raises(PipemapError, match=word):
            LedRing(**kwargs)
    for kwargs, word in [(dict(exposure=-1), "exposure"), (dict(exposure=1, vignetting=1.5), "vignetting"),
                         (dict(exposure=1, bit_depth=20), "bit depth")]:
        with pytest.raises(PipemapError, match=word):
            Sensor(**kwargs)
