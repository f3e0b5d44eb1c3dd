"""ROS 1 and ROS 2 bags: raw and compressed image topics, frames in stamp order, stamps as times."""

import numpy as np
import pytest

from footage_helpers import texture_frames, write_bag, write_dataset
from pipemap.dataset import FootageLog, load_dataset
from pipemap.errors import PipemapError

BASE_NS = 1_700_000_000_000_000_000
STAMPS = [BASE_NS + k * 100_000_000 for k in range(8)] + [BASE_NS + k * 100_000_000 for k in range(10, 14)]
LOG_ORDER = [0, 1, 3, 2, 4, 5, 6, 7, 9, 8, 10, 11]  # frames 2/3 and 8/9 reached the logger swapped


@pytest.mark.parametrize("bag, images, ros2, compressed, encoding, storage", [
    ("run.bag", "run.bag", False, False, "mono8", None),
    ("run.bag", "run.bag", False, True, "mono8", None),
    ("run", "run", True, False, "rgb8", "sqlite3"),
    ("run", "run/run.mcap", True, True, "mono8", "mcap"),
    ("run", "run/run.db3", True, False, "bgr8", "sqlite3"),
])
def test_frames_come_in_stamp_order_with_stamp_times(tmp_path, bag, images, ros2, compressed, encoding, storage):
    frames = texture_frames(12)
    write_bag(tmp_path / bag, frames, STAMPS, LOG_ORDER, ros2=ros2, compressed=compressed, encoding=encoding,
              storage=storage or "sqlite3", extra_topic="/chatter")
    ds = load_dataset(write_dataset(tmp_path, images, topic="/camera/image_raw"))
    assert len(ds) == 12 and ds.image_paths is None and ds.bag_path == tmp_path / images
    log = FootageLog()
    got = list(ds.frames(log=log))
    assert [f.index for f in got] == list(range(12))
    for f in got:  # PNG and raw images are lossless: every frame is exactly the one stamped at its place
        np.testing.assert_array_equal(f.image, frames[f.index].astype(np.float32))
    assert [f.timestamp for f in got] == pytest.approx([(s - BASE_NS) * 1e-9 for s in STAMPS])
    assert ds.time_origin == pytest.approx(1.7e9)
    assert ds.drops() == [(8, 2)] and log.drops == [(8, 2)] and log.repeated == [] and log.damage == []
    assert np.array_equal(ds.read(9).image, got[9].image) and np.array_equal(ds.read(2).image, got[2].image)
    assert [f.index for f in ds.frames(start=7, stop=10)] == [7, 8, 9]


def test_the_only_image_topic_needs_no_name_and_a_bad_message_is_a_hole(tmp_path):
    frames = texture_frames(6)
    frames[2] = None
    write_bag(tmp_path / "run.bag", frames, STAMPS[:6], compressed=True, extra_topic="/chatter")
    ds = load_dataset(write_dataset(tmp_path, "run.bag"))
    assert ds.source.topic == "/camera/image_raw"
    log = FootageLog()
    assert [f.index for f in ds.frames(log=log)] == [0, 1, 3, 4, 5]
    assert [(d.index, d.frames, d.kind) for d in log.damage] == [(2, 1, "unreadable")]
    assert "run.bag: frame 2 cannot be decoded" in log.line()
    with pytest.raises(PipemapError, match="run.bag: frame 2 cannot be decoded"):
        ds.read(2)


def test_a_repeated_message_is_flagged(tmp_path):
    frames = texture_frames(6)
    frames[3] = frames[2]
    write_bag(tmp_path / "run", frames, STAMPS[:6], ros2=True)
    ds = load_dataset(write_dataset(tmp_path, "run"))
    assert [f.index for f in ds.frames() if f.repeated] == [3]


@pytest.mark.parametrize("topic, words", [
    ("/nope", "topic: /nope is not in the bag \\(image topics: /camera/image_raw\\)"),
    ("/chatter", "topic: /chatter is std_msgs/msg/String, not an image"),
])
def test_a_wrong_topic_names_the_key_and_lists_the_image_topics(tmp_path, topic, words):
    write_bag(tmp_path / "run.bag", texture_frames(2), STAMPS[:2], extra_topic="/chatter")
    with pytest.raises(PipemapError, match=f"dataset.yaml: {words}"):
        load_dataset(write_dataset(tmp_path, "run.bag", topic=topic))


def test_bag_errors_are_one_line(tmp_path):
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 100)
    with pytest.raises(PipemapError, match="junk.bag: cannot read ROS bag") as info:
        load_dataset(write_dataset(tmp_path / "a", "../junk.bag"))
    assert "\n" not in str(info.value)
    with pytest.raises(PipemapError, match="images: ROS bag not found"):
        load_dataset(write_dataset(tmp_path / "b", "missing.bag"))
    (tmp_path / "c").mkdir()
    (tmp_path / "c/0.png").write_bytes(b"")
    with pytest.raises(PipemapError, match="topic: is read only from ROS bags"):
        load_dataset(write_dataset(tmp_path / "c", "*.png", topic="/camera/image_raw"))


def test_a_split_ros1_recording_is_one_dataset_and_two_cameras_need_a_topic(tmp_path):
    frames = texture_frames(12)
    write_bag(tmp_path / "run_0.bag", frames[:6], STAMPS[:6])
    write_bag(tmp_path / "run_1.bag", frames[6:], STAMPS[6:])
    ds = load_dataset(write_dataset(tmp_path, "run_*.bag"))
    got = list(ds.frames())
    assert [f.index for f in got] == list(range(12)) and ds.drops() == [(8, 2)]
    np.testing.assert_array_equal(got[7].image, frames[7].astype(np.float32))
    write_bag(tmp_path / "other" / "cams_0.bag", frames[:2], STAMPS[:2], topic="/left/image_raw")
    write_bag(tmp_path / "other" / "cams_1.bag", frames[:2], STAMPS[:2], topic="/right/image_raw")
    with pytest.raises(PipemapError, match="topic: name the camera's topic .image topics in the bag: "
                                           "/left/image_raw, /right/image_raw"):
        load_dataset(write_dataset(tmp_path / "other", "cams_*.bag"))
    ds = load_dataset(write_dataset(tmp_path / "other", "cams_*.bag", topic="/right/image_raw"))
    assert len(ds) == 2
