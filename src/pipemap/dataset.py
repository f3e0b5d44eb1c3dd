"""Reads a dataset folder (formats.md): dataset.yaml, frames streamed lazily, gain mask, ground truth."""

from __future__ import annotations

import glob
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipemap.camera import CameraModel, camera_from_dict
from pipemap.errors import PipemapError
from pipemap.yamlfile import read_yaml
from pipemap.network import PipeNetwork, load_network
from pipemap.trajectory import Trajectory, read_tum

FORMAT = "pipemap-dataset/1"
VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm", ".mpg", ".mpeg"}


@dataclass(frozen=True)
class Frame:
    index: int
    timestamp: float
    image: np.ndarray  # float32 grey, 0..255 scale (16-bit input is rescaled), gain-corrected when asked


def read_grey(path: Path) -> np.ndarray:
    """Any 8/16-bit grey or colour image -> float32 grey on the 0..255 scale."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise PipemapError("cannot read image (missing, empty or corrupt)", path)
    return to_grey(img)


def to_grey(img: np.ndarray) -> np.ndarray:
    scale = 255.0 / 65535.0 if img.dtype == np.uint16 else 1.0
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    return img.astype(np.float32) * np.float32(scale)


@dataclass
class Dataset:
    """One dataset folder. Frames are read on demand; nothing is held in memory between them."""

    root: Path
    yaml_path: Path
    name: str
    fps: float
    camera: CameraModel
    radius_m: float
    image_paths: list[Path] | None  # None for a video
    video_path: Path | None
    gain_mask_path: Path | None

    def __len__(self) -> int:
        if self.image_paths is not None:
            return len(self.image_paths)
        return _video_frame_count(self.video_path)

    def timestamp(self, index: int) -> float:
        return index / self.fps

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
                    f"gain mask is {mask.shape[1]}x{mask.shape[0]}, the camera is {self.camera.width}x{self.camera.height}",
                    self.gain_mask_path,
                )
            if mask.max() <= 0:
                raise PipemapError("gain mask is all zero", self.gain_mask_path)
            norm = mask / mask.mean()
            # Pixels the mask says receive no light cannot be corrected; keep them finite.
            self._gain = np.maximum(norm, 1e-3).astype(np.float32)
        return self._gain

    def read(self, index: int, gain_correct: bool = True) -> Frame:
        if self.image_paths is None:
            for frame in self.frames(start=index, stop=index + 1, gain_correct=gain_correct):
                return frame
            raise PipemapError(f"video has no frame {index}", self.video_path)
        if not 0 <= index < len(self.image_paths):
            raise IndexError(index)
        return self._frame(index, read_grey(self.image_paths[index]), self.image_paths[index], gain_correct)

    def frames(self, start: int = 0, stop: int | None = None, step: int = 1, gain_correct: bool = True) -> Iterator[Frame]:
        """Stream frames lazily in order: index, timestamp = index / fps, float32 grey image."""
        if self.image_paths is not None:
            stop = len(self.image_paths) if stop is None else min(stop, len(self.image_paths))
            for i in range(start, stop, step):
                yield self._frame(i, read_grey(self.image_paths[i]), self.image_paths[i], gain_correct)
            return
        for i, img in _decode_video(self.video_path, start, stop):
            if (i - start) % step == 0:
                yield self._frame(i, to_grey(img), self.video_path, gain_correct)

    def _frame(self, index: int, img: np.ndarray, where: Path, gain_correct: bool) -> Frame:
        if img.shape != (self.camera.height, self.camera.width):
            raise PipemapError(
                f"frame {index} is {img.shape[1]}x{img.shape[0]}, dataset.yaml says {self.camera.width}x{self.camera.height}",
                where,
            )
        gain = self.gain() if gain_correct else None
        if gain is not None:
            img = img / gain
        return Frame(index, self.timestamp(index), img)

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


def _decode_video(path: Path, start: int, stop: int | None) -> Iterator[tuple[int, np.ndarray]]:
    import av

    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError) as exc:
        raise PipemapError(f"cannot open video: {exc}", path) from None
    with container:
        try:
            for i, frame in enumerate(container.decode(video=0)):
                if stop is not None and i >= stop:
                    break
                if i >= start:
                    yield i, frame.to_ndarray(format="gray")
        except av.error.FFmpegError as exc:
            raise PipemapError(f"cannot decode video: {exc}", path) from None


def _video_frame_count(path: Path) -> int:
    import av

    try:
        with av.open(str(path)) as container:
            n = container.streams.video[0].frames
            if n > 0:
                return int(n)
            return sum(1 for _ in container.demux(video=0) if _.size)
    except (av.error.FFmpegError, OSError, IndexError) as exc:
        raise PipemapError(f"cannot open video: {exc}", path) from None


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
    if fmt != FORMAT:
        raise PipemapError(f"expected '{FORMAT}', found {fmt!r}", yaml_path, "format")
    fps = _positive(_require(data, "fps", yaml_path), yaml_path, "fps")
    radius = _positive(_require(data, "pipe.radius_m", yaml_path), yaml_path, "pipe.radius_m")
    camera = camera_from_dict(_require(data, "camera", yaml_path), yaml_path)
    images = _require(data, "images", yaml_path)
    if not isinstance(images, str) or not images.strip():
        raise PipemapError("expected a glob of image files or a video file", yaml_path, "images")
    image_paths = video_path = None
    target = root / images
    if target.suffix.lower() in VIDEO_SUFFIXES and not any(c in images for c in "*?["):
        if not target.is_file():
            raise PipemapError(f"video file not found: {target}", yaml_path, "images")
        video_path = target
    else:
        image_paths = sorted(Path(p) for p in glob.glob(str(target)))
        image_paths = [p for p in image_paths if p.is_file()]
        if not image_paths:
            raise PipemapError(f"no images match {images!r}", yaml_path, "images")
    gain_mask_path = None
    if data.get("gain_mask"):
        gain_mask_path = root / str(data["gain_mask"])
        if not gain_mask_path.is_file():
            raise PipemapError(f"gain mask not found: {gain_mask_path}", yaml_path, "gain_mask")
    name = str(data.get("name") or root.name)
    return Dataset(root, yaml_path, name, fps, camera, radius, image_paths, video_path, gain_mask_path)
