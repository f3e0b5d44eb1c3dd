"""Dataset folders: validation with errors naming file and key, lazy frames, video, gain mask."""

import cv2
import numpy as np
import pytest
import yaml

from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError

CAMERA = {"model": "pinhole", "width": 64, "height": 48,
          "params": dict(fx=60.0, fy=60.0, cx=31.5, cy=23.5, k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0)}


def make_dataset(root, n=5, gain=None, **overrides):
    (root / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(n):
        cv2.imwrite(str(root / "images" / f"{i:06d}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    doc = {"format": "pipemap-dataset/1", "name": "t", "images": "images/*.png", "fps": 10.0,
           "camera": CAMERA, "pipe": {"radius_m": 0.2}}
    if gain is not None:
        cv2.imwrite(str(root / "gain_mask.png"), gain)
        doc["gain_mask"] = "gain_mask.png"
    doc.update(overrides)
    (root / "dataset.yaml").write_text(yaml.safe_dump(doc))
    return root


def test_frames_stream_with_index_and_timestamp(tmp_path):
    ds = load_dataset(make_dataset(tmp_path / "d"))
    frames = list(ds.frames(start=1, step=2))
    assert [f.index for f in frames] == [1, 3]
    assert frames[1].timestamp == pytest.approx(0.3)
    raw = cv2.imread(str(tmp_path / "d/images/000003.png"), cv2.IMREAD_GRAYSCALE)
    assert frames[1].image.dtype == np.float32 and np.array_equal(frames[1].image, raw.astype(np.float32))


def test_gain_mask_is_applied(tmp_path):
    gain = np.tile(np.linspace(20000, 60000, 64).astype(np.uint16), (48, 1))
    ds = load_dataset(make_dataset(tmp_path / "d", gain=gain))
    f = ds.read(2)
    raw = ds.read(2, gain_correct=False).image
    g = gain.astype(np.float64) / gain.mean()
    np.testing.assert_allclose(f.image, raw / g, rtol=1e-5)


def test_sixteen_bit_and_colour_frames_become_grey_on_the_8bit_scale(tmp_path):
    root = make_dataset(tmp_path / "d", n=1)
    img16 = np.full((48, 64), 65535, np.uint16)
    cv2.imwrite(str(root / "images/000000.png"), img16)
    assert load_dataset(root).read(0).image.max() == pytest.approx(255.0)
    cv2.imwrite(str(root / "images/000000.png"), np.full((48, 64, 3), 100, np.uint8))
    assert load_dataset(root).read(0).image.mean() == pytest.approx(100.0)


def test_video_frames(tmp_path):
    import av

    root = make_dataset(tmp_path / "d", n=1, images="run.mp4")
    with av.open(str(root / "run.mp4"), "w") as out:
        stream = out.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        for i in range(6):
            img = np.full((48, 64, 3), 40 * i, np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    ds = load_dataset(root)
    assert len(ds) == 6
    frames = list(ds.frames())
    assert [f.index for f in frames] == list(range(6))
    assert frames[3].image.mean() == pytest.approx(120, abs=6)


@pytest.mark.parametrize(
    "change, key",
    [
        ({"format": "something/2"}, "format"),
        ({"fps": 0}, "fps"),
        ({"fps": "fast"}, "fps"),
        ({"pipe": {"radius_m": 0}}, "pipe.radius_m"),
        ({"pipe": {}}, "pipe.radius_m"),
        ({"camera": dict(CAMERA, model="fancy")}, "camera.model"),
        ({"images": "nothing/*.png"}, "images"),
        ({"gain_mask": "missing.png"}, "gain_mask"),
    ],
)
def test_bad_dataset_yaml_names_file_and_key(tmp_path, change, key):
    root = make_dataset(tmp_path / "d", **change)
    if change.get("pipe") == {}:
        doc = yaml.safe_load((root / "dataset.yaml").read_text())
        (root / "dataset.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(PipemapError) as info:
        load_dataset(root)
    line = str(info.value)
    assert "dataset.yaml" in line and key in line


def test_wrong_frame_size_and_corrupt_image_name_the_file(tmp_path):
    root = make_dataset(tmp_path / "d", n=2)
    cv2.imwrite(str(root / "images/000001.png"), np.zeros((10, 10), np.uint8))
    ds = load_dataset(root)
    with pytest.raises(PipemapError, match="000001.png.*10x10"):
        list(ds.frames())
    (root / "images/000001.png").write_bytes(b"not a png")
    with pytest.raises(PipemapError, match="000001.png.*cannot read"):
        ds.read(1)


def test_missing_folder(tmp_path):
    with pytest.raises(PipemapError, match="no dataset.yaml"):
        load_dataset(tmp_path)


def test_results_are_readable_by_others(tmp_path):
    import os
    import stat

    from pipemap.output import atomic_write_text, result_folder

    old = os.umask(0o022)
    try:
        with result_folder(tmp_path / "out") as tmp:
            atomic_write_text(tmp / "a.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "out" / "a.txt").stat().st_mode) == 0o644
