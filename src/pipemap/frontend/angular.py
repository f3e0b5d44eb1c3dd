"""The front end's pixel settings for a given camera.

Sizes and thresholds in pixels (template footprints, search radii, flow and keyframe thresholds,
the Harris scale, the classification's sub-sampling) are set at a reference pixel density: the
fisheye paper's camera at 640x480 (`frontend.reference_px_per_deg`). A camera with another
density sees the same wall patch, the same motion and the same blur over proportionally more or
fewer pixels, so each of them is scaled by the camera's density at its image centre over the
reference (patch sizes only upwards: `frontend_for`), and one set of settings serves every
resolution. What is not scaled: the RANSAC floor
in pixels (a corner's position error is a fraction of a pixel at any resolution) and the
descriptor's sample count (its footprint is scaled; the samples average over it).
"""

from __future__ import annotations

import numpy as np

from pipemap.camera import CameraModel
from pipemap.config import ClassificationSettings, FrontendSettings


def pixel_angle(camera: CameraModel) -> float:
    """Angle (radians) subtended by one pixel at the image centre."""
    c = np.array([[camera.width / 2.0, camera.height / 2.0], [camera.width / 2.0 + 1.0, camera.height / 2.0]])
    b, _ = camera.unproject(c)
    return float(np.arccos(np.clip(b[0] @ b[1], -1.0, 1.0)))


def pixels_per_degree(camera: CameraModel) -> float:
    return float(np.radians(1.0) / pixel_angle(camera))


def pixel_scale(camera: CameraModel, reference_px_per_deg: float | None) -> float:
    """The camera's pixel density over the reference's (1 when no reference is set)."""
    return 1.0 if reference_px_per_deg is None else pixels_per_degree(camera) / reference_px_per_deg


def _odd(x: float, least: int) -> int:
    return max(least, 2 * int(round((x - 1.0) / 2.0)) + 1)


def frontend_for(camera: CameraModel, s: FrontendSettings) -> FrontendSettings:
    """`s` with its pixel sizes scaled to the camera (module docstring). What the images move by (flow and
    keyframe thresholds, search radii, how far apart two matches may be) scales both ways. What a feature is
    seen over (template footprints, ZNCC patches, the Harris window, corner spacing) scales up only: on a
    coarser camera the same angle holds fewer pixels than a patch needs to place a corner (at 320x240 a
    7 px ZNCC patch made the relative rotation 20 % worse than the reference's 11 px)."""
    k = pixel_scale(camera, s.reference_px_per_deg)
    if k == 1.0:
        return s
    up = max(k, 1.0)
    return s.model_copy(update={
        "template_window": _odd(s.template_window * up, s.template_size),
        "zncc_patch": _odd(s.zncc_patch * up, 3),
        "harris_block_px": _odd(s.harris_block_px * up, 3),
        "min_distance_px": max(1, int(round(s.min_distance_px * up))),
        "max_flow_px": s.max_flow_px * k,
        "keyframe_min_flow_px": s.keyframe_min_flow_px * k,
        "guided_search_px": max(2, int(round(s.guided_search_px * k))),
        "refine_matches_px": 0 if s.refine_matches_px == 0 else max(1, int(round(s.refine_matches_px * k))),
        "duplicate_px": s.duplicate_px * k,
        "anchor_max_shift_px": s.anchor_max_shift_px * up,
        "lighting_sigma_px": s.lighting_sigma_px * k,
        "reference_px_per_deg": None,  # scaled once
    })


def classification_for(camera: CameraModel, s: ClassificationSettings,
                       reference_px_per_deg: float | None) -> ClassificationSettings:
    """`s` with its sub-sampling scaled to the camera: the sub-sampled image keeps the reference density."""
    k = pixel_scale(camera, reference_px_per_deg)
    return s if k == 1.0 else s.model_copy(update={"subsample": max(1, int(round(s.subsample * k)))})


def scaled_settings(camera: CameraModel, s: FrontendSettings) -> dict:
    """The scale and the pixel values it gave, for run.json."""
    f = frontend_for(camera, s)
    keys = ("template_window", "zncc_patch", "harris_block_px", "min_distance_px", "max_flow_px",
            "keyframe_min_flow_px", "guided_search_px", "refine_matches_px", "duplicate_px", "anchor_max_shift_px",
            "lighting_sigma_px")
    return {"pixels_per_degree": round(pixels_per_degree(camera), 4),
            "reference_px_per_deg": s.reference_px_per_deg,
            "scale": round(pixel_scale(camera, s.reference_px_per_deg), 4),
            "pixels": {key: getattr(f, key) for key in keys}}
