"""Too little to map is one line and a non-zero exit, and no result folder: one frame, a frozen
picture, dark frames, blank frames, no motion."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from pipemap.cli import app
from pipemap.config import Settings
from pipemap.errors import PipemapError
from pipemap.quality import FrameStats, require_mappable


def _textured(rng, shape=(120, 160)):
    return np.clip(128 + 40 * rng.standard_normal(shape), 0, 255).astype(np.float32)


def test_frame_stats_tell_dark_blank_and_textured_frames():
    rng = np.random.default_rng(0)
    stats = FrameStats.for_settings(Settings())
    stats.add(np.zeros((120, 160), np.float32))
    stats.add(np.full((120, 160), 128, np.float32))
    stats.add(_textured(rng))
    assert (stats.frames, stats.dark, stats.blank) == (3, 1, 1)


@pytest.mark.parametrize("kind, words", [("dark", "are dark"), ("blank", "no wall texture"),
                                         ("few", "distinct frames of"), ("still", "could not be followed")])
def test_require_mappable_says_why(kind, words):
    rng = np.random.default_rng(1)
    stats = FrameStats.for_settings(Settings())
    frames = 3 if kind == "few" else 20
    for _ in range(frames):
        stats.add({"dark": np.zeros((120, 160), np.float32), "blank": np.full((120, 160), 90, np.float32)}
                  .get(kind, _textured(rng)))
    with pytest.raises(PipemapError, match=words):
        require_mappable(stats, 1, frames, 0, Settings(), "data")


def test_enough_frames_pass():
    rng = np.random.default_rng(2)
    stats = FrameStats.for_settings(Settings())
    for _ in range(20):
        stats.add(_textured(rng))
    require_mappable(stats, 10, 20, 0, Settings(), "data")


def _dataset(root, images):
    import cv2

    (root / "images").mkdir(parents=True)
    for i, im in enumerate(images):
        cv2.imwrite(str(root / "images" / f"{i:04d}.png"), im)
    h, w = images[0].shape
    doc = {"format": "pipemap-dataset/1", "name": "t", "images": "images/*.png", "fps": 7.5,
           "camera": {"model": "pinhole", "width": w, "height": h,
                      "params": {"fx": 200.0, "fy": 200.0, "cx": w / 2 - 0.5, "cy": h / 2 - 0.5,
                                 "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}},
           "pipe": {"radius_m": 0.15}}
    (root / "dataset.yaml").write_text(yaml.safe_dump(doc))
    return root


@pytest.mark.parametrize("method", ["network", "sparse-cylinder"])
@pytest.mark.parametrize("case", ["one frame", "black"])
def test_cli_refuses_with_one_line_and_no_folder(tmp_path, method, case):
    rng = np.random.default_rng(3)
    images = ([_textured(rng, (240, 320)).astype(np.uint8)] if case == "one frame"
              else [np.zeros((240, 320), np.uint8)] * 30)
    data = _dataset(tmp_path / "data", images)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["run", str(data), "--out", str(out), "--method", method])
    assert res.exit_code == 2
    lines = [l for l in res.output.splitlines() if l.startswith("pipemap: error:")]
    assert len(lines) == 1 and str(data) in lines[0]
    assert ("distinct frame" in lines[0]) if case == "one frame" else ("are dark" in lines[0])
    assert not out.exists() and not list(tmp_path.glob(".out*"))
