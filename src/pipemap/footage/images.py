"""Image folders: frames as files sorted by name, optional per-image timestamps, the user's mask."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipemap.errors import PipemapError
from pipemap.footage.records import Damage
from pipemap.footage.source import RawFrame


def read_grey(path: Path) -> np.ndarray:
    """Any 8/16-bit grey or colour image -> float32 grey on the 0..255 scale."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise PipemapError("cannot read image (missing, empty or corrupt)", path)
    return to_grey(img)


def to_grey(img: np.ndarray, rgb: bool = False) -> np.ndarray:
    """8/16-bit grey or colour (BGR, or RGB when `rgb`) -> float32 grey on the 0..255 scale."""
    scale = 255.0 / 65535.0 if img.dtype == np.uint16 else 1.0
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        if img.shape[2] == 4:
            code = cv2.COLOR_RGBA2GRAY if rgb else cv2.COLOR_BGRA2GRAY
        else:
            code = cv2.COLOR_RGB2GRAY if rgb else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    return img.astype(np.float32) * np.float32(scale)


def read_mask(path: Path, width: int, height: int) -> np.ndarray:
    """The user's static mask: non-zero = usable pixel -> (height, width) bool."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise PipemapError("cannot read mask image (missing, empty or corrupt)", path)
    if img.shape[:2] != (height, width):
        raise PipemapError(f"mask is {img.shape[1]}x{img.shape[0]}, the camera is {width}x{height}", path)
    usable = img.any(axis=2) if img.ndim == 3 else img != 0
    if not usable.any():
        raise PipemapError("mask has no usable pixel (all zero)", path)
    return usable


def read_timestamps(path: Path, count: int) -> np.ndarray:
    """A timestamps file: one time in seconds per image, in the images' order; `#` starts a comment."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise PipemapError(f"cannot read timestamps: {exc}", path) from None
    times: list[float] = []
    for number, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        try:
            t = float(text)
        except ValueError:
            raise PipemapError(f"line {number}: expected one time in seconds, got {text!r}", path) from None
        if not np.isfinite(t) or (times and t <= times[-1]):
            raise PipemapError(f"line {number}: time {text} is not after the line before", path)
        times.append(t)
    if len(times) != count:
        raise PipemapError(f"{len(times)} timestamps for {count} images", path)
    return np.array(times, np.float64)


class ImageFolder:
    """Frames stored as image files; an unreadable file is a one-frame hole while streaming."""

    def __init__(self, paths: list[Path], fps: float, times: np.ndarray | None = None):
        self.paths = paths
        self.path = paths[0].parent
        self.fps = fps
        self._times = times

    def __len__(self) -> int:
        return len(self.paths)

    predicted = False
    codec = None

    @property
    def timed(self) -> bool:
        return self._times is not None

    @property
    def origin(self) -> float:
        return float(self._times[0]) if self._times is not None else 0.0

    def times(self) -> np.ndarray:
        if self._times is not None:
            return self._times - self._times[0]
        return np.arange(len(self.paths)) / self.fps

    def stream(self, start: int, stop: int) -> Iterator[RawFrame | Damage]:
        for i in range(start, min(stop, len(self.paths))):
            try:
                yield RawFrame(i, read_grey(self.paths[i]))
            except PipemapError as exc:
                yield Damage(str(self.paths[i]), i, 1, "unreadable", exc.message)

    def read(self, index: int) -> RawFrame:
        if not 0 <= index < len(self.paths):
            raise IndexError(index)
        return RawFrame(index, read_grey(self.paths[index]))

    def where(self, index: int) -> Path:
        return self.paths[index]

    def cut(self) -> None:
        return None

    def describe(self) -> str:
        return f"{len(self.paths)} images in {self.path}"
