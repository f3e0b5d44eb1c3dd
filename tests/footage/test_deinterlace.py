"""De-interlacing: bob keeps the first field and rebuilds the other, blend is a [1, 2, 1] / 4 filter; auto blends
a recording whose decoder says it was coded as fields or whose pictures comb."""

import numpy as np
import pytest

from footage_helpers import write_dataset, write_video
from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.footage import RawFrame, deinterlace, interlaced as is_interlaced
from pipemap.footage.deinterlace import COMBING_LIMIT, anisotropy, combing


def interlaced(shift_px: float, h: int = 120, w: int = 160) -> tuple[np.ndarray, np.ndarray]:
    """A smooth picture whose bottom field was taken `shift_px` later (the camera moved right)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    scene = lambda x: 128 + 60 * np.sin(x / 6.0) * np.cos(yy / 9.0)  # noqa: E731
    first, second = scene(xx), scene(xx - shift_px)
    frame = first.copy()
    frame[1::2] = second[1::2]
    return frame.astype(np.float32), first.astype(np.float32)


def comb(img: np.ndarray) -> float:
    """Mean jump between neighbouring lines beyond what the lines two apart say (combing)."""
    return float(np.abs(img[1:-1] - 0.5 * (img[:-2] + img[2:])).mean())


def test_bob_shows_the_first_field_alone():
    frame, first = interlaced(6.0)
    out = deinterlace(frame, "bob")
    assert np.array_equal(out[0::2], frame[0::2])
    np.testing.assert_allclose(out[1:-1:2], 0.5 * (frame[0:-2:2] + frame[2::2]))
    np.testing.assert_array_equal(out[-1], frame[-2])  # the last line has only a neighbour above
    assert comb(frame) > 20 * comb(out)
    assert np.abs(frame - first).max() > 20 and np.abs(out - first)[2:-2].max() < 2.0  # the first instant


def test_bob_keeps_the_bottom_field_when_it_comes_first():
    frame, _ = interlaced(6.0)
    out = deinterlace(frame, "bob", top_field_first=False)
    assert np.array_equal(out[1::2], frame[1::2])
    np.testing.assert_allclose(out[2::2], 0.5 * (frame[1:-1:2] + frame[3::2]))
    np.testing.assert_array_equal(out[0], frame[1])


def test_blend_is_a_vertical_1_2_1_filter():
    frame, _ = interlaced(6.0)
    out = deinterlace(frame, "blend")
    np.testing.assert_allclose(out[1:-1], 0.25 * frame[:-2] + 0.5 * frame[1:-1] + 0.25 * frame[2:], atol=1e-4)
    np.testing.assert_allclose(out[0], 0.5 * frame[0] + 0.5 * frame[1], atol=1e-4)  # mirrored at the border
    assert comb(out) < 0.3 * comb(frame)
    flat = np.full((48, 64), 77.0, np.float32)
    assert np.array_equal(deinterlace(flat, "blend"), flat) and deinterlace(frame, "none") is frame


def test_dataset_key_deinterlaces_every_frame(tmp_path):
    frame, _ = interlaced(6.0)
    images = [np.clip(frame, 0, 255).astype(np.uint8)] * 3
    write_video(tmp_path / "run.avi", images, "mjpeg")
    plain = load_dataset(write_dataset(tmp_path / "a", "../run.avi", deinterlace="none")).read(1).image
    for method in ("bob", "blend"):
        ds = load_dataset(write_dataset(tmp_path / method, "../run.avi", deinterlace=method))
        assert ds.deinterlace == method
        assert np.array_equal(ds.read(1).image, deinterlace(plain, method))
        assert np.array_equal(next(ds.frames(start=1)).image, deinterlace(plain, method))
    assert load_dataset(write_dataset(tmp_path / "off", "../run.avi", deinterlace=False)).deinterlace == "none"
    with pytest.raises(PipemapError, match="dataset.yaml: deinterlace: expected one of auto, none, bob, blend"):
        load_dataset(write_dataset(tmp_path / "bad", "../run.avi", deinterlace="yadif"))


def textured(h: int = 240, w: int = 320, seed: int = 0) -> np.ndarray:
    """A wall-like picture: smoothed noise at several scales, grey levels 30-220."""
    import cv2

    rng = np.random.default_rng(seed)
    img = sum(cv2.resize(rng.normal(0, 1, (h // s, w // s)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
              for s in (2, 4, 8, 16))
    return (125 + 95 * img / np.abs(img).max()).astype(np.float32)


def test_combing_tells_a_combed_picture_from_a_progressive_one():
    """The wall moved 3 px between the fields: combed. The same wall whole, blurred, noisy or blended: not."""
    import cv2

    wall = textured()
    later = np.roll(wall, 3, axis=1)
    combed = wall.copy()
    combed[1::2] = later[1::2]
    noisy = wall + np.random.default_rng(1).normal(0, 3, wall.shape).astype(np.float32)
    for progressive in (wall, cv2.GaussianBlur(wall, (0, 0), 1.0), noisy, deinterlace(combed, "blend")):
        assert combing(progressive) < 0.75
    assert combing(combed) > 1.2 > COMBING_LIMIT
    samples = [RawFrame(i, img) for i, img in enumerate((combed, combed, wall))]
    found, why = is_interlaced(samples)
    assert found and why.startswith("its pictures comb")
    assert is_interlaced([RawFrame(0, wall)])[1].startswith(f"progressive (combing {combing(wall):.2f}, limit 0.85")
    # noise rows are as far from their neighbours as from the rows two away, but no further than columns are
    noise = np.random.default_rng(2).integers(0, 255, (48, 64)).astype(np.float32)
    assert combing(noise) > COMBING_LIMIT and not is_interlaced([RawFrame(0, noise)])[0]
    assert anisotropy(combed) > 1.25 > 1.1 > anisotropy(wall)
    assert is_interlaced([RawFrame(0, wall, interlaced=True)])[0]  # the decoder's word for it


def test_auto_blends_a_combed_recording_and_leaves_a_progressive_one(tmp_path):
    wall = textured(120, 160)
    combed = [np.roll(wall, 3 * k, axis=1) for k in range(12)]
    for k in range(12):
        combed[k][1::2] = np.roll(wall, 3 * k + 2, axis=1)[1::2]
    write_video(tmp_path / "combed.avi", [np.clip(c, 0, 255).astype(np.uint8) for c in combed], "mjpeg")
    write_video(tmp_path / "plain.avi", [np.clip(np.roll(wall, 3 * k, axis=1), 0, 255).astype(np.uint8)
                                         for k in range(12)], "mjpeg")
    ds = load_dataset(write_dataset(tmp_path / "c", "../combed.avi"))
    assert ds.deinterlace == "auto" and ds.deinterlacing[0] == "blend"
    raw = load_dataset(write_dataset(tmp_path / "c0", "../combed.avi", deinterlace="none")).read(5).image
    assert np.array_equal(ds.read(5).image, deinterlace(raw, "blend"))
    plain = load_dataset(write_dataset(tmp_path / "p", "../plain.avi"))
    assert plain.deinterlacing[0] == "none"
    from pipemap.footage import FootageLog
    log = FootageLog()
    list(ds.frames(log=log))
    assert log.to_dict()["deinterlace"] == {"method": "blend", "why": ds.deinterlacing[1]}
    assert "de-interlaced (blend: its pictures comb" in log.line()
