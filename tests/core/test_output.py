"""--force: an existing output is replaced only by a complete new one, and never when it holds an input."""

from __future__ import annotations

import pytest

from pipemap.errors import PipemapError
from pipemap.output import forced, result_folder


def _old(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    return out


def test_forced_replaces_after_success(tmp_path):
    out = _old(tmp_path)
    with forced(out, True):
        with result_folder(out) as tmp:
            (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing set aside is left


def test_forced_puts_the_old_output_back_on_failure(tmp_path):
    out = _old(tmp_path)
    with pytest.raises(RuntimeError):
        with forced(out, True):
            with result_folder(out) as tmp:
                (tmp / "new.txt").write_text("half")
                raise RuntimeError("interrupted")
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_without_force_the_writer_refuses(tmp_path):
    out = _old(tmp_path)
    with pytest.raises(PipemapError, match="already exists"):
        with forced(out, False):
            with result_folder(out):
                pass
    assert (out / "old.txt").read_text() == "old"


@pytest.mark.parametrize("given", ["out", "out/data"])
def test_forced_never_replaces_an_input(tmp_path, given):
    out = _old(tmp_path)
    (out / "data").mkdir()
    with pytest.raises(PipemapError, match="would replace the input"):
        with forced(out, True, [tmp_path / given]):
            pass
    assert (out / "old.txt").read_text() == "old" and (out / "data").is_dir()


def test_forced_file(tmp_path):
    from pipemap.output import atomic_write_text

    path = tmp_path / "metrics.json"
    path.write_text("old")
    with forced(path, True):
        atomic_write_text(path, "new")
    assert path.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]
