"""Each keyframe's exposure, so that auto-exposure steps and drift do not show in the maps as bands.

A crawler camera's auto exposure (and its LEDs' flicker) scales the whole image; the appearance map
averages every wall point over the keyframes that saw it, so a step of the gain between keyframes
leaves a step in the map where the keyframes that contribute change. Each keyframe image is divided
by its exposure level and the map is scaled back by the median level of all keyframes.

The level must not follow what the camera sees: the robot's light falls off across the band the
map samples, so a tee's opening that hides the dim part of the band would raise the plain median of
the band's grey levels and brighten the map round every tee. The light field (per pixel, the median
of keyframes spread along the run: the wall's texture averages out, the light stays put) is divided
out first; the level is the median of what is left over the lit pixels of the band (an opening is
dark at any exposure and left out).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from pipemap.frontend.harris import bearing_map

DARK_FRACTION = 0.35  # of the band's 95th percentile: darker pixels are openings, not lit wall
LEVEL_PERCENTILE = 50


class ExposureLevels:
    def __init__(self, camera, band_deg: tuple[float, float], usable: np.ndarray | None = None):
        bearings, valid = bearing_map(camera)
        theta = np.degrees(np.arccos(np.clip(bearings[..., 2], -1.0, 1.0)))
        self.pixels = valid & (theta > band_deg[0]) & (theta < band_deg[1])
        if usable is not None:
            self.pixels &= usable
        self.light: np.ndarray | None = None  # the light field at self.pixels (use_light)
        self.levels: list[float] = []

    def light_field(self, images: Iterable[np.ndarray]) -> np.ndarray | None:
        """Per pixel median of `images` (frames spread along the run), each first divided by its own level
        (without a light field) so that the exposure changes among them do not shape it; None for fewer than 5."""
        plain = ExposureLevels.__new__(ExposureLevels)
        plain.pixels, plain.light, plain.levels = self.pixels, None, []
        stack = [plain.normalise(im) for im in images]
        return np.median(np.stack(stack), axis=0) if len(stack) >= 5 else None

    def use_light(self, light: np.ndarray | None) -> None:
        if light is None:
            return
        lit = light[self.pixels]
        self.pixels &= light > DARK_FRACTION * (np.percentile(lit, 95) if lit.size else 0.0)
        self.light = np.maximum(light[self.pixels], 1e-6).astype(np.float32)

    def normalise(self, image: np.ndarray) -> np.ndarray:
        """The image divided by its exposure level (recorded); unchanged where the band is black."""
        values = np.asarray(image, np.float32)[self.pixels]
        if self.light is not None:
            values = values / self.light
        level = 0.0
        if values.size:
            lit = values[values > DARK_FRACTION * np.percentile(values, 95)]
            level = float(np.percentile(lit, LEVEL_PERCENTILE)) if lit.size else 0.0
        if not level > (1.0 if self.light is None else 1e-3):  # lights off, or no band: nothing to tell
            self.levels.append(float("nan"))
            return np.asarray(image, np.float32)
        self.levels.append(level)
        return np.asarray(image, np.float32) / np.float32(level)

    @property
    def reference(self) -> float:
        """The level the normalised map is scaled back to: the median of the keyframes' levels."""
        good = np.asarray([v for v in self.levels if np.isfinite(v)])
        return float(np.median(good)) if good.size else 1.0

    def to_dict(self) -> dict:
        good = np.asarray([v for v in self.levels if np.isfinite(v)])
        if not good.size:
            return {"keyframes": len(self.levels), "normalised": 0}
        ref = float(np.median(good))
        return {"keyframes": len(self.levels), "normalised": int(good.size), "light_field": self.light is not None,
                "relative_level_range": [round(float(good.min() / ref), 4), round(float(good.max() / ref), 4)]}
