"""The user's static mask, the dataset format's versions, and docs/formats.md naming every key."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from footage_helpers import texture_frames, write_dataset
from pipemap.dataset import FootageLog, load_dataset
from pipemap.errors import PipemapError

DOCS = Path(__file__).resolve().parents[2] / "docs" / "formats.md"


def folder(root, images):
    (root / "images").mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(images):
        cv2.imwrite(str(root / "images" / f"{i:06d}.png"), img)
    return root


def test_mask_is_loaded_as_usable_pixels(tmp_path):
    root = folder(tmp_path, texture_frames(2))
    mask = np.zeros((120, 160), np.uint8)
    mask[10:100, 20:150] = 255
    mask[50, 60] = 1  # any non-zero value is usable
    cv2.imwrite(str(root / "mask.png"), mask)
    ds = load_dataset(write_dataset(root, "images/*.png", mask="mask.png"))
    assert ds.mask.dtype == bool and ds.mask.shape == (120, 160)
    assert np.array_equal(ds.mask, mask != 0) and ds.mask_path == root / "mask.png"
    assert load_dataset(write_dataset(root, "images/*.png")).mask is None


@pytest.mark.parametrize("content, words", [
    (np.full((60, 80), 255, np.uint8), "mask.png: mask is 80x60, the camera is 160x120"),
    (np.zeros((120, 160), np.uint8), "mask.png: mask has no usable pixel"),
    (b"garbage", "mask.png: cannot read mask image"),
])
def test_bad_masks_are_one_line_naming_the_file(tmp_path, content, words):
    root = folder(tmp_path, texture_frames(1))
    if isinstance(content, bytes):
        (root / "mask.png").write_bytes(content)
    else:
        cv2.imwrite(str(root / "mask.png"), content)
    with pytest.raises(PipemapError, match=words) as info:
        load_dataset(write_dataset(root, "images/*.png", mask="mask.png"))
    assert "\n" not in str(info.value)
    with pytest.raises(PipemapError, match="dataset.yaml: mask: file not found"):
        load_dataset(write_dataset(root, "images/*.png", mask="other.png"))


def test_a_masked_out_overlay_does_not_hide_a_stall(tmp_path):
    images = texture_frames(6)
    images[3] = images[2].copy()
    images[3][:, :64] = 255 - images[3][:, :64]  # a big overlay redrawn on the stalled frame: 40 % of it
    root = folder(tmp_path, images)
    assert [f.index for f in load_dataset(write_dataset(root, "images/*.png")).frames() if f.repeated] == []
    mask = np.full((120, 160), 255, np.uint8)
    mask[:, :64] = 0
    cv2.imwrite(str(root / "mask.png"), mask)
    ds = load_dataset(write_dataset(root, "images/*.png", mask="mask.png"))
    assert [f.index for f in ds.frames() if f.repeated] == [3]


def test_old_and_new_format_versions_are_read(tmp_path):
    root = folder(tmp_path, texture_frames(2))
    for fmt in ("pipemap-dataset/1", "pipemap-dataset/2"):
        assert len(load_dataset(write_dataset(root, "images/*.png", format=fmt))) == 2
    with pytest.raises(PipemapError, match="format: expected 'pipemap-dataset/2'"):
        load_dataset(write_dataset(root, "images/*.png", format="pipemap-dataset/3"))


def test_formats_md_documents_every_dataset_key():
    text = DOCS.read_text()
    assert "format: pipemap-dataset/2" in text
    for key in ("deinterlace:", "topic:", "mask:", "timestamps:", "repeated", "dropped", "truncated", "undecodable",
                "unreadable", "footage"):
        assert key in text, key


def test_footage_log_is_json_ready(tmp_path):
    import json

    log = FootageLog(frames=5, repeated=[1, 2, 4], drops=[(3, 2)])
    doc = json.loads(json.dumps(log.to_dict()))
    assert doc == {"frames_read": 5, "repeated": 3, "repeated_frames": [[1, 2], [4, 4]], "dropped": 2,
                   "drops": [{"before": 3, "missing": 2}], "damaged": 0, "damage": [], "predicted": False,
                   "settling_left_out": 0, "deinterlace": {"method": "none", "why": None}}
    assert log.line() == "footage: 5 frames read, 3 repeated, 2 dropped in 1 gap"
