"""Reads a dataset folder (formats.md): dataset.yaml, frames streamed lazily, gain mask, ground truth.

The frames come from an image folder, a video file or a ROS bag (pipemap.footage); whichever it
is, a frame's index is its place in the recording, and a frame that cannot be read is skipped
while streaming and recorded, so a damaged recording is read up to (and around) the damage."""

from __future__ import annotations

import glob
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from pipemap.camera import CameraModel, camera_from_dict
from pipemap.errors import PipemapError
from pipemap.footage import (DEINTERLACE_AUTO, DEINTERLACE_METHODS, DEINTERLACE_SAMPLES, Damage, FootageLog,
                             FrameSource, ImageFolder, RawFrame, RepeatDetector, RosBag, VideoFile, deinterlace,
                             frame_period, interlaced, is_bag, missing_before,
                             read_grey, read_mask, read_timestamps, to_grey)
from pipemap.yamlfile import read_yaml
from pipemap.network import PipeNetwork, load_network
from pipemap.trajectory import Trajectory, read_tum

FORMAT = "pipemap-dataset/2"
FORMATS_READ = ("pipemap-dataset/1", FORMAT)  # /2 added deinterlace, topic, mask, timestamps: all optional
VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm", ".mpg", ".mpeg", ".ts", ".m2ts"}

__all__ = ["Dataset", "Frame", "FootageLog", "Damage", "load_dataset", "read_grey", "to_grey", "FORMAT"]


@dataclass(frozen=True)
class Frame:
    index: int
    timestamp: float  # seconds since the recording's first frame: PTS, ROS stamps, timestamps file, else index / fps
    image: np.ndarray  # float32 grey, 0..255 scale (16-bit input is rescaled), gain-corrected when asked
    repeated: bool = False  # nearly identical to the last frame that was not: a stalled link (only while streaming)
    dropped_before: int = 0  # frames missing from the recording just before this one (a gap in time)


@dataclass
class Dataset:
    """One dataset folder. Frames are read on demand; nothing is held in memory between them."""

    root: Path
    yaml_path: Path
    name: str
    fps: float  # the nominal rate from dataset.yaml
    camera: CameraModel
    radius_m: float
    image_paths: list[Path] | None  # None for a video or a bag
    video_path: Path | None
    gain_mask_path: Path | None
    source: FrameSource
    bag_path: Path | None = None
    deinterlace: str = "auto"  # as asked for: see `deinterlacing` for what the frames get
    mask_path: Path | None = None
    mask: np.ndarray | None = field(default=None, repr=False)  # (H, W) bool, True = usable pixel; None: all usable

    def __len__(self) -> int:
        """Frames in the recording, readable or not (see `scan` for how many are readable)."""
        return len(self.source)

    # -- time ---------------------------------------------------------------------------

    def times(self) -> np.ndarray:
        """(len,) seconds since the first frame; cached (one pass over a video's or bag's index)."""
        if getattr(self, "_times", None) is None:
            self._times = np.asarray(self.source.times(), np.float64)
        return self._times

    def timestamp(self, index: int) -> float:
        return float(self.times()[index])

    @property
    def time_origin(self) -> float:
        """The first frame's own time in seconds (a video's first PTS, a bag's first stamp as Unix
        time, a timestamps file's first line; 0 for images without one)."""
        return self.source.origin

    @property
    def frame_period(self) -> float:
        """The spacing that dropped frames are counted against (footage.stalls.frame_period)."""
        return frame_period(self.times(), self.fps)

    def missing_before(self) -> np.ndarray:
        """(len,) int: frames dropped just before each frame, from the timestamps alone (cheap)."""
        if getattr(self, "_missing", None) is None:
            self._missing = missing_before(self.times(), self.frame_period)
        return self._missing

    def drops(self) -> list[tuple[int, int]]:
        """(index of the frame after the gap, frames missing) for every gap in the recording."""
        missing = self.missing_before()
        return [(int(i), int(missing[i])) for i in np.flatnonzero(missing)]

    # -- images -------------------------------------------------------------------------

    @property
    def predicted(self) -> bool:
        """The frames are a video whose pictures are predicted from the pictures before them (H.264, MPEG-4, ...)."""
        return bool(self.source.predicted)

    @property
    def codec(self) -> str | None:
        """A video's codec as FFmpeg names it ("h264"); None for images and bags."""
        return self.source.codec

    @property
    def has_gain_mask(self) -> bool:
        return self.gain_mask_path is not None

    def gain(self) -> np.ndarray | None:
        """The normalised gain mask / mean(mask), or None. Cached after the first call."""
        if self.gain_mask_path is None:
            return None
        if getattr(self, "_gain", None) is None:
            mask = read_grey(self.gain_mask_path)
            if mask.shape != (self.camera.height, self.camera.width):
                raise PipemapError(
                    f"gain mask is {mask.shape[1]}x{mask.shape[0]}, "
                    f"the camera is {self.camera.width}x{self.camera.height}",
                    self.gain_mask_path,
                )
            if mask.max() <= 0:
                raise PipemapError("gain mask is all zero", self.gain_mask_path)
            norm = mask / mask.mean()
            # Pixels the mask says receive no light cannot be corrected; keep them finite.
            self._gain = np.maximum(norm, 1e-3).astype(np.float32)
        return self._gain

    def read(self, index: int, gain_correct: bool = True) -> Frame:
        """One frame by index (a video seeks to it). PipemapError if that frame is damaged."""
        if not 0 <= index < len(self):
            raise IndexError(index)
        return self._frame(self.source.read(index), gain_correct)

    @property
    def deinterlacing(self) -> tuple[str, str]:
        """(the de-interlacing the frames get, why when `auto` chose it): `auto` looks at a few pictures spread
        through the recording once (footage.deinterlace.interlaced)."""
        if self.deinterlace != "auto":
            return self.deinterlace, ""
        if getattr(self, "_deinterlacing", None) is None:
            found, why = interlaced(self._samples(DEINTERLACE_SAMPLES))
            self._deinterlacing = (DEINTERLACE_AUTO if found else "none", why)
        return self._deinterlacing

    def _samples(self, n: int) -> list[RawFrame]:
        """Up to n readable raw frames spread through the recording (its first and last tenth left out: a crawler
        often stands at the start)."""
        total = len(self)
        at = np.unique(np.linspace(0.1 * (total - 1), 0.9 * (total - 1), n).round().astype(int)) if total else []
        out = []
        for i in at:
            try:
                out.append(self.source.read(int(i)))
            except PipemapError:
                continue
        return out

    def frames(self, start: int = 0, stop: int | None = None, step: int = 1, gain_correct: bool = True,
               log: FootageLog | None = None) -> Iterator[Frame]:
        """Stream the readable frames in index order, flagged `repeated` and `dropped_before`.

        Damaged frames are skipped. Pass a FootageLog to have it filled with what this pass found
        (frames read, repeated indices, drops, damage records) for run.json."""
        stop = len(self) if stop is None else min(stop, len(self))
        if log is not None:
            log.deinterlace, log.deinterlace_why = self.deinterlacing
        missing = self.missing_before()
        repeats = RepeatDetector(self.mask)
        counted = start  # drops before this index are already handed out
        for item in self.source.stream(start, stop):
            if isinstance(item, Damage):
                if log is not None:
                    log.add_damage(item)
                continue
            if (item.index - start) % step:
                continue
            self._check_size(item)
            dropped = int(missing[counted:item.index + 1].sum())
            counted = item.index + 1
            repeated = repeats.is_repeat(item.image, item.requantised)
            if log is not None:
                log.frames += 1
                if repeated:
                    log.repeated.append(item.index)
                if dropped:
                    log.drops.append((item.index, dropped))
            yield self._frame(item, gain_correct, repeated, dropped)

    def frames_at(self, indices) -> Iterator[Frame]:
        """The readable frames of the sorted image `indices`, each once, in order, gain-corrected (not flagged
        repeated or dropped). An image folder reads each; a video is streamed over their span and only they
        are converted."""
        indices = sorted({int(i) for i in indices})
        if not indices:
            return
        if self.image_paths is not None:
            for i in indices:
                yield self.read(i)
            return
        wanted = frozenset(indices)
        if isinstance(self.source, VideoFile):
            items = self.source.stream(indices[0], indices[-1] + 1, wanted=wanted)
        else:
            items = self.source.stream(indices[0], indices[-1] + 1)
        for item in items:
            if not isinstance(item, Damage) and item.index in wanted:
                self._check_size(item)
                yield self._frame(item, True)

    def scan(self, progress: Callable[[int, int], None] | None = None) -> FootageLog:
        """Read every frame once: how many are readable, repeated, dropped and damaged."""
        log = FootageLog()
        total = len(self)
        for frame in self.frames(gain_correct=False, log=log):
            if progress is not None:
                progress(frame.index + 1, total)
        return log

    def describe(self) -> str:
        return self.source.describe()

    def _check_size(self, raw: RawFrame) -> None:
        h, w = raw.image.shape[:2]
        if (h, w) != (self.camera.height, self.camera.width):
            raise PipemapError(f"frame {raw.index} is {w}x{h}, "
                               f"dataset.yaml says {self.camera.width}x{self.camera.height}",
                               self.source.where(raw.index))

    def _frame(self, raw: RawFrame, gain_correct: bool, repeated: bool = False, dropped: int = 0) -> Frame:
        self._check_size(raw)
        img = deinterlace(raw.image, self.deinterlacing[0], raw.top_field_first)
        gain = self.gain() if gain_correct else None
        if gain is not None:
            img = img / gain
        return Frame(raw.index, self.timestamp(raw.index), img, repeated, dropped)

    # -- ground truth -------------------------------------------------------------------

    @property
    def ground_truth_dir(self) -> Path:
        return self.root / "ground_truth"

    def ground_truth_poses(self) -> Trajectory | None:
        path = self.ground_truth_dir / "poses.tum"
        return read_tum(path) if path.exists() else None

    def network(self) -> PipeNetwork | None:
        path = self.ground_truth_dir / "network.yaml"
        return load_network(path) if path.exists() else None


def _require(data: dict, key: str, path: Path):
    node = data
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            raise PipemapError("missing", path, key)
        node = node[part]
    return node


def _positive(value, path: Path, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PipemapError(f"must be a number, got {value!r}", path, key)
    if not np.isfinite(value) or value <= 0:
        raise PipemapError(f"must be positive, got {value!r}", path, key)
    return float(value)


def _file_key(data: dict, key: str, root: Path, yaml_path: Path) -> Path | None:
    value = data.get(key)
    if value is None or value == "":
        return None
    if not isinstance(value, str):
        raise PipemapError(f"expected a file name, got {value!r}", yaml_path, key)
    path = root / value
    if not path.is_file():
        raise PipemapError(f"file not found: {path}", yaml_path, key)
    return path


def _deinterlace_method(data: dict, yaml_path: Path) -> str:
    value = data.get("deinterlace")
    if value is None:
        return "auto"
    if value is False:  # YAML reads `off` / `no` as false
        return "none"
    if not isinstance(value, str) or value.lower() not in DEINTERLACE_METHODS:
        raise PipemapError(f"expected one of {', '.join(DEINTERLACE_METHODS)}, got {value!r}", yaml_path, "deinterlace")
    return value.lower()


def _bags(images: str, target: Path, matches: list[Path]) -> list[Path]:
    """The bag files `images:` names: one bag (ROS 1 file, ROS 2 folder or storage file), or a glob
    of ROS 1 files (a split recording); [] when it names something else."""
    if matches:
        return matches if all(p.suffix.lower() == ".bag" for p in matches) else []
    return [target] if not any(c in images for c in "*?[") and is_bag(target) else []


def _source(data: dict, root: Path, yaml_path: Path, fps: float) -> tuple[FrameSource, dict]:
    """The recording that `images:` names, and the Dataset fields that describe it."""
    images = _require(data, "images", yaml_path)
    if not isinstance(images, str) or not images.strip():
        raise PipemapError("expected a glob of image files, a video file or a ROS bag", yaml_path, "images")
    topic = data.get("topic")
    if topic is not None and (not isinstance(topic, str) or not topic.strip()):
        raise PipemapError(f"expected a topic name, got {topic!r}", yaml_path, "topic")
    target = root / images
    is_glob = any(c in images for c in "*?[")
    matches = sorted(Path(p) for p in glob.glob(str(target))) if is_glob else []
    bags = _bags(images, target, matches)
    if topic is not None and not bags:
        raise PipemapError("is read only from ROS bags, and images: is not one", yaml_path, "topic")
    if data.get("timestamps") is not None and (bags or target.suffix.lower() in VIDEO_SUFFIXES):
        raise PipemapError("is read only for image folders (videos and bags carry their own times)",
                           yaml_path, "timestamps")
    if bags:
        if not bags[0].exists():
            raise PipemapError(f"ROS bag not found: {bags[0]}", yaml_path, "images")
        bag = RosBag(bags, topic, yaml_path)
        bag.check()
        return bag, {"image_paths": None, "video_path": None, "bag_path": bags[0]}
    if not is_glob and target.suffix.lower() in VIDEO_SUFFIXES:
        if not target.is_file():
            raise PipemapError(f"video file not found: {target}", yaml_path, "images")
        video = VideoFile(target, fps)
        video.check()
        return video, {"image_paths": None, "video_path": target}
    paths = [p for p in (matches if is_glob else [target]) if p.is_file()]
    if not paths:
        raise PipemapError(f"no images match {images!r}", yaml_path, "images")
    times_path = _file_key(data, "timestamps", root, yaml_path)
    times = read_timestamps(times_path, len(paths)) if times_path is not None else None
    return ImageFolder(paths, fps, times), {"image_paths": paths, "video_path": None}


def load_dataset(path: str | Path) -> Dataset:
    """Open a dataset folder (or its dataset.yaml) and validate it; errors name the file and key."""
    path = Path(path)
    yaml_path = path / "dataset.yaml" if path.is_dir() else path
    if not yaml_path.exists():
        where = path if path.exists() else yaml_path
        raise PipemapError("no dataset.yaml here" if path.is_dir() else "dataset not found", where)
    root = yaml_path.parent
    data = read_yaml(yaml_path, "dataset.yaml")
    fmt = data.get("format")
    if fmt not in FORMATS_READ:
        raise PipemapError(f"expected '{FORMAT}' (or '{FORMATS_READ[0]}'), found {fmt!r}", yaml_path, "format")
    fps = _positive(_require(data, "fps", yaml_path), yaml_path, "fps")
    radius = _positive(_require(data, "pipe.radius_m", yaml_path), yaml_path, "pipe.radius_m")
    camera = camera_from_dict(_require(data, "camera", yaml_path), yaml_path)
    method = _deinterlace_method(data, yaml_path)
    source, fields = _source(data, root, yaml_path, fps)
    gain_mask_path = _file_key(data, "gain_mask", root, yaml_path)
    mask_path = _file_key(data, "mask", root, yaml_path)
    mask = read_mask(mask_path, camera.width, camera.height) if mask_path is not None else None
    name = str(data.get("name") or root.name)
    return Dataset(root, yaml_path, name, fps, camera, radius, fields.pop("image_paths"), fields.pop("video_path"),
                   gain_mask_path, source, deinterlace=method, mask_path=mask_path, mask=mask, **fields)
