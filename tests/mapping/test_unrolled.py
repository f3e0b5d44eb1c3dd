"""Unrolled wall images: files, sidecar numbers, orientation (as seen from inside the pipe)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from pipemap.mapping import read_unrolled, write_unrolled
from pipemap.mapping.unrolled import resample_weights
from pipemap.mapping.appearance import write_maps

from mapping_helpers import albedo_on_grid, high_pass


def test_unrolled_png_and_json(loop_case, loop_map, tmp_path):
    pngs = write_unrolled(tmp_path / "unrolled", loop_map)
    names = sorted(p.stem for p in pngs)
    seen = sorted(pm.piece.name for pm in loop_map.pieces if pm.piece.unroll and pm.seen.any())
    assert names == seen and "S1.1" in names and "S4.2" in names
    assert not (tmp_path / "unrolled" / "B1.png").exists()  # the tee stub is not unrolled
    for png in pngs:
        img, meta = read_unrolled(png)
        pm = loop_map.piece(meta["piece"])
        piece = pm.piece
        assert img.dtype == np.uint8 and img.shape == (meta["height_px"], meta["width_px"])
        assert img.shape == (round(2 * np.pi * piece.radius / 0.002), round(piece.length / 0.002) + 1)
        assert meta["metres_per_pixel"] == 0.002
        assert meta["metres_per_pixel_along"] == pytest.approx(0.002, rel=0.01)
        assert meta["metres_per_pixel_around"] == pytest.approx(0.002, rel=0.01)
        assert meta["metres_per_pixel_along"] * (img.shape[1] - 1) == pytest.approx(piece.length, abs=1e-9)
        np.testing.assert_allclose(meta["axis"]["start"], piece.start, atol=1e-12)
        np.testing.assert_allclose(meta["axis"]["end"], piece.end, atol=1e-12)
        assert meta["axis"]["radius"] == piece.radius and meta["axis"]["up"] == [0.0, 0.0, 1.0]
        assert meta["phi_per_row_rad"] == pytest.approx(-2 * np.pi / img.shape[0])
        # pixel (row k, column i) is the map at h[i], phi = -k dphi
        I = pm.intensity
        k = np.arange(img.shape[0])
        expect = I[:, (-k) % I.shape[1]].T
        ok = np.isfinite(expect)
        assert np.array_equal(img == 0, ~ok)
        assert np.max(np.abs(img[ok].astype(float) - np.clip(expect[ok], 1, 255))) <= 0.5 + 1e-6


def test_unrolled_image_reads_like_the_wall_seen_from_inside(loop_case, loop_map, tmp_path):
    """The simulator paints its lettering unmirrored seen from inside the pipe, in rows running
    anticlockwise looking along the axis: the unrolled image must match that layout, not its mirror."""
    (png,) = [p for p in write_unrolled(tmp_path / "u", loop_map) if p.stem == "S1.1"]
    img, _ = read_unrolled(png)
    pm = loop_map.piece("S1.1")
    albedo = albedo_on_grid(loop_case, pm).T  # (phi, h)
    W = albedo.shape[0]
    texture_layout = albedo[(-np.arange(W)) % W]  # rows anticlockwise = the simulator's s
    seen = img > 0
    a = high_pass(img.astype(np.float32), seen)[seen]
    right = np.corrcoef(a, high_pass(texture_layout, seen)[seen])[0, 1]
    mirrored = np.corrcoef(a, high_pass(texture_layout[::-1], seen)[seen])[0, 1]
    assert right > 0.6 and abs(mirrored) < 0.2


def test_coarser_unrolled_pixels(loop_map, tmp_path):
    (png,) = [p for p in write_unrolled(tmp_path / "u", loop_map, px_m=0.005) if p.stem == "S1.1"]
    img, meta = read_unrolled(png)
    piece = loop_map.piece("S1.1").piece
    assert img.shape == (round(2 * np.pi * piece.radius / 0.005), round(piece.length / 0.005) + 1)
    assert meta["metres_per_pixel_along"] == pytest.approx(0.005, rel=0.01)
    assert json.loads(png.with_suffix(".json").read_text())["image"] == "S1.1.png"


def test_write_maps_writes_both_outputs(loop_case, tmp_path):
    c = loop_case
    from pipemap.config import Settings

    info = write_maps(tmp_path, c.dataset, c.indices[::3], c.poses[::3], c.pieces, Settings())
    assert (tmp_path / "appearance.ply").exists()
    assert sorted(info["unrolled_images"]) == sorted(p.name for p in (tmp_path / "unrolled").glob("*.png"))
    assert info["keyframes"] == 20 and info["appearance_points"] > 100_000
    assert info["points_per_second"] > 0 and set(info["seconds"]) == {"appearance", "appearance_write"}


@pytest.mark.parametrize("n_src, n_dst", [(600, 600), (600, 300), (601, 250), (600, 1100), (7, 3)])
def test_resampling_keeps_a_ramp_at_the_cell_centres_and_matches_opencv(n_src, n_dst):
    """Linear interpolation and box averages over whole samples return a linear ramp at each image cell's centre
    (away from the clamped ends when enlarging), box averages over part samples within an eighth of a sample;
    equal to cv2.resize where that is a whole-number shrink or linear."""
    w = resample_weights(n_src, n_dst)
    assert w.shape == (n_dst, n_src) and np.allclose(np.asarray(w.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    centres = (np.arange(n_dst) + 0.5) * n_src / n_dst - 0.5  # in source samples
    got = w @ np.arange(n_src, dtype=float)
    inner = (centres >= 0) & (centres <= n_src - 1)
    exact = n_dst >= n_src or n_src % n_dst == 0
    assert np.abs(got - centres)[inner].max() < (1e-9 if exact else 0.125)
    ramp = np.tile(np.random.default_rng(1).uniform(0, 255, n_src).astype(np.float32), (4, 1))
    if exact:
        ref = cv2.resize(ramp, (n_dst, 4), interpolation=cv2.INTER_LINEAR if n_dst >= n_src else cv2.INTER_AREA)
        assert np.abs(ref[0] - w @ ramp[0]).max() < 1e-3
