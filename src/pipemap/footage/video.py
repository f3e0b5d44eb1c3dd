"""Video files (H.264, MJPEG, MPEG-4, ... anything FFmpeg reads) through PyAV, frame-accurately.

A frame's index is its place among the video's packets in presentation order, found by demuxing
once (no decoding; cached per file). So a frame the decoder rejects leaves a hole instead of
shifting every later index, seeking lands on the frame asked for, and the count is the real one
even where the header's count is missing (Matroska) or wrong (a file cut short)."""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import numpy as np

from pipemap.errors import PipemapError
from pipemap.footage.records import Damage
from pipemap.footage.source import RawFrame, read_from_stream

# AVFieldOrder values whose bottom field is displayed first (AV_FIELD_BB, AV_FIELD_TB).
_BOTTOM_FIRST = {3, 4}
_DEPENDENT = "could not be decoded (it depends on a damaged frame)"


@dataclass(frozen=True)
class VideoIndex:
    """What demuxing the whole file found.

    pts: (n,) presentation times of the frames in order, or None where the container gives none,
    repeats them or numbers them in decoding order (then frames are numbered as they come out of
    the decoder); slots: pts -> index; stated: the frames the header promises (0 = not stated; for
    Matroska, from its duration); cut: pts of packets the demuxer found cut short; decoded_at: pts
    -> place of its packet in decoding order; keys: places of the keyframe packets; error: why
    demuxing stopped early, or None."""

    count: int
    pts: np.ndarray | None
    slots: dict
    time_base: Fraction
    stated: int
    cut: frozenset
    cut_short: bool
    codec: str
    width: int
    height: int
    top_field_first: bool
    decoded_at: dict
    keys: np.ndarray
    error: str | None


_INDEX_CACHE: dict[tuple, VideoIndex] = {}
# 8-bit formats whose first plane is the luma: their grey picture is a table lookup of it
_LUMA_FIRST = frozenset({"gray", "yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "yuv411p",
                         "yuv410p", "yuv440p", "yuvj440p", "nv12", "nv21"})
_GREY_TABLES: dict[tuple, np.ndarray] = {}


def _grey_table(fmt: str, color_range: int) -> np.ndarray:
    """(256,) float32: the grey value FFmpeg's own conversion gives each luma value (its range expansion),
    found once by converting a picture holding every luma value."""
    import av

    key = (fmt, color_range)
    if key not in _GREY_TABLES:
        ramp = av.VideoFrame(256, 2, fmt)
        for k, plane in enumerate(ramp.planes):
            rows = np.full((plane.height, plane.line_size), 128, np.uint8)
            if k == 0:
                rows[:, :256] = np.arange(256, dtype=np.uint8)
            plane.update(rows.tobytes())
        ramp.color_range = color_range
        _GREY_TABLES[key] = ramp.to_ndarray(format="gray")[0, :256].astype(np.float32)
    return _GREY_TABLES[key]


def grey(frame) -> np.ndarray:
    """A decoded picture as float32 grey on the 0..255 scale, exactly as FFmpeg converts it to grey; for 8-bit
    luma-first formats by table from the luma plane (a fifth of the conversion's time at 720x576)."""
    fmt = frame.format.name
    if fmt not in _LUMA_FIRST:
        return frame.to_ndarray(format="gray").astype(np.float32)
    plane = frame.planes[0]
    luma = np.frombuffer(plane, np.uint8).reshape(-1, plane.line_size)[:frame.height, :frame.width]
    return _grey_table(fmt, frame.color_range)[luma]
# codecs whose pictures are predicted from earlier ones (motion-compensated); MJPEG, FFV1 and the like code each
# picture alone
PREDICTED_CODECS = frozenset({"h264", "hevc", "mpeg4", "mpeg2video", "mpeg1video", "h263", "msmpeg4v2", "msmpeg4v3",
                              "vp8", "vp9", "av1", "theora", "wmv3", "vc1"})


def _message(exc: Exception) -> str:
    """FFmpeg's reason without its error number and the file or function name it repeats."""
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return text.splitlines()[0]


def _open(path: Path):
    import av

    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError) as exc:
        hint = " (an MP4/MOV cut short loses its index at the end; re-mux or recover it first)" \
            if path.suffix.lower() in {".mp4", ".mov", ".m4v"} else ""
        raise PipemapError(f"cannot open video: {_message(exc)}{hint}", path) from None
    if not container.streams.video:
        container.close()
        raise PipemapError("no video stream in the file", path)
    return container


def video_index(path: Path) -> VideoIndex:
    """Demux every packet once (no decoding); cached while the file's size and time stay the same."""
    import av

    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key in _INDEX_CACHE:
        return _INDEX_CACHE[key]
    with _open(path) as container:
        stream = container.streams.video[0]
        ctx = stream.codec_context
        pts: list = []
        cut = set()
        keys: list[int] = []
        error = None
        try:
            for packet in container.demux(stream):
                if not packet.size:
                    continue
                if packet.is_keyframe:
                    keys.append(len(pts))
                pts.append(packet.pts)
                if packet.is_corrupt:
                    cut.add(packet.pts)
        except av.error.FFmpegError as exc:
            error = _message(exc)
        stated = int(stream.frames or 0)
        end = _stated_end(container) if not stated else None
        ordered = None
        if pts and None not in pts and len(set(pts)) == len(pts):
            ordered = np.sort(np.array(pts, np.int64))
            if "avi" in container.format.name.split(","):
                # AVI's header counts the frames its muxer skipped too; the others count packets.
                stated = max(stated - _skipped(ordered), 0)
            if np.array_equal(ordered, pts) and not _shown_in_order(path):
                ordered = None
        tb = Fraction(stream.time_base or Fraction(1, 1))
        missing_at_end = _missing_at_end(ordered, tb, end)
        cut_short = error is not None or stated > len(pts) or missing_at_end > 0 or bool(pts and pts[-1] in cut)
        if ordered is not None and cut_short:
            tail = set(pts[-(max(int(ctx.has_b_frames or 0), 0) + 2):])
            ordered = _end_at_cut(ordered, tail, cut)
            if end is not None:
                stated = len(ordered) + _missing_at_end(ordered, tb, end)
        count = len(ordered) if ordered is not None else len(pts)
        slots = {int(p): i for i, p in enumerate(ordered)} if ordered is not None else {}
        decoded_at = {p: k for k, p in enumerate(pts)} if ordered is not None else {}
        index = VideoIndex(count, ordered, slots, tb, stated, frozenset(cut), cut_short, ctx.name, ctx.width,
                           ctx.height, ctx.field_order not in _BOTTOM_FIRST, decoded_at, np.array(keys, np.int64),
                           error)
    _INDEX_CACHE[key] = index
    return index


def _shown_in_order(path: Path, frames: int = 48) -> bool:
    """Whether the first frames come out of the decoder in the order of their pts. AVI numbers its
    packets in decoding order and calls that the pts, which B-frames then show out of order: such
    pts say nothing about which frame is which, and frames are numbered as they come out instead."""
    import av

    last = None
    with _open(path) as container:
        try:
            for k, frame in enumerate(container.decode(container.streams.video[0])):
                if frame.pts is None or (last is not None and frame.pts <= last):
                    return False
                last = frame.pts
                if k + 1 >= frames:
                    break
        except av.error.FFmpegError:
            pass
    return True


def _skipped(ordered: np.ndarray) -> int:
    """Frames missing in the gaps between presentation times (as footage.stalls counts drops)."""
    steps = np.diff(ordered)
    if not len(steps):
        return 0
    step = float(np.median(steps))
    return int(np.sum(np.where(steps > 1.5 * step, np.rint(steps / step) - 1, 0)))


def _stated_end(container) -> float | None:
    """Matroska states no frame count, but its header keeps the duration even when the file is cut
    short: the time its last frame should end at (seconds), or None."""
    if "matroska" not in container.format.name or not container.duration:
        return None
    return (container.duration + (container.start_time or 0)) / 1e6


def _missing_at_end(ordered: np.ndarray | None, tb: Fraction, end: float | None) -> int:
    """Frames between the last one present and the stated end (0 when not known)."""
    if end is None or ordered is None or len(ordered) < 2:
        return 0
    step = float(np.median(np.diff(ordered))) * float(tb)
    if step <= 0:
        return 0
    return max(int(round((end - (float(ordered[-1]) * float(tb) + step)) / step)), 0)


def _end_at_cut(ordered: np.ndarray, tail: set, cut: set) -> np.ndarray:
    """A file cut short loses its last packets in decoding order, which with B-frames are not its
    last frames in presentation order: end the recording at the first frame near the cut that is
    missing or cut short, so the frames lost there are not counted as dropped."""
    steps = np.diff(ordered)
    step = float(np.median(steps)) if len(steps) else 0.0
    for s in range(max(0, len(ordered) - 2 * len(tail)), len(ordered)):
        gap = s > 0 and ordered[s] - ordered[s - 1] > 1.5 * step
        if int(ordered[s]) in tail and (int(ordered[s]) in cut or gap):
            return ordered[:s]
    return ordered


class _SeekMissed(Exception):
    """The seek landed after the frame asked for; decode from the start instead."""


class VideoFile:
    def __init__(self, path: Path, fps: float):
        self.path = path
        self.fps = fps

    def check(self) -> None:
        """Open the file and find its video stream (reads the header only)."""
        _open(self.path).close()

    def index(self) -> VideoIndex:
        return video_index(self.path)

    def __len__(self) -> int:
        return self.index().count

    @property
    def timed(self) -> bool:
        return self.index().pts is not None

    @property
    def codec(self) -> str:
        return self.index().codec

    @property
    def predicted(self) -> bool:
        return self.codec in PREDICTED_CODECS

    @property
    def origin(self) -> float:
        idx = self.index()
        return float(idx.pts[0] * idx.time_base) if idx.pts is not None and idx.count else 0.0

    def times(self) -> np.ndarray:
        idx = self.index()
        if idx.pts is None:
            return np.arange(idx.count) / self.fps
        return (idx.pts - idx.pts[0]).astype(np.float64) * float(idx.time_base)

    def where(self, index: int) -> Path:
        return self.path

    def describe(self) -> str:
        idx = self.index()
        stated = f", header promises {idx.stated}" if idx.stated and idx.stated != idx.count else ""
        return f"{idx.codec} video {idx.width}x{idx.height}, {idx.count} frames{stated}"

    def read(self, index: int) -> RawFrame:
        return read_from_stream(self, index)

    def stream(self, start: int, stop: int, wanted: frozenset | None = None) -> Iterator[RawFrame | Damage]:
        """As FrameSource.stream; `wanted`: only these indices are handed out as frames (the others are decoded,
        as the pictures after them need, but not converted)."""
        idx = self.index()
        stop = min(stop, idx.count)
        if start < stop:
            if idx.pts is None:
                yield from self._stream_in_decoding_order(idx, start, stop, wanted)
            else:
                try:
                    yield from self._stream_by_pts(idx, start, stop, seek=start > 0, wanted=wanted)
                except _SeekMissed:
                    yield from self._stream_by_pts(idx, start, stop, seek=False, wanted=wanted)
        if stop == idx.count and start <= stop:
            end = self.cut()
            if end is not None:
                yield end

    def cut(self) -> Damage | None:
        """How the file ends short of what its header promises, from the index alone (None: it does not)."""
        idx = self.index()
        missing = max(idx.stated - idx.count, 0)
        if idx.error is not None:
            return Damage(str(self.path), idx.count, missing, "truncated",
                          f"cannot be read: the file is damaged there ({idx.error})")
        if idx.stated > idx.count:
            return Damage(str(self.path), idx.count, missing, "truncated",
                          f"are missing: the file ends after {idx.count} of the {idx.stated} frames "
                          "its header promises")
        if idx.cut_short:
            return Damage(str(self.path), idx.count, 0, "truncated", "are missing: the file is cut short")
        return None

    def _stream_by_pts(self, idx: VideoIndex, start: int, stop: int, seek: bool,
                       wanted: frozenset | None = None) -> Iterator[RawFrame | Damage]:
        import av

        slot_of = idx.slots
        failed: dict[int, str] = {}
        want = start  # the next index to hand out; everything before it is accounted for
        trust = _DamageSpans(idx)
        keyframes = _Keyframes()

        def holes(upto: int) -> Iterator[Damage]:
            for i in range(want, upto):
                reason = failed.get(i) or ("is cut short in the file" if int(idx.pts[i]) in idx.cut else _DEPENDENT)
                yield Damage(str(self.path), i, 1, "undecodable", reason)

        with _open(self.path) as container:
            stream = container.streams.video[0]
            if seek:
                try:
                    container.seek(int(idx.pts[start]), stream=stream, backward=True, any_frame=False)
                except av.error.FFmpegError:
                    raise _SeekMissed from None
            try:
                for packet in container.demux(stream):
                    try:
                        frames = packet.decode()
                    except av.error.FFmpegError as exc:
                        trust.lost(packet.pts)
                        if packet.pts in slot_of:
                            failed[slot_of[packet.pts]] = f"cannot be decoded ({_message(exc)})"
                        continue
                    for frame in frames:
                        i = slot_of.get(frame.pts)
                        if frame.is_corrupt or frame.pts in idx.cut:
                            trust.lost(frame.pts)
                            if i is not None and frame.is_corrupt:
                                failed[i] = "is damaged (the decoder flagged it)"
                            continue
                        if not trust.frame(frame.pts):
                            continue
                        if i is None or i < want:
                            continue
                        if seek and want == start and i > start:
                            raise _SeekMissed
                        seek = False
                        if i >= stop:
                            yield from holes(stop)
                            return
                        yield from holes(i)
                        fresh = keyframes.fresh(frame)
                        if wanted is None or i in wanted:
                            yield RawFrame(i, grey(frame), idx.top_field_first, fresh, bool(frame.interlaced_frame))
                        want = i + 1
                        if want >= stop:
                            return
            except av.error.FFmpegError as exc:
                reason = f"could not be read ({_message(exc)})"
                failed.update({i: reason for i in range(want, stop) if i not in failed})
        yield from holes(stop)

    def _stream_in_decoding_order(self, idx: VideoIndex, start: int, stop: int,
                                  wanted: frozenset | None = None) -> Iterator[RawFrame | Damage]:
        """Frames numbered as they come out of the decoder; a packet it rejects is simply absent,
        so damage shows as fewer frames at the end rather than as a hole in place."""
        import av

        i = 0
        trust = _Trust()
        keyframes = _Keyframes()
        reason = _DEPENDENT
        with _open(self.path) as container:
            try:
                for packet in container.demux(container.streams.video[0]):
                    try:
                        frames = packet.decode()
                    except av.error.FFmpegError as exc:
                        trust.lost()
                        reason = f"could not be decoded ({_message(exc)})"
                        continue
                    for frame in frames:
                        if i >= stop:
                            return
                        good = trust.frame(frame)
                        fresh = keyframes.fresh(frame)
                        if i >= start:
                            if good and (wanted is None or i in wanted):
                                yield RawFrame(i, grey(frame), idx.top_field_first, fresh, bool(frame.interlaced_frame))
                            elif not good:
                                yield Damage(str(self.path), i, 1, "undecodable", _DEPENDENT)
                        i += 1
            except av.error.FFmpegError as exc:
                reason = f"could not be read ({_message(exc)})"
        if i < stop:
            yield Damage(str(self.path), max(i, start), stop - max(i, start), "undecodable", reason)


class _Keyframes:
    """Whether a frame is a keyframe shown after predicted ones (not MJPEG, where all are keys)."""

    def __init__(self):
        self.last_key = True

    def fresh(self, frame) -> bool:
        fresh = bool(frame.key_frame) and not self.last_key
        self.last_key = bool(frame.key_frame)
        return fresh


class _DamageSpans:
    """After damage a decoder conceals what it lost and goes on, and the frames predicted from the
    damaged one come out with garbage in them (measured: 30 grey levels off on a noise texture) and
    no flag. So no frame decoded after a damaged one is trusted until the next keyframe; frames
    decoded before it but shown after it (B-frame reordering) are fine."""

    def __init__(self, idx: VideoIndex):
        self.idx = idx
        self.spans: list[tuple[int, int]] = []  # (damaged packet, next keyframe packet) in decoding order

    def lost(self, pts) -> None:
        at = self.idx.decoded_at.get(pts)
        if at is not None:
            k = int(np.searchsorted(self.idx.keys, at, side="right"))
            self.spans.append((at, int(self.idx.keys[k]) if k < len(self.idx.keys) else len(self.idx.decoded_at)))

    def frame(self, pts) -> bool:
        at = self.idx.decoded_at.get(pts, -1)
        return not any(lo < at < hi for lo, hi in self.spans)


class _Trust:
    """The same rule for frames numbered as they come out (no usable pts): after damage, nothing
    is trusted until the next keyframe."""

    def __init__(self):
        self.damaged = False

    def lost(self) -> None:
        self.damaged = True

    def frame(self, frame, cut: bool = False) -> bool:
        if frame.is_corrupt or cut:
            self.damaged = True
            return False
        if frame.key_frame:
            self.damaged = False
        return not self.damaged
