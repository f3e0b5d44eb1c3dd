"""Wall textures: seeded determinism, seamless wrap in s, exact sampling bookkeeping, paint, anti-aliasing."""

import cv2
import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.sim.texture import WallTexture

LENGTH, CIRC = 1.0, 0.6283  # a 200 mm pipe; 629 rows at 1 mm/px, odd so the pyramid rounds up


@pytest.fixture(scope="module")
def surface():
    return WallTexture(11).surface("S1", LENGTH, CIRC)


def exact_bilinear(img, x, y):
    """Float64 bilinear interpolation at pixel coordinates (x clamped, y wrapping), with the
    bound on cv2.remap's 1/32-texel weight quantisation at each point."""
    rows, cols = img.shape
    img = img.astype(np.float64)
    x = np.clip(x, 0, cols - 1)
    x0 = np.minimum(np.floor(x).astype(int), cols - 2)
    y0 = np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    r0, r1 = y0 % rows, (y0 + 1) % rows
    a, b, c, d = img[r0, x0], img[r0, x0 + 1], img[r1, x0], img[r1, x0 + 1]
    value = (1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * c + fx * d)
    bound = (np.maximum(abs(b - a), abs(d - c)) + np.maximum(abs(c - a), abs(d - b))) / 64
    return value, bound


def test_layout_dtype_and_range(surface):
    level0 = surface.levels[0]
    assert level0.shape == (629, 1000) and level0.dtype == np.float32
    assert surface.length_m == LENGTH and surface.circumference_m == CIRC and surface.mm_per_px == 1.0
    assert 0.05 <= level0.min() and level0.max() <= 0.95
    assert 0.1 < level0.std() < 0.3
    shapes = [lv.shape for lv in surface.levels]
    assert shapes[1] == (315, 500) and shapes[2] == (158, 250) and min(shapes[-1]) <= 4
    assert all(lv.dtype == np.float32 for lv in surface.levels)


def test_same_seed_and_key_give_the_same_texture_and_others_differ(surface):
    again = WallTexture(11).surface("S1", LENGTH, CIRC)
    assert np.array_equal(again.levels[0], surface.levels[0])
    other_key = WallTexture(11).surface("S2", LENGTH, CIRC)
    other_seed = WallTexture(12).surface("S1", LENGTH, CIRC)
    for other in (other_key, other_seed):
        assert np.abs(other.levels[0] - surface.levels[0]).mean() > 0.05


def test_surfaces_are_cached_per_key():
    tex = WallTexture(3)
    assert tex.surface("a", 0.3, 0.3) is tex.surface("a", 0.3, 0.3)
    assert tex.surface("a", 0.3, 0.3) is not tex.surface("b", 0.3, 0.3)


def wrap_step_ratio(level):
    """Mean |difference| across s = 0 over the mean |difference| of neighbouring rows."""
    return np.abs(level[0] - level[-1]).mean() / np.abs(np.diff(level, axis=0)).mean()


@pytest.mark.parametrize("style", ["procedural", "brick", "gravel"])
def test_texture_wraps_around_the_pipe_without_a_seam(style):
    surf = WallTexture(5, style=style).surface("W", LENGTH, CIRC)
    for level in surf.levels[:2]:
        assert wrap_step_ratio(level) < 1.6
    # the check sees a seam: the same image cut short of one period has one
    assert wrap_step_ratio(surf.levels[0][:560]) > 2


def test_sample_is_bilinear_on_level_zero(surface):
    level0 = surface.levels[0]
    rows, cols = level0.shape
    rng = np.random.default_rng(0)
    # on the 1/32-texel lattice cv2.remap's weights are exact
    x = rng.integers(0, 32 * (cols - 1), 5000) / 32.0
    y = rng.integers(-16, 32 * rows - 16, 5000) / 32.0
    h, s = (x + 0.5) / 1000, (y + 0.5) * CIRC / rows
    expected, _ = exact_bilinear(level0, x, y)
    for footprint in (None, 0.0, np.zeros(5000)):
        assert np.allclose(surface.sample(h, s, footprint), expected, atol=1e-5, rtol=0)
    # anywhere else within the quantisation bound
    x, y = rng.uniform(0, cols - 1, 20000), rng.uniform(-0.5, rows - 0.5, 20000)
    expected, bound = exact_bilinear(level0, x, y)
    got = surface.sample((x + 0.5) / 1000, (y + 0.5) * CIRC / rows)
    assert np.all(np.abs(got - expected) <= bound + 1e-5)
    assert np.abs(got - expected).mean() < 1e-3


def test_footprint_selects_the_pyramid_level(surface):
    for k in (1, 2, 3):
        level = surface.levels[k]
        rows, cols = level.shape
        i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
        h = (j + 0.5) * surface.levels[0].shape[1] / 1000 / cols
        s = (i + 0.5) * CIRC / rows
        footprint = 0.001 * 2**k
        assert np.allclose(surface.sample(h, s, footprint), level, atol=1e-5)
        assert np.allclose(surface.sample(h, s, np.full(h.shape, footprint)), level, atol=1e-5)
    # half way between two levels is their average
    h, s = np.array([0.3101]), np.array([0.2052])
    mid = surface.sample(h, s, 0.001 * 2**1.5)
    assert mid == pytest.approx(0.5 * (surface.sample(h, s, 0.002) + surface.sample(h, s, 0.004)), abs=1e-5)


def test_s_wraps_and_h_clamps(surface):
    rows = surface.levels[0].shape[0]
    s = (np.arange(0, rows, 7) + 0.5) * CIRC / rows
    h = np.full(s.shape, 0.4005)
    base = surface.sample(h, s)
    assert np.allclose(surface.sample(h, s + 2 * CIRC), base, atol=1e-4)
    assert np.allclose(surface.sample(h, s - CIRC), base, atol=1e-4)
    assert np.allclose(surface.sample(np.full(s.shape, -3.0), s), surface.sample(np.zeros(s.shape), s))
    assert np.allclose(surface.sample(np.full(s.shape, 9.0), s), surface.sample(np.full(s.shape, LENGTH), s))
    grid = surface.sample(np.full((3, 4), 0.2), np.full((3, 4), 0.1), np.full((3, 4), 0.003))
    assert grid.shape == (3, 4) and grid.dtype == np.float32


def letter_like_blobs(albedo, dark=0.15):
    _, _, stats, _ = cv2.connectedComponentsWithStats((albedo < dark).astype(np.uint8), connectivity=8)
    w, h, area = stats[1:, 2], stats[1:, 3], stats[1:, 4]
    size = np.maximum(w, h)
    return int(np.sum((size >= 20) & (size <= 120) & (area >= 40) & (area < 0.7 * w * h)))


def test_painted_lettering_is_present(surface):
    # unpainted wall stays above 0.2, so thin dark glyph-sized blobs are paint
    assert letter_like_blobs(surface.levels[0]) >= 3
    white = WallTexture(11, style="white").surface("S1", LENGTH, CIRC).levels[0]
    assert letter_like_blobs(white) == 0
    assert white.mean() == pytest.approx(0.9, abs=0.01) and white.std() < 0.01


def test_large_footprint_filters_fine_detail(surface):
    rng = np.random.default_rng(1)
    h = rng.uniform(0.05, 0.95, 20000)
    s = rng.uniform(0, CIRC, 20000)
    point = surface.sample(h, s)
    filtered = surface.sample(h, s, 0.016)
    assert filtered.var() < 0.7 * point.var()
    assert filtered.mean() == pytest.approx(point.mean(), abs=0.02)


def test_photo_styles_are_deterministic_and_differ_from_procedural(surface):
    for style in ("brick", "gravel"):
        a = WallTexture(11, style=style).surface("S1", LENGTH, CIRC).levels[0]
        b = WallTexture(11, style=style).surface("S1", LENGTH, CIRC).levels[0]
        assert np.array_equal(a, b)
        assert np.abs(a - surface.levels[0]).mean() > 0.01


def test_long_segments_are_sampled_in_tiles():
    surf = WallTexture(2).surface("long", 40.0, 0.1)  # 40000 columns: beyond cv2.remap's int16 limit
    level0 = surf.levels[0]
    x = np.linspace(16370, 16400, 301)  # across the first tile boundary
    y = np.full(x.shape, 37.25)
    expected, bound = exact_bilinear(level0, x, y)
    got = surf.sample((x + 0.5) / 1000, (y + 0.5) * 0.1 / level0.shape[0])
    assert np.all(np.abs(got - expected) <= bound + 1e-5)


def test_bad_settings_fail_with_one_clear_error():
    with pytest.raises(PipemapError, match="style"):
        WallTexture(1, style="marble")
    with pytest.raises(PipemapError, match="resolution"):
        WallTexture(1, mm_per_px=0)
    with pytest.raises(PipemapError, match="positive"):
        WallTexture(1).surface("x", -1.0, 0.5)
