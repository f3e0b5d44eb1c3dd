"""The one interface behind image folders, videos and ROS bags."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol

import numpy as np

from pipemap.errors import PipemapError
from pipemap.footage.records import Damage


@dataclass(frozen=True)
class RawFrame:
    """One decoded frame before de-interlacing and gain correction.

    index: the frame's place in the recording (holes where frames are damaged);
    image: float32 grey on the 0..255 scale; top_field_first: the field order, for `bob`;
    requantised: see footage.stalls (repeats re-encoded as keyframes)."""

    index: int
    image: np.ndarray
    top_field_first: bool = True
    requantised: bool = False  # a keyframe after predicted frames: a copy would return with fresh coding noise
    interlaced: bool = False  # the decoder says the picture was coded as two fields


class FrameSource(Protocol):
    """A recording as a numbered list of frames.

    `times()`: seconds since the first frame (`origin`: that frame's own time), from one pass over
    the container's index (no decoding), cached. `stream` yields frames in index order and a Damage
    record in place of each frame it cannot read; `read` raises PipemapError for such a frame;
    `cut()` says, from the index alone, whether the recording ends short of what it promises."""

    path: Path
    timed: bool  # the frames carry their own times (else times are index / fps and no drop can be seen)
    predicted: bool  # a video whose pictures are predicted from the pictures before them (H.264, MPEG-4, ...)
    codec: str | None  # a video's codec as FFmpeg names it ("h264"); None for images

    @property
    def origin(self) -> float: ...

    def __len__(self) -> int: ...

    def times(self) -> np.ndarray: ...

    def stream(self, start: int, stop: int) -> Iterator[RawFrame | Damage]: ...

    def read(self, index: int) -> RawFrame: ...

    def where(self, index: int) -> Path: ...

    def cut(self) -> Damage | None: ...

    def describe(self) -> str: ...


def read_from_stream(source: FrameSource, index: int) -> RawFrame:
    """`read` for sources that seek inside `stream`: frame `index`, or PipemapError naming the damage."""
    if not 0 <= index < len(source):
        raise IndexError(index)
    for item in source.stream(index, index + 1):
        if isinstance(item, Damage):
            raise PipemapError(f"frame {index} {item.reason}", source.path)
        return item
    raise PipemapError(f"frame {index} could not be read", source.path)
