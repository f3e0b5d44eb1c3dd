"""Where written frames go: numbered PNGs or one video file (PyAV), each frame stamped with its slot.

Video: H.264 (libx264, constant rate factor) or MPEG-4 part 2 (fixed quantiser) in .mp4, MJPEG
(fixed quantiser) in .mov, all 4:2:0. A grey frame is grey-in-YUV: luma only, chroma at 128;
H.264 and MPEG-4 use limited-range luma (16..235, what players and PyAV's `format="gray"`
conversion assume), MJPEG full range (yuvj420p), so a reader converting to grey gets the frame
back to within the codec's loss. A frame's presentation time is its slot (time base 1/fps), so a
dropped frame leaves a gap in the timestamps while the frames themselves stay consecutive.
Interlaced frames are flagged top field first (and coded as interlaced by H.264 and MPEG-4).
Encoding runs on one thread so that the same input gives the same bytes on any machine.
"""

from __future__ import annotations

import queue
import threading
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from pipemap.errors import PipemapError
from pipemap.sim.effects import Video

_CODECS = {"h264": ("libx264", "yuv420p", ".mp4"), "mpeg4": ("mpeg4", "yuv420p", ".mp4"),
           "mjpeg": ("mjpeg", "yuvj420p", ".mov")}


_FIELD_TT = 2  # AVFieldOrder AV_FIELD_TT: top field coded and shown first


def video_name(video: Video) -> str:
    return "video" + _CODECS[video.codec][2]


class PngWriter:
    """Encodes and writes PNGs on a thread (OpenCV releases the GIL) while the next frame renders."""

    def __init__(self, depth: int = 2):
        self.q: queue.Queue = queue.Queue(maxsize=depth)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def _run(self):
        while True:
            item = self.q.get()
            if item is None:
                return
            path, img = item
            if self.error is None:
                try:
                    if not cv2.imwrite(str(path), img):
                        raise PipemapError("cannot write image", path)
                except BaseException as exc:  # handed to the main thread
                    self.error = exc

    def put(self, path: Path, img: np.ndarray) -> None:
        if self.error is not None:
            raise self.error
        self.q.put((path, img))

    def __exit__(self, exc_type, exc, tb):
        self.q.put(None)
        self.thread.join()
        if exc_type is None and self.error is not None:
            raise self.error
        return False


class PngFrames:
    """images/000000.png ...: written frame k is file k."""

    glob = "images/*.png"

    def __init__(self, folder: Path):
        self.images = Path(folder) / "images"
        self.images.mkdir()
        self.writer = PngWriter()

    def __enter__(self):
        self.writer.__enter__()
        return self

    def put(self, index: int, slot: int, img: np.ndarray) -> None:
        self.writer.put(self.images / f"{index:06d}.png", img)

    def __exit__(self, *exc):
        return self.writer.__exit__(*exc)


class VideoFrames:
    """One video file in `folder`, frames presented at their slot / fps."""

    def __init__(self, folder: Path, video: Video, width: int, height: int, fps: float, interlaced: bool = False):
        import av

        if width % 2 or height % 2:
            raise PipemapError(f"4:2:0 video needs an even width and height, got {width}x{height}", key="effects.video")
        codec, self.pix_fmt, _ = _CODECS[video.codec]
        self.glob = video_name(video)
        self.path = Path(folder) / self.glob
        rate = Fraction(fps).limit_denominator(100000)
        self.time_base = 1 / rate
        self.container = av.open(str(self.path), "w")
        stream = self.container.add_stream(codec, rate=rate)
        stream.width, stream.height, stream.pix_fmt = int(width), int(height), self.pix_fmt
        stream.codec_context.thread_count = 1
        options = {}
        if video.codec == "h264":
            options.update(crf=f"{video.crf:g}", preset=video.preset, threads="1")
        else:  # a fixed quantiser: rate control may not raise it, and the bit rate cap is out of reach
            options.update(qmin=str(video.qscale), qmax=str(video.qscale))
            stream.bit_rate = 1_000_000_000
        if video.gop is not None:
            stream.codec_context.gop_size = int(video.gop)
        if interlaced:  # top field first, flagged; H.264 and MPEG-4 code the fields as interlaced video
            stream.codec_context.field_order = _FIELD_TT
            if video.codec != "mjpeg":
                options.update(flags="+ildct+ilme")
        stream.options = options
        self.stream = stream

    def __enter__(self):
        return self

    def put(self, index: int, slot: int, img: np.ndarray) -> None:
        import av

        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="gray").reformat(format=self.pix_fmt)
        frame.pts = int(slot)
        frame.time_base = self.time_base
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is None:
                for packet in self.stream.encode():
                    self.container.mux(packet)
        finally:
            self.container.close()
        return False
