"""The pixels that show the wall: the user's mask (dataset.yaml `mask:`) and the static overlay found
in the footage (static_mask.py), for features, matching, classification and the maps."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipemap.config import Settings
from pipemap.dataset import Dataset
from pipemap.frontend.angular import frontend_for
from pipemap.frontend.harris import valid_mask
from pipemap.frontend.static_mask import StaticMask, find_static_mask


@dataclass(frozen=True)
class UsableMask:
    usable: np.ndarray | None  # (H, W) bool, or None: every pixel of the camera's image (features, matching)
    given: bool  # the dataset has a user's mask
    static: StaticMask | None  # what the footage showed, when looked for
    note: str  # why no static mask was used, if none
    view: np.ndarray | None  # the pixels that show the wall (classification, maps): `usable` and the light's rings

    def to_dict(self) -> dict:
        return {"given": self.given,
                "masked_fraction": None if self.usable is None else round(float(1.0 - self.usable.mean()), 5),
                "static_overlay": None if self.static is None else self.static.to_dict(),
                "note": self.note}


def _sample(dataset: Dataset, count: int):
    """Frames spread evenly over the recording (damaged ones skipped), for the static overlay."""
    n = len(dataset)
    for i in np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(int)):
        try:
            yield dataset.read(int(i), gain_correct=False).image
        except Exception:  # a damaged frame: the tracking stage reports it
            continue


def usable_mask(dataset: Dataset, settings: Settings) -> UsableMask:
    fe = settings.frontend
    given = dataset.mask
    s = frontend_for(dataset.camera, fe)
    margin = max(s.template_window, s.zncc_patch) // 2 + 1  # no feature's patch reaches into a masked pixel
    usable = view = None
    if given is not None:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        usable = view = cv2.erode(given.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=1) > 0
    static, note = None, "off (frontend.static_mask_frames = 0)"
    if fe.static_mask_frames > 0:
        inside = valid_mask(dataset.camera, margin)
        centre = dataset.camera.project(np.array([0.0, 0.0, 1.0]))[0]  # the light's rings centre on the axis
        found = find_static_mask(_sample(dataset, fe.static_mask_frames), inside, s.lighting_sigma_px,
                                 grow_px=margin, centre=(float(centre[0]), float(centre[1])),
                                 dark_share=settings.classification.dark_threshold)
        if found is None:
            note = "too few frames to tell what moves"
        elif found.masked_fraction > fe.static_mask_max_fraction:
            note = (f"not used: {100 * found.masked_fraction:.0f} % of the image looked static (the robot barely "
                    "moved over the frames sampled)")
            static = found
        else:
            static, note = found, ""
            usable = found.usable if usable is None else usable & found.usable
            view = found.view if view is None else view & found.view
    return UsableMask(usable, given is not None, static, note, view)
