"""Image folders: an unreadable file is a hole, a timestamps file gives times and drops, repeats."""

import cv2
import numpy as np
import pytest

from footage_helpers import texture_frames, write_dataset
from pipemap.dataset import FootageLog, load_dataset
from pipemap.errors import PipemapError


def image_folder(root, images):
    (root / "images").mkdir(parents=True)
    for i, img in enumerate(images):
        cv2.imwrite(str(root / "images" / f"{i:06d}.png"), img)
    return root


def test_an_unreadable_image_is_skipped_and_recorded(tmp_path):
    root = image_folder(tmp_path, texture_frames(8))
    (root / "images/000003.png").write_bytes(b"\x89PNG broken")
    (root / "images/000004.png").write_bytes(b"")
    ds = load_dataset(write_dataset(root, "images/*.png"))
    log = FootageLog()
    assert [f.index for f in ds.frames(log=log)] == [0, 1, 2, 5, 6, 7]
    assert [(d.index, d.frames, d.kind) for d in log.damage] == [(3, 1, "unreadable"), (4, 1, "unreadable")]
    assert "000003.png: frame 3 cannot read image" in log.line() and log.frames == 6
    with pytest.raises(PipemapError, match="000003.png: cannot read image"):
        ds.read(3)


def test_timestamps_file_gives_times_and_drops(tmp_path):
    root = image_folder(tmp_path, texture_frames(8))
    times = [100.0, 100.1, 100.2, 100.5, 100.6, 100.7, 100.8, 101.0]
    (root / "times.txt").write_text("# seconds\n" + "\n".join(f"{t:.3f}" for t in times) + "\n")
    ds = load_dataset(write_dataset(root, "images/*.png", timestamps="times.txt"))
    np.testing.assert_allclose(ds.times(), np.array(times) - 100.0, atol=1e-9)
    assert ds.time_origin == 100.0 and ds.drops() == [(3, 2), (7, 1)]
    log = FootageLog()
    frames = list(ds.frames(log=log))
    assert [f.dropped_before for f in frames] == [0, 0, 0, 2, 0, 0, 0, 1] and log.dropped == 3
    assert frames[3].timestamp == pytest.approx(0.5)


def test_without_timestamps_frames_are_index_over_fps_and_nothing_is_dropped(tmp_path):
    ds = load_dataset(write_dataset(image_folder(tmp_path, texture_frames(4)), "images/*.png", fps=4.0))
    assert [f.timestamp for f in ds.frames()] == [0.0, 0.25, 0.5, 0.75]
    assert ds.drops() == [] and not ds.source.timed


@pytest.mark.parametrize("text, words", [
    ("0.0\n0.1\n0.1\n0.3\n", "line 3: time 0.1 is not after"),
    ("0.0\n0.1\n0.2\n", "3 timestamps for 4 images"),
    ("0.0\n0.1\nsoon\n0.3\n", "line 3: expected one time in seconds"),
])
def test_bad_timestamps_files_name_the_file_and_line(tmp_path, text, words):
    root = image_folder(tmp_path, texture_frames(4))
    (root / "times.txt").write_text(text)
    with pytest.raises(PipemapError, match=f"times.txt: {words}"):
        load_dataset(write_dataset(root, "images/*.png", timestamps="times.txt"))


def test_repeated_images_are_flagged_against_the_last_kept_one(tmp_path):
    images = texture_frames(12)
    images[5] = images[4].copy()
    images[6] = images[4].copy()
    rng = np.random.default_rng(1)
    noise = rng.normal(0, 0.3, images[4].shape)  # what re-encoding a copy might leave
    images[7] = np.clip(np.rint(images[4] + noise), 0, 255).astype(np.uint8)
    images[9] = images[8].copy()
    images[9][:10, :40] = 255  # a burned-in clock that kept running while the link stalled
    ds = load_dataset(write_dataset(image_folder(tmp_path, images), "images/*.png"))
    log = FootageLog()
    assert [f.index for f in ds.frames(log=log) if f.repeated] == [5, 6, 7, 9]
    assert log.to_dict()["repeated_frames"] == [[5, 7], [9, 9]]
