"""ROS 1 bags and ROS 2 bags (folder, .db3, .mcap): one sensor_msgs Image or CompressedImage topic.

Frames are numbered in the order of their header stamps (the time the camera took them; the bag's
own receive time where a driver leaves the stamp at zero), which is not always the order they were
logged in. One pass over the topic reads every stamp without decoding an image and is cached."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipemap.errors import PipemapError
from pipemap.footage.images import to_grey
from pipemap.footage.records import Damage
from pipemap.footage.source import RawFrame, read_from_stream

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
BAG_SUFFIXES = {".bag", ".db3", ".mcap"}

# ROS encoding -> (dtype, channels, RGB order); bayer patterns map to OpenCV's names as cv_bridge does.
_RAW = {
    "mono8": (np.uint8, 1, False), "8UC1": (np.uint8, 1, False), "mono16": (np.uint16, 1, False),
    "16UC1": (np.uint16, 1, False), "bgr8": (np.uint8, 3, False), "rgb8": (np.uint8, 3, True),
    "bgra8": (np.uint8, 4, False), "rgba8": (np.uint8, 4, True), "8UC3": (np.uint8, 3, False),
    "8UC4": (np.uint8, 4, False), "bgr16": (np.uint16, 3, False), "rgb16": (np.uint16, 3, True),
    "bgra16": (np.uint16, 4, False), "rgba16": (np.uint16, 4, True), "16UC3": (np.uint16, 3, False),
}
_BAYER = {"rggb": cv2.COLOR_BayerBG2BGR, "bggr": cv2.COLOR_BayerRG2BGR,
          "gbrg": cv2.COLOR_BayerGR2BGR, "grbg": cv2.COLOR_BayerGB2BGR}
_YUV = {"yuv422": cv2.COLOR_YUV2GRAY_UYVY, "uyvy": cv2.COLOR_YUV2GRAY_UYVY,
        "yuv422_yuy2": cv2.COLOR_YUV2GRAY_YUY2, "yuyv": cv2.COLOR_YUV2GRAY_YUY2}


def is_bag(target: Path) -> bool:
    return target.suffix.lower() in BAG_SUFFIXES or (target.is_dir() and (target / "metadata.yaml").is_file())


def raw_image_to_grey(msg) -> np.ndarray:
    """A sensor_msgs/Image -> float32 grey on the 0..255 scale (ValueError for what it cannot take)."""
    enc = str(msg.encoding)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, np.uint8)
    if enc.startswith("bayer_"):
        pattern, bits = enc[6:10], enc[10:]
        dtype, channels, rgb, code = (np.uint16 if bits == "16" else np.uint8), 1, False, _BAYER.get(pattern)
        if code is None:
            raise ValueError(f"unknown bayer pattern in encoding {enc!r}")
    elif enc in _YUV:
        dtype, channels, rgb, code = np.uint8, 2, False, _YUV[enc]
    elif enc in _RAW:
        (dtype, channels, rgb), code = _RAW[enc], None
    else:
        raise ValueError(f"image encoding {enc!r} is not supported")
    row = w * channels * np.dtype(dtype).itemsize
    if step < row or data.size < step * h:
        raise ValueError(f"{data.size} bytes cannot hold {w}x{h} {enc} with row step {step}")
    img = data[: step * h].reshape(h, step)[:, :row].copy().view(dtype)
    if dtype != np.uint8 and bool(msg.is_bigendian) == np.little_endian:  # stored in the other byte order
        img = img.byteswap()
    img = img.reshape(h, w, channels) if channels > 1 else img.reshape(h, w)
    if code is not None:
        if enc in _YUV:
            return cv2.cvtColor(img, code).astype(np.float32)
        img = cv2.cvtColor(img, code)
    return to_grey(img, rgb=rgb)


def compressed_image_to_grey(msg) -> np.ndarray:
    """A sensor_msgs/CompressedImage (JPEG or PNG) -> float32 grey on the 0..255 scale."""
    img = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"cannot decode the {str(msg.format) or 'compressed'} image")
    return to_grey(img)


def _stamp_ns(raw: bytes | memoryview, ros2: bool) -> int:
    """The header stamp straight from the serialised bytes: the Header is the first field of both
    image messages (ROS 1: seq, sec, nsec; CDR: 4-byte encapsulation, sec, nanosec)."""
    if ros2:
        order = "<" if raw[1] == 1 else ">"
        sec, nsec = struct.unpack_from(order + "iI", raw, 4)
    else:
        sec, nsec = struct.unpack_from("<II", raw, 4)
    return sec * 1_000_000_000 + nsec


@dataclass(frozen=True)
class BagIndex:
    """stamps: (n,) ns, header stamps in frame order; logged: (n,) ns, when each frame was logged
    (in frame order); rank: (n,) frame index of each message in the bag's own order."""

    topic: str
    msgtype: str
    stamps: np.ndarray
    logged: np.ndarray
    rank: np.ndarray
    error: str | None


_INDEX_CACHE: dict[tuple, BagIndex] = {}


def _fingerprint(paths: list[Path]) -> tuple:
    files = [f for p in paths for f in (sorted(p.rglob("*")) if p.is_dir() else [p]) if f.is_file()]
    return tuple((str(f.resolve()), f.stat().st_size, f.stat().st_mtime_ns) for f in files)


def _reader(paths: list[Path]):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    # Bags from older ROS 2 releases carry no message definitions; sensor_msgs is the same everywhere.
    return AnyReader(paths, default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def _why(exc: Exception) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if "not indexed" in text.lower():
        text += " (a recording that was cut short; `rosbag reindex` repairs it)"
    return text


class RosBag:
    timed = True
    predicted = False  # image topics, raw or compressed (JPEG, PNG), carry each picture alone
    codec = None

    def __init__(self, paths: list[Path], topic: str | None, yaml_path: Path):
        self.paths = paths
        self.path = paths[0]
        self.requested = topic
        self.yaml_path = yaml_path

    def index(self) -> BagIndex:
        key = (_fingerprint(self.paths), self.requested)
        if key not in _INDEX_CACHE:
            _INDEX_CACHE[key] = self._build_index()
        return _INDEX_CACHE[key]

    def check(self) -> None:
        """Open the bag and find the topic (reads the bag's index, not its messages)."""
        try:
            with _reader(self.paths) as reader:
                self._connections(reader)
        except PipemapError:
            raise
        except Exception as exc:  # noqa: BLE001 - rosbags raises many types for unreadable bags
            raise PipemapError(f"cannot read ROS bag: {_why(exc)}", self.path) from None

    def _connections(self, reader):
        images = {name: info for name, info in reader.topics.items() if info.msgtype in IMAGE_TYPES}
        topic = self.requested
        if topic is None:
            if len(images) != 1:
                found = ", ".join(sorted(images)) or "none"
                raise PipemapError(f"name the camera's topic (image topics in the bag: {found})", self.yaml_path,
                                   "topic")
            topic = next(iter(images))
        if topic not in images:
            other = reader.topics.get(topic)
            found = ", ".join(sorted(images)) or "none"
            what = f"is {other.msgtype}, not an image" if other else "is not in the bag"
            raise PipemapError(f"{topic} {what} (image topics: {found})", self.yaml_path, "topic")
        return topic, images[topic].msgtype, [c for c in reader.connections if c.topic == topic]

    def _build_index(self) -> BagIndex:
        stamps, logged, error = [], [], None
        try:
            with _reader(self.paths) as reader:
                topic, msgtype, connections = self._connections(reader)
                try:
                    for _, t, raw in reader.messages(connections=connections):
                        stamp = _stamp_ns(raw, reader.is2)
                        stamps.append(stamp if stamp > 0 else t)
                        logged.append(t)
                except Exception as exc:  # noqa: BLE001 - any failure of a damaged bag ends the readable part
                    error = _why(exc)
        except PipemapError:
            raise
        except Exception as exc:  # noqa: BLE001 - rosbags raises many types for unreadable bags
            raise PipemapError(f"cannot read ROS bag: {_why(exc)}", self.path) from None
        if not stamps and error is None:
            raise PipemapError(f"topic {topic} has no messages", self.path)
        stamps_a, logged_a = np.array(stamps, np.int64), np.array(logged, np.int64)
        order = np.lexsort((np.arange(len(stamps_a)), stamps_a))
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order))
        return BagIndex(topic, msgtype, stamps_a[order], logged_a[order], rank, error)

    def __len__(self) -> int:
        return len(self.index().stamps)

    @property
    def topic(self) -> str:
        return self.index().topic

    @property
    def origin(self) -> float:
        stamps = self.index().stamps
        return float(stamps[0]) * 1e-9 if len(stamps) else 0.0

    def times(self) -> np.ndarray:
        stamps = self.index().stamps
        return (stamps - stamps[0]).astype(np.float64) * 1e-9 if len(stamps) else np.zeros(0)

    def where(self, index: int) -> Path:
        return self.path

    def describe(self) -> str:
        idx = self.index()
        return f"ROS bag topic {idx.topic} ({idx.msgtype.rsplit('/', 1)[-1]}), {len(idx.stamps)} messages"

    def read(self, index: int) -> RawFrame:
        return read_from_stream(self, index)

    def stream(self, start: int, stop: int) -> Iterator[RawFrame | Damage]:
        idx = self.index()
        stop = min(stop, len(idx.stamps))
        if start < stop:
            yield from self._stream(idx, start, stop)
        end = self.cut() if stop == len(idx.stamps) else None
        if end is not None:
            yield end

    def cut(self) -> Damage | None:
        """Where the bag stops being readable, from the index pass alone (None: it does not)."""
        idx = self.index()
        if idx.error is None:
            return None
        return Damage(str(self.path), len(idx.stamps), 0, "truncated",
                      f"cannot be read: the bag is damaged there ({idx.error})")

    def _stream(self, idx: BagIndex, start: int, stop: int) -> Iterator[RawFrame | Damage]:
        # Messages come in logging order; hold the few logged ahead of their stamp order.
        bag_order = idx.logged[idx.rank]
        first_logged = int(idx.logged[start:stop].min())
        if np.all(np.diff(bag_order) >= 0):
            ordinal = int(np.searchsorted(bag_order, first_logged, side="left"))
        else:  # not in time order after all: count every message from the start
            first_logged, ordinal = None, 0
        pending: dict[int, bytes] = {}
        want = start
        try:
            with _reader(self.paths) as reader:
                _, _, connections = self._connections(reader)
                for conn, _, raw in reader.messages(connections=connections, start=first_logged):
                    if ordinal >= len(idx.rank):
                        break
                    i = int(idx.rank[ordinal])
                    ordinal += 1
                    if start <= i < stop:
                        pending[i] = bytes(raw)
                    while want in pending:
                        yield self._decode(reader, conn.msgtype, want, pending.pop(want))
                        want += 1
                    if want >= stop:
                        return
        except PipemapError:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged bag: what was read stands
            if want < stop:
                yield Damage(str(self.path), want, stop - want, "unreadable", f"could not be read ({_why(exc)})")
            return
        if want < stop:
            yield Damage(str(self.path), want, stop - want, "unreadable", "could not be read from the bag")

    def _decode(self, reader, msgtype: str, index: int, raw: bytes) -> RawFrame | Damage:
        try:
            msg = reader.deserialize(raw, msgtype)
            if msgtype.endswith("CompressedImage"):
                return RawFrame(index, compressed_image_to_grey(msg))
            return RawFrame(index, raw_image_to_grey(msg))
        except Exception as exc:  # noqa: BLE001 - one bad message is a hole, not the end of the bag
            return Damage(str(self.path), index, 1, "unreadable", f"cannot be decoded ({_why(exc)})")
