"""Video files: real frame counts, frame-accurate reading and seeking, PTS times, damage."""

import numpy as np
import pytest

from pipemap.dataset import FootageLog, load_dataset
from pipemap.errors import PipemapError
from pipemap.footage.images import ImageFolder
from pipemap.footage.video import VideoFile

from footage_helpers import packets, texture_frames, write_dataset, write_video


def nearest_source(image, sources):
    return int(np.argmin([np.abs(image - s.astype(np.float32)).mean() for s in sources]))


@pytest.mark.parametrize("name, codec, options", [
    ("run.mkv", "libx264", {"crf": "28", "g": "12"}),   # Matroska states no frame count; B-frames reorder
    ("run.mp4", "libx264", {"crf": "28", "g": "12"}),
    ("run.avi", "mjpeg", {}),
    ("run.avi", "mpeg4", {"g": "12"}),
    ("b.avi", "libx264", {"g": "12"}),  # AVI's pts are decoding order: frames are numbered as they come out
])
def test_every_frame_is_the_right_one_streamed_or_sought(tmp_path, frames40, name, codec, options):
    write_video(tmp_path / name, frames40, codec, options=options)
    ds = load_dataset(write_dataset(tmp_path, name))
    assert len(ds) == 40
    frames = list(ds.frames())
    assert [f.index for f in frames] == list(range(40))
    assert [nearest_source(f.image, frames40) for f in frames] == list(range(40))
    np.testing.assert_allclose(ds.times(), np.arange(40) / 10.0, atol=1e-9)
    for i in (0, 13, 25, 39):  # seeking lands on the same frame that streaming gives
        assert np.array_equal(ds.read(i).image, frames[i].image), i
    with pytest.raises(IndexError):
        ds.read(40)
    # a few frames streamed over their span, the others decoded but not converted: the same pictures
    some = [3, 4, 17, 30]
    assert [(f.index, f.image.tobytes()) for f in ds.frames_at(some)] == \
        [(i, frames[i].image.tobytes()) for i in some]


@pytest.mark.parametrize("codec, fmt", [("libx264", "yuv420p"), ("mjpeg", "yuvj420p"), ("mpeg4", "yuv420p")])
def test_grey_by_table_is_ffmpegs_own_conversion(tmp_path, frames40, codec, fmt):
    import av

    from pipemap.footage.video import grey

    write_video(tmp_path / "run.avi", frames40, codec)
    with av.open(str(tmp_path / "run.avi")) as c:
        for k, frame in enumerate(c.decode(video=0)):
            assert frame.format.name == fmt
            ref = frame.to_ndarray(format="gray").astype(np.float32)
            got = grey(frame)
            assert got.dtype == np.float32 and np.array_equal(got, ref), k


def test_times_come_from_pts_and_gaps_are_drops(tmp_path, frames40):
    pts = list(range(10)) + [k + 2 for k in range(10, 30)] + [k + 5 for k in range(30, 40)]
    write_video(tmp_path / "run.mkv", frames40, pts=pts)
    ds = load_dataset(write_dataset(tmp_path, "run.mkv"))
    np.testing.assert_allclose(ds.times(), np.array(pts) / 10.0, atol=1e-9)
    assert ds.drops() == [(10, 2), (30, 3)]
    log = FootageLog()
    frames = list(ds.frames(log=log))
    assert [f.timestamp for f in frames] == pytest.approx(list(np.array(pts) / 10.0))
    assert {f.index: f.dropped_before for f in frames if f.dropped_before} == {10: 2, 30: 3}
    assert log.drops == [(10, 2), (30, 3)] and log.dropped == 5 and log.frames == 40
    assert ds.fps == 10.0 and ds.frame_period == pytest.approx(0.1)
    # With a step, a gap is reported on the next frame handed out.
    assert {f.index: f.dropped_before for f in ds.frames(start=1, step=4) if f.dropped_before} == {13: 2, 33: 3}


@pytest.mark.parametrize("codec, options", [("libx264", {"crf": "28"}), ("libx264", {"crf": "35"}),
                                            ("mjpeg", {}), ("mpeg4", {}),
                                            ("mpeg4", {"g": "5", "qmin": "6", "qmax": "6"}),  # 10, 20 are keyframes
                                            ("libx264", {"crf": "28", "g": "5", "bf": "0"})])
def test_stalled_frames_are_flagged_repeated(tmp_path, codec, options):
    images = texture_frames(30)
    images[10] = images[9]  # the link stalled for two frames: 9 sent again as 10 and 11
    images[11] = images[9]
    images[20] = images[19]
    write_video(tmp_path / "run.avi", images, codec, options=options)
    ds = load_dataset(write_dataset(tmp_path, "run.avi"))
    log = FootageLog()
    flags = [f.index for f in ds.frames(log=log) if f.repeated]
    assert flags == [10, 11, 20]
    assert log.repeated == [10, 11, 20] and log.to_dict()["repeated_frames"] == [[10, 11], [20, 20]]
    assert log.dropped == 0 and log.damage == []


def frames_before(path, packet):
    """Frames, in presentation order, wholly stored before the `packet`-th packet: with B-frames a
    few later frames are stored earlier, and the frames between are lost with a cut there."""
    shown = sorted(p[2] for p in packets(path)[:packet])
    step = shown[1] - shown[0]
    return next((k for k, p in enumerate(shown) if p != shown[0] + k * step), len(shown))


def cut_after(path, packet, into=0.5):
    """Cut `path` part-way through its `packet`-th packet (file order)."""
    pos, size, _, _ = packets(path)[packet]
    path.write_bytes(path.read_bytes()[: pos + int(size * into)])


@pytest.mark.parametrize("name, codec, options, container", [
    ("run.avi", "mjpeg", {}, None),
    ("run.avi", "mpeg4", {}, None),
    ("run.mp4", "libx264", {"g": "10"}, {"movflags": "faststart"}),
    ("run.mkv", "libx264", {"g": "10"}, None),
])
def test_a_file_cut_short_is_read_up_to_the_cut(tmp_path, frames40, name, codec, options, container):
    path = write_video(tmp_path / name, frames40, codec, options=options, container_options=container)
    whole = frames_before(path, 25)
    assert whole in (24, 25)  # B-frames stored ahead of their turn are lost with the packet cut
    cut_after(path, 25)
    ds = load_dataset(write_dataset(tmp_path, name))
    log = FootageLog()
    frames = list(ds.frames(log=log))
    # Every frame shown before the first one lost at the cut is read, and is the right one.
    assert [f.index for f in frames] == list(range(whole))
    assert [nearest_source(f.image, frames40) for f in frames] == list(range(whole))
    assert len(ds) == whole and log.dropped == 0
    (damage,) = log.damage
    assert (damage.kind, damage.index, damage.frames) == ("truncated", whole, 40 - whole)
    assert f"ends after {whole} of the 40 frames" in log.line()
    assert ds.scan().to_dict() == log.to_dict()


def test_a_damaged_frame_is_skipped_with_those_predicted_from_it_and_reading_goes_on(tmp_path, frames40):
    path = write_video(tmp_path / "run.avi", frames40, "mpeg4", options={"g": "12"})  # keyframes 0, 12, 24, 36
    pos, size, pts, key = packets(path)[20]
    data = bytearray(path.read_bytes())
    garbage = np.random.default_rng(3).integers(0, 256, 40, dtype=np.uint8).tobytes()
    data[pos + size // 4: pos + size // 4 + 40] = garbage
    path.write_bytes(bytes(data))
    ds = load_dataset(write_dataset(tmp_path, "run.avi"))
    log = FootageLog()
    frames = list(ds.frames(log=log))
    assert [f.index for f in frames] == [i for i in range(40) if not 20 <= i < 24]
    assert [nearest_source(f.image, frames40) for f in frames] == [f.index for f in frames]
    assert [(d.index, d.frames) for d in log.damage] == [(20, 1), (21, 3)]
    assert "frame 20 is damaged" in log.line() and "frames 21-23 could not be decoded" in log.line()
    with pytest.raises(PipemapError, match="run.avi: frame 20"):
        ds.read(20)
    assert np.array_equal(ds.read(24).image, frames[20].image)


def test_h264_frames_that_lose_their_reference_are_holes_until_the_next_keyframe(tmp_path, frames40):
    path = write_video(tmp_path / "run.mkv", frames40, options={"g": "10"})
    pos, size, pts, key = packets(path)[10]
    assert key
    data = bytearray(path.read_bytes())
    data[pos + size // 4: pos + size // 4 + size // 2] = bytes(size // 2)
    path.write_bytes(bytes(data))
    ds = load_dataset(write_dataset(tmp_path, "run.mkv"))
    log = FootageLog()
    frames = list(ds.frames(log=log))
    read = [f.index for f in frames]
    assert read[:9] == list(range(9)) and read[-20:] == list(range(20, 40)) and 10 not in read
    assert [nearest_source(f.image, frames40) for f in frames] == read  # no concealed garbage handed out
    assert sum(d.frames for d in log.damage) == 40 - len(read)
    assert "frame 10 cannot be decoded" in log.line()


def test_unreadable_videos_are_one_line_errors(tmp_path, frames40):
    (tmp_path / "junk.mp4").write_bytes(b"\x00" * 1000)
    with pytest.raises(PipemapError, match="junk.mp4: cannot open video"):
        load_dataset(write_dataset(tmp_path / "a", "../junk.mp4"))
    path = write_video(tmp_path / "run.mp4", frames40)  # index (moov) written at the end
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(PipemapError, match="run.mp4: cannot open video.*cut short") as info:
        load_dataset(write_dataset(tmp_path / "b", "../run.mp4"))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("name, codec, predicted", [("run.mp4", "libx264", True), ("run.avi", "mjpeg", False),
                                                    ("run.mkv", "ffv1", False), ("run.avi", "mpeg4", True)])
def test_a_video_says_whether_its_pictures_are_predicted(tmp_path, name, codec, predicted):
    write_video(tmp_path / name, texture_frames(3), codec)
    video = VideoFile(tmp_path / name, 10.0)
    assert video.predicted is predicted
    assert video.codec == {"libx264": "h264"}.get(codec, codec)
    images = ImageFolder([tmp_path / "a.jpg"], 10.0)
    assert not images.predicted and images.codec is None
