"""Region Harris corners (fisheye paper III-A): a uniform spread of the strongest corners.

The image is split into rows x cols regions and the strongest corners of each region are
kept, so a bright, textured part of the wall cannot take every feature. Corners lie only
inside the valid fisheye circle (eroded by a margin so that descriptor windows stay inside).
"""

from __future__ import annotations

import cv2
import numpy as np

from pipemap.camera import CameraModel

_CACHE: dict[tuple, np.ndarray] = {}


def _camera_key(camera: CameraModel) -> tuple:
    return (camera.model, camera.width, camera.height, tuple(camera.params.tolist()), camera.max_theta)


def bearing_map(camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Bearing (H, W, 3) float32 of every integer pixel and its validity (H, W); cached per camera."""
    key = ("bearings",) + _camera_key(camera)
    if key not in _CACHE:
        v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(float)
        bearings, valid = camera.unproject(np.stack([u, v], axis=-1))
        _CACHE[key] = (bearings.astype(np.float32), valid)
    return _CACHE[key]


def valid_mask(camera: CameraModel, margin_px: int = 0) -> np.ndarray:
    """uint8 mask (H, W) of pixels inside the fisheye circle, eroded by `margin_px`; cached."""
    key = ("mask", margin_px) + _camera_key(camera)
    if key not in _CACHE:
        mask = bearing_map(camera)[1].astype(np.uint8)
        if margin_px > 0:
            # Erode against the image border too: a window must not leave the image.
            padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
            mask = cv2.erode(padded, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)[1:-1, 1:-1]
        _CACHE[key] = mask
    return _CACHE[key]


def flatten_lighting(image: np.ndarray, sigma_px: float, dark_level: float = 0.0, log_offset: float = 8.0,
                     contrast_limit: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The wall's texture without the robot's lighting: (log I - local mean of log I) x 64, and a lit mask.

    The LEDs move with the camera, so their fall-off towards the edge of the view is fixed in the
    image; corners and templates on that slope would match in place, at zero flow, which the
    epipolar geometry of forward motion cannot reject. Taking logs turns the lighting into an
    additive, slowly varying term that the local mean removes. `lit` (uint8) marks pixels whose
    local mean brightness exceeds `dark_level` (unlit openings and the black outside the image
    circle carry only noise). `contrast_limit` > 0 compresses the result softly to about that size
    (c tanh(x / c)): the rim of a dark opening (a tee's mouth seen from the branch) is a step of
    several log units that would otherwise outscore every wall corner of its region and fill it with
    corners sliding along the rim, which are not points of the wall.
    """
    image = np.ascontiguousarray(image, dtype=np.float32)
    log = np.log(image + np.float32(log_offset))
    flat = (log - _local_mean(log, sigma_px)) * np.float32(64.0)
    if contrast_limit > 0:
        c = np.float32(contrast_limit)
        flat = c * np.tanh(flat / c)
    lit = (_local_mean(image, sigma_px) > dark_level).astype(np.uint8)
    return flat, lit


def log_brightness(image: np.ndarray, log_offset: float = 8.0) -> np.ndarray:
    """64 x log(I + log_offset): the robot's light becomes an additive term, the gain of an exposure change a
    constant; the offset keeps the sensor's noise in the dark from being magnified."""
    return np.log(np.asarray(image, np.float32) + np.float32(log_offset)) * np.float32(64.0)


def _local_mean(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Two box filters (cost independent of sigma) approximating a Gaussian of `sigma_px`."""
    size = max(3, int(round(sigma_px * np.sqrt(6.0))) | 1)  # two boxes of width w have variance w^2 / 6
    return cv2.blur(cv2.blur(image, (size, size)), (size, size))


def harris_response(image: np.ndarray, block_size: int = 3, k: float = 0.04) -> np.ndarray:
    return cv2.cornerHarris(np.ascontiguousarray(image, dtype=np.float32), block_size, 3, k)


def detect_corners(
    image: np.ndarray,
    mask: np.ndarray,
    regions: tuple[int, int] = (2, 2),
    per_region: int = 200,
    k: float = 0.04,
    block_size: int = 3,
    min_distance_px: int = 3,
    quality: float = 0.01,
    subpix_window: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel corners (N, 2) as (u, v) and their Harris responses (N,), strongest first per region.

    A corner is a local maximum of the response within `min_distance_px`, inside `mask`,
    above `quality` times the strongest response of its region (the goodFeaturesToTrack
    rule, per region so that a dim region still gets corners). Positions are refined by a
    parabola through the response and then cv2.cornerSubPix over a (2 subpix_window + 1)^2
    window (0 = parabola only).
    """
    response = harris_response(image, block_size, k)
    size = 2 * min_distance_px + 1
    local_max = cv2.dilate(response, cv2.getStructuringElement(cv2.MORPH_RECT, (size, size)))
    peak = (response >= local_max) & (response > 0) & (mask > 0)
    # Keep the quadratic fit's neighbours inside the image.
    peak[[0, -1], :] = False
    peak[:, [0, -1]] = False
    vs, us = np.nonzero(peak)
    if vs.size == 0:
        return np.zeros((0, 2)), np.zeros(0)
    score = response[vs, us]
    h, w = image.shape
    rows, cols = regions
    region = (vs * rows // h) * cols + (us * cols // w)
    region_max = np.zeros(rows * cols)
    np.maximum.at(region_max, region, score)
    strong = score >= quality * region_max[region]
    vs, us, score, region = vs[strong], us[strong], score[strong], region[strong]
    order = np.lexsort((-score, region))
    region_sorted = region[order]
    first = np.searchsorted(region_sorted, region_sorted, side="left")
    rank = np.arange(order.size) - first
    keep = order[rank < per_region]
    vs, us, score = vs[keep], us[keep], score[keep]
    du = _parabola_offset(response[vs, us - 1], score, response[vs, us + 1])
    dv = _parabola_offset(response[vs - 1, us], score, response[vs + 1, us])
    coarse = np.stack([us + du, vs + dv], axis=-1)
    if subpix_window > 0:
        # Gradient-based refinement halves the error of the response-peak fit (0.13 vs 0.21 px).
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 20, 0.01)
        fine = cv2.cornerSubPix(np.ascontiguousarray(image, dtype=np.float32),
                                coarse.astype(np.float32).reshape(-1, 1, 2),
                                (subpix_window, subpix_window), (-1, -1), criteria).reshape(-1, 2).astype(float)
        stable = np.all(np.abs(fine - coarse) < 1.0, axis=1)
        coarse = np.where(stable[:, None], fine, coarse)
    return coarse, score.astype(float)


def _parabola_offset(left: np.ndarray, centre: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Vertex of the parabola through three samples, relative to the centre, within +-0.5."""
    curvature = left - 2.0 * centre + right
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (left - right) / curvature, 0.0)
    return np.clip(offset, -0.5, 0.5)
