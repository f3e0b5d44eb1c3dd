"""Straight vs T-intersection image classification (fisheye paper, section III-B).

Per frame (`classify_frame`):

1. sub-sample every `subsample`-th row and column;
2. threshold the dark pixels inside the field of view. The grey level is relative to the
   frame itself: `lo + dark_threshold * (hi - lo)`, with lo / hi the 1st / 99th percentiles
   of the grey levels inside the field of view, so that exposure and gain do not matter;
3. binary erosion by a disc of radius `erosion_px` (sub-sampled pixels);
4. cluster the dark pixels into 8-connected blobs and keep the largest;
5. second moments of area of the blob about its centroid, L = sum |x - c|^2, and about the
   principal point p, L_p = sum |x - p|^2 (sums over the blob's pixels);
6. straight when L_p / L < `ratio_threshold`, else junction.

What the ratio means: by the parallel-axis theorem L_p = L + A |c - p|^2 with A the blob's
area, so L_p / L = 1 + (d / rho)^2, where d = |c - p| is the distance of the blob's centroid
from the principal point and rho = sqrt(L / A) its radius of gyration (R / sqrt 2 for a
disc of radius R). The test asks whether the dark blob is centred on the optical axis
relative to its own size: threshold 1.5 <=> d < rho / sqrt 2 = R / 2 for a disc, i.e. the
centre of the dark far end of the pipe lies within half its radius of the principal point.
In a straight pipe the far end is centred on the direction of the pipe axis; it moves off
the principal point only by the camera's misalignment with the axis (a few degrees), while
its radius is the angle the pipe's unlit far part subtends (10-20 degrees), so the ratio
stays near 1. At a tee the largest dark region is the branch opening seen sideways, or the
far end and the opening merged into one lopsided blob: d is comparable to or larger than R.

The field of view: the pixels whose bearing the camera model accepts (`camera.unproject`),
minus the rim where the lens and the lights leave the image dark whatever the scene (at the
edge of a 190 degree fisheye). The rim is found per frame from the grey level of rings of
equal colatitude: going outwards from the brightest ring, the field of view ends at the first
ring whose mean grey level falls below the dark threshold. A ring-shaped dark rim would
otherwise be the largest blob, centred on the principal point, and every frame straight.

A frame with no dark blob at all (glare, a saturated or black image: no grey range) has an
infinite ratio and is labelled junction; the temporal filter relabels such isolated frames.

Temporal filter (`temporal_filter`): the labels of a sequence form runs of equal labels. While
some run is shorter than `min_cluster_keyframes` and more than one run remains, the shortest
run (the earliest of equal ones) takes the other label, merging with its neighbours. Runs at
the ends of the sequence are filtered like any other.

Ground truth (`ground_truth_labels`): a frame is 'junction' when the camera centre is within
one pipe diameter (2 r) of the centroid of a tee of the network (network.yaml), measured in
3D; else 'straight'. This rule is symmetric about the tee, but what the camera sees is not:
once the camera has turned into the branch and passed the tee centre by more than about r
(plus r tan 5 deg), the whole tee lies behind its 95 degree half field of view and the image
is that of a straight pipe. `visible=True` gives that variant (straight once the camera has
passed the tee centre by more than r along its viewing direction), the best any classifier
of single images can in principle match. Measured on the simulator's loops (benchmarks/
bench_classification.py, default settings): clusters start 1.0-1.5 r before the tee centre
when the tee is entered along its run (the branch opening outgrows the far end), 2.7-3.1 r
before it when entered from the branch (its far end is then the lit wall of the run, not
dark), and end 0.5-0.8 r after it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable

import cv2
import numpy as np

from pipemap.camera import CameraModel
from pipemap.config import ClassificationSettings
from pipemap.dataset import Dataset, Frame

STRAIGHT = "straight"
JUNCTION = "junction"

_RING_DEG = 2.5  # width of the colatitude rings that find the dark rim of the field of view


@dataclass(frozen=True)
class Blob:
    """The largest dark blob of a frame."""

    area: int  # pixels of the sub-sampled image
    centroid: tuple[float, float]  # (u, v) in full-resolution pixels
    L: float  # second moment about the centroid: sum of squared distances, sub-sampled pixels
    L_p: float  # the same about the principal point


@dataclass(frozen=True)
class FrameClass:
    label: str  # 'straight' or 'junction'
    ratio: float  # L_p / L; inf when there is no blob
    blob: Blob | None
    dark_level: float  # grey level below which a pixel counted as dark
    fov_theta_deg: float  # colatitude where the used field of view ended

    @property
    def is_junction(self) -> bool:
        return self.label == JUNCTION


@dataclass
class SequenceClass:
    """The labels of a sequence of frames, before and after the temporal filter."""

    indices: np.ndarray  # (N,) frame indices
    ratios: np.ndarray  # (N,) L_p / L
    raw_junction: np.ndarray  # (N,) bool, per-frame labels
    junction: np.ndarray  # (N,) bool, after the temporal filter
    clusters: list[tuple[int, int]] = field(default_factory=list)  # (first, last) frame index of each junction cluster

    @property
    def raw_labels(self) -> list[str]:
        return label_names(self.raw_junction)

    @property
    def labels(self) -> list[str]:
        return label_names(self.junction)


def label_names(junction: np.ndarray) -> list[str]:
    return [JUNCTION if j else STRAIGHT for j in np.asarray(junction, bool)]


class _Geometry:
    """Per camera and sub-sampling: field-of-view mask, colatitude rings, principal point."""

    def __init__(self, camera: CameraModel, step: int):
        v, u = np.mgrid[0 : camera.height : step, 0 : camera.width : step].astype(np.float64)
        bearings, valid = camera.unproject(np.stack([u, v], axis=-1))
        theta = np.degrees(np.arccos(np.clip(bearings[..., 2], -1.0, 1.0)))
        valid &= np.isfinite(theta)
        self.valid = valid
        ring = np.where(valid, np.floor(np.nan_to_num(theta) / _RING_DEG), -1).astype(np.int64)
        self.n_rings = int(ring.max()) + 1 if valid.any() else 0
        self.ring = ring
        self.ring_of_valid = ring[valid]
        self.ring_count = np.bincount(self.ring_of_valid, minlength=self.n_rings).astype(np.float64)
        # the optical axis' pixel: u0, v0 of the polynomial model, cx, cy of the others
        self.principal = camera.project(np.array([0.0, 0.0, 1.0]))[0] / step  # sub-sampled pixels


_CACHE: dict[tuple, _Geometry] = {}


def _geometry(camera: CameraModel, step: int) -> _Geometry:
    key = (camera.model, camera.width, camera.height, tuple(camera.params), camera.max_theta, step)
    geo = _CACHE.get(key)
    if geo is None:
        if len(_CACHE) > 8:
            _CACHE.clear()
        geo = _CACHE[key] = _Geometry(camera, step)
    return geo


def _percentiles(values: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """Percentiles of grey levels via a 1-grey-level histogram (fast, exact to one level)."""
    v = np.clip(values, 0, 255).astype(np.uint8)
    hist = np.bincount(v, minlength=256).cumsum()
    return np.searchsorted(hist, np.asarray(qs) / 100.0 * hist[-1]).astype(np.float64)


def classify_frame(image: np.ndarray, camera: CameraModel, settings: ClassificationSettings | None = None,
                   usable: np.ndarray | None = None) -> FrameClass:
    """Classify one grey image (float or integer, 0..255 scale) as straight or junction. `usable`: (H, W) bool,
    the pixels that show the wall (an overlay's are neither dark nor counted in the grey range)."""
    s = settings or ClassificationSettings()
    img = np.asarray(image)
    if img.shape != (camera.height, camera.width):
        raise ValueError(f"image of shape {img.shape}, the camera is {camera.width}x{camera.height}")
    geo = _geometry(camera, s.subsample)
    sub = np.ascontiguousarray(img[:: s.subsample, :: s.subsample], dtype=np.float32)
    seen = geo.valid if usable is None else geo.valid & usable[:: s.subsample, :: s.subsample]
    inside = sub[seen]
    if inside.size == 0:
        return FrameClass(JUNCTION, float("inf"), None, float("nan"), float("nan"))
    lo, hi = _percentiles(inside, (1.0, 99.0))
    level = lo + s.dark_threshold * (hi - lo)
    fov_rings = _fov_rings(geo, geo.ring_of_valid if usable is None else geo.ring[seen], inside, level)
    fov_deg = fov_rings * _RING_DEG
    if hi - lo < 1.0:  # no grey range (black, saturated, blank): nothing to see
        return FrameClass(JUNCTION, float("inf"), None, float(level), fov_deg)
    dark = ((sub < level) & (geo.ring >= 0) & (geo.ring < fov_rings) & seen).astype(np.uint8)
    if s.erosion_px > 0:
        k = 2 * s.erosion_px + 1
        dark = cv2.erode(dark, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    # connectedComponents + bincount: ~3x faster here than connectedComponentsWithStats
    n, labels = cv2.connectedComponents(dark, connectivity=8)
    if n <= 1:
        return FrameClass(JUNCTION, float("inf"), None, float(level), fov_deg)
    areas = np.bincount(labels.ravel(), minlength=n)
    best = 1 + int(np.argmax(areas[1:]))
    ys, xs = np.nonzero(labels == best)
    xs = xs.astype(np.float64)
    ys = ys.astype(np.float64)
    cx, cy = xs.mean(), ys.mean()
    pu, pv = geo.principal
    L = float(np.sum((xs - cx) ** 2 + (ys - cy) ** 2))
    L_p = float(np.sum((xs - pu) ** 2 + (ys - pv) ** 2))
    ratio = L_p / L if L > 0 else float("inf")  # a one-pixel blob tells nothing about roundness
    blob = Blob(int(xs.size), (float(cx * s.subsample), float(cy * s.subsample)), L, L_p)
    label = STRAIGHT if ratio < s.ratio_threshold else JUNCTION
    return FrameClass(label, float(ratio), blob, float(level), fov_deg)


def _fov_rings(geo: _Geometry, rings: np.ndarray, inside: np.ndarray, level: float) -> int:
    """Number of colatitude rings in the used field of view: outwards from the brightest ring,
    up to the first ring whose mean grey level is below `level` (the dark rim of the lens).
    `rings`: the ring of each grey level in `inside`."""
    count = geo.ring_count if rings is geo.ring_of_valid else np.bincount(rings, minlength=geo.n_rings)
    total = np.bincount(rings, weights=inside, minlength=geo.n_rings)
    ring_mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)  # a ring the mask hides says nothing
    if not np.isfinite(ring_mean).any():
        return geo.n_rings
    brightest = int(np.nanargmax(ring_mean))
    dark_rings = np.flatnonzero(ring_mean[brightest:] < level)
    return int(brightest + dark_rings[0]) if dark_rings.size else geo.n_rings


def temporal_filter(junction, min_cluster: int) -> np.ndarray:
    """Relabel runs shorter than `min_cluster`: shortest first (earliest of equals), until none remain."""
    lab = np.asarray(junction, bool).copy()
    if lab.size == 0 or min_cluster <= 1:
        return lab
    while True:
        edges = np.flatnonzero(np.diff(lab.astype(np.int8))) + 1
        starts = np.concatenate([[0], edges])
        lengths = np.diff(np.concatenate([starts, [lab.size]]))
        if lengths.size <= 1:
            return lab
        k = int(np.argmin(lengths))
        if lengths[k] >= min_cluster:
            return lab
        lab[starts[k] : starts[k] + lengths[k]] = ~lab[starts[k]]


def junction_clusters(indices, junction) -> list[tuple[int, int]]:
    """(first, last) frame index of each run of junction frames."""
    j = np.concatenate([[False], np.asarray(junction, bool), [False]]).astype(np.int8)
    d = np.diff(j)
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    idx = np.asarray(indices)
    return [(int(idx[a]), int(idx[b - 1])) for a, b in zip(starts, stops)]


class SequenceClassifier:
    """Streaming form of classify_sequence: `add` each frame in time order, then `result`."""

    def __init__(self, camera: CameraModel, settings: ClassificationSettings | None = None,
                 usable: np.ndarray | None = None):
        self.camera, self.s, self.usable = camera, settings or ClassificationSettings(), usable
        self.indices: list[int] = []
        self.ratios: list[float] = []
        self.raw: list[bool] = []

    def add(self, frame: Frame) -> FrameClass:
        fc = classify_frame(frame.image, self.camera, self.s, self.usable)
        self.indices.append(frame.index)
        self.ratios.append(fc.ratio)
        self.raw.append(fc.is_junction)
        return fc

    def result(self) -> SequenceClass:
        indices = np.asarray(self.indices, dtype=np.int64)
        raw = np.asarray(self.raw, bool)
        filtered = temporal_filter(raw, self.s.min_cluster_keyframes)
        return SequenceClass(indices, np.asarray(self.ratios, float), raw, filtered,
                             junction_clusters(indices, filtered))


def classify_sequence(frames: Dataset | Iterable[Frame], camera: CameraModel | None = None,
                      settings: ClassificationSettings | None = None,
                      progress: Callable[[int], None] | None = None) -> SequenceClass:
    """Classify every frame (a Dataset, or Frames in time order with `camera`), then filter the
    labels in time. `progress(n)` is called after each frame with the number done."""
    s = settings or ClassificationSettings()
    if isinstance(frames, Dataset):
        camera = camera or frames.camera
        frames = frames.frames()
    if camera is None:
        raise ValueError("classify_sequence needs the camera")
    classifier = SequenceClassifier(camera, s)
    for frame in frames:
        classifier.add(frame)
        if progress is not None:
            progress(len(classifier.raw))
    return classifier.result()
