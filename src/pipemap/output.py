"""Writing results safely: nothing half-written that looks complete, nothing the user had overwritten."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

from pipemap.errors import PipemapError


def check_new_file(path: Path, force: bool = False) -> None:
    if path.exists() and not force:
        raise PipemapError("already exists; choose another --out or pass --force to replace it", path)
    if not path.parent.exists():
        raise PipemapError("folder does not exist", path.parent)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _usual_mode(path, base: int) -> None:
    """Temporary files and folders are private (0600 / 0700); the result gets the mode a plain
    open() or mkdir() would have given it."""
    os.chmod(path, base & ~_umask())


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        _usual_mode(tmp, 0o666)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


@contextlib.contextmanager
def replacing(path: Path) -> Iterator[Path]:
    """Yield a temporary name beside `path` (same suffix) to write to; it is renamed onto `path` when
    the block succeeds and removed otherwise."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def result_folder(out: Path) -> Iterator[Path]:
    """Yield a temporary folder beside `out`; on success it is renamed to `out`, on failure removed.

    An existing non-empty `out` is refused, never replaced.
    """
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise PipemapError("output already exists and is not empty; choose another --out", out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        _usual_mode(tmp, 0o777)
        yield tmp
        if out.exists():
            out.rmdir()
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def forced(out: Path, force: bool, inputs: Iterable[Path] = ()) -> Iterator[None]:
    """--force for a command that writes `out` (a result folder or a file) through result_folder or an atomic
    write: an existing `out` is set aside while the command runs, removed once the command has finished,
    and put back if it fails or is interrupted, so the old output is lost only to a complete new one.
    Without force nothing happens here (the writers refuse an existing output themselves). An `out` that is
    or holds one of `inputs` is refused: --force never replaces what the user gave."""
    out = Path(out)
    if not force or not out.exists() or (out.is_dir() and not any(out.iterdir())):
        yield
        return
    target = out.resolve()
    for given in inputs:
        given = Path(given).resolve()
        if given == target or target in given.parents:
            raise PipemapError(f"--force would replace the input {given}; choose another --out", out)
    aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.replaced-", dir=out.parent)) / out.name
    os.replace(out, aside)
    try:
        yield
    except BaseException:
        if not out.exists():
            os.replace(aside, out)
        shutil.rmtree(aside.parent, ignore_errors=True)
        raise
    shutil.rmtree(aside.parent, ignore_errors=True)
