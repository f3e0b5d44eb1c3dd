"""`pipemap info` on damaged footage: how many frames are readable, repeated, dropped and damaged."""

import re

from typer.testing import CliRunner

from footage_helpers import packets, texture_frames, write_dataset, write_video
from pipemap.cli import app

runner = CliRunner()


def table_text(output: str) -> str:
    """The table's words in order, whatever the terminal's width made of its rows."""
    return " ".join(re.sub("[│┃┌┐└┘├┤┬┴┼─━┏┓┗┛┡┩]", " ", output).split())


def damaged_video(tmp_path):
    images = texture_frames(40)
    images[10] = images[9]
    images[11] = images[9]
    pts = list(range(20)) + [k + 3 for k in range(20, 40)]
    path = write_video(tmp_path / "run.avi", images, "mjpeg", pts=pts)
    pos, size, _, _ = packets(path)[30]
    path.write_bytes(path.read_bytes()[: pos + size // 2])
    return write_dataset(tmp_path, "run.avi")


def test_info_counts_readable_repeated_dropped_and_damaged_frames(tmp_path):
    result = runner.invoke(app, ["info", str(damaged_video(tmp_path))])
    assert result.exit_code == 0, result.output
    text = table_text(result.output)
    for words in ("frames 30 (", "readable 30 of 30", "repeated 2 (10-11)", "dropped 3 in 1 gap (before frame 20)",
                  "frames 30-39 are missing: the file ends after 30 of the 40 frames its header promises"):
        assert words in text, words


def test_info_quick_does_not_decode_but_knows_the_index(tmp_path):
    result = runner.invoke(app, ["info", str(damaged_video(tmp_path)), "--quick"])
    assert result.exit_code == 0, result.output
    text = table_text(result.output)
    for words in ("readable not checked (--quick)", "repeated not checked (--quick)",
                  "dropped 3 in 1 gap (before frame 20)", "damage not checked (--quick);", "ends after 30 of the 40"):
        assert words in text, words


def test_info_on_a_recording_with_nothing_readable_is_one_line(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "images/000000.png").write_bytes(b"broken")
    result = runner.invoke(app, ["info", str(write_dataset(tmp_path, "images/*.png"))])
    assert result.exit_code == 2
    assert "none of the 1 frames can be read" in result.output and result.output.strip().count("\n") == 0
