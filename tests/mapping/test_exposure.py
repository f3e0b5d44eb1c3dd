"""Auto-exposure steps leave no bands in the appearance map (mapping/exposure.py).

How a band is measured: the map built from frames whose gain steps (x0.7 for a third of the run,
x1.1 for the last third) is divided by the map of the same frames as rendered; along each piece the
median of that ratio over the clock positions gives a profile in distance along the pipe, and its
spread (95th minus 5th percentile, relative to its median) is the band. A flat map has none."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
import yaml

from pipemap.config import AppearanceSettings
from pipemap.dataset import load_dataset
from pipemap.mapping import build_appearance
from pipemap.mapping.exposure import ExposureLevels
from pipemap.sim.presets import fisheye_camera

GAINS = (1.0, 0.7, 1.1)


@pytest.fixture(scope="module")
def stepped(loop_case, tmp_path_factory):
    """The loop's frames with the gain stepping at a third and two thirds of the run."""
    src = loop_case.dataset.root
    dst = tmp_path_factory.mktemp("exposure") / "stepped"
    shutil.copytree(src, dst)
    doc = yaml.safe_load((dst / "dataset.yaml").read_text())
    paths = sorted(dst.glob(doc["images"]))
    for i, p in enumerate(paths):
        g = GAINS[min(2, 3 * i // len(paths))]
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64)
        cv2.imwrite(str(p), np.clip(np.rint(img * g), 0, 255).astype(np.uint8))
    return load_dataset(dst)


def _band(clean, stepped) -> float:
    spreads = []
    for a, b in zip(stepped.pieces, clean.pieces):
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = a.intensity / b.intensity
        ratio = np.where(np.isfinite(ratio), ratio, np.nan)
        rows = np.isfinite(ratio).any(axis=1)
        profile = np.nanmedian(ratio[rows], axis=1)
        profile = profile[np.isfinite(profile)]
        if profile.size > 20:
            p5, p50, p95 = np.percentile(profile, [5, 50, 95])
            spreads.append((p95 - p5) / p50)
    return max(spreads)


def test_exposure_steps_leave_no_band(loop_case, stepped):
    c = loop_case
    on, off = AppearanceSettings(), AppearanceSettings(exposure_normalise=False)
    plain = [build_appearance(d, c.indices, c.poses, c.pieces, off) for d in (c.dataset, stepped)]
    fixed = [build_appearance(d, c.indices, c.poses, c.pieces, on) for d in (c.dataset, stepped)]
    assert _band(*plain) > 0.25  # measured 0.33: the steps show
    assert _band(*fixed) < 0.03  # measured 0.022, what the x1.1 frames lose to saturation
    assert fixed[1].exposure["normalised"] == len(c.indices)
    lo, hi = fixed[1].exposure["relative_level_range"]
    assert hi / lo > 1.4  # the levels saw the steps (1.1 / 0.7 = 1.57)


def test_levels_divide_out_a_gain():
    cam = fisheye_camera(160, 120)
    img = np.random.default_rng(0).uniform(20, 200, (120, 160)).astype(np.float32)
    levels = ExposureLevels(cam, (50.0, 90.0))
    levels.use_light(levels.light_field([img * g for g in (0.8, 1.0, 1.2, 0.9, 1.1)]))
    a, b = levels.normalise(img), levels.normalise(1.5 * img)
    assert np.allclose(a, b, rtol=1e-5)
    assert levels.levels[1] / levels.levels[0] == pytest.approx(1.5, rel=1e-6)
    assert levels.reference == pytest.approx(np.median(levels.levels), rel=1e-6)
    dark = levels.normalise(np.zeros_like(img))  # lights off: left as it is, no level
    assert not dark.any() and np.isnan(levels.levels[-1])
