"""Text burned into inspection footage: a distance counter, the date and clock, a manhole id.

Drawn as CCTV character generators draw it: white strokes over a dark outline, no anti-aliasing
(every text pixel is exactly 255 or OUTLINE, so static text is identical from frame to frame),
at fixed places: the clock top left, the counter bottom left, the manhole id top right (bottom
right, or under the clock, where the image is too narrow). `boxes` says where each text can ever
be, for tests and for judging a static-overlay mask.
"""

from __future__ import annotations

import math
from datetime import datetime, timedelta

import cv2
import numpy as np

from pipemap.sim.effects import Overlay

FONT = cv2.FONT_HERSHEY_SIMPLEX
OUTLINE = 0  # grey level of the dark outline
_DIGIT_HEIGHT_AT_1 = 22  # cv2.getTextSize height of the Hershey simplex font at scale 1
_CLOCK_TEMPLATE = "8888-88-88 88:88:88"
_COUNTER_TEMPLATE = "-8888.88 m"  # '-' is the widest glyph used; digits share one width


def counter_text(distance_m: float) -> str:
    return f"{distance_m:.2f} m"


def clock_text(when: datetime) -> str:
    return when.strftime("%Y-%m-%d %H:%M:%S")


class OverlayPainter:
    """Draws `spec`'s texts into grey uint8 frames of width x height."""

    def __init__(self, spec: Overlay, width: int, height: int):
        self.spec = spec
        self.scale = max(0.2, spec.text_height * height / _DIGIT_HEIGHT_AT_1)
        self.thickness = max(1, int(round(self.scale * 1.5)))
        self.outline = self.thickness + 2
        pad = self.outline // 2 + 1
        margin = max(2, int(round(0.02 * height)))
        (_, cap), base = cv2.getTextSize("8", FONT, self.scale, self.thickness)
        self.origins: dict[str, tuple[int, int]] = {}
        self.boxes: dict[str, tuple[int, int, int, int]] = {}  # name -> (x0, y0, x1, y1), exclusive ends

        def box(template: str, x: int | None, y: int) -> tuple[tuple[int, int], tuple[int, int, int, int]]:
            (w, _), _ = cv2.getTextSize(template, FONT, self.scale, self.thickness)
            if x is None:  # right-aligned
                x = width - margin - pad - w
            return (x, y), (x - pad, y - cap - pad, x + w + pad, y + base + pad)

        def place(name: str, template: str, *spots: tuple[int | None, int]) -> None:
            """The first spot whose box overlaps no text placed before (else the last one)."""
            for x, y in spots:
                origin, b = box(template, x, y)
                if not any(_overlap(b, other) for other in self.boxes.values()):
                    break
            self.origins[name] = origin
            self.boxes[name] = (max(0, b[0]), max(0, b[1]), min(width, b[2]), min(height, b[3]))

        top = margin + pad + cap
        bottom = height - margin - pad - base
        line = cap + base + 2 * pad + margin
        if spec.clock:
            place("clock", _CLOCK_TEMPLATE, (margin + pad, top))
        if spec.distance:
            place("distance", _COUNTER_TEMPLATE, (margin + pad, bottom))
        if spec.manhole:  # top right; in a narrow image bottom right, or under the clock
            place("manhole", spec.manhole, (None, top), (None, bottom), (margin + pad, top + line))
        self.shape = (height, width)

    def texts(self, distance_m: float, seconds: float) -> dict[str, str]:
        out = {}
        if self.spec.clock:
            out["clock"] = clock_text(self.spec.start + timedelta(seconds=math.floor(seconds)))
        if self.spec.manhole:
            out["manhole"] = self.spec.manhole
        if self.spec.distance:
            out["distance"] = counter_text(distance_m)
        return out

    def draw(self, img: np.ndarray, distance_m: float, seconds: float) -> np.ndarray:
        """Burn the texts of a frame `seconds` after the start into `img` (in place); returns the
        (H, W) bool mask of the pixels written."""
        layer = np.zeros(self.shape, np.uint8)  # 1: outline, 2: stroke
        for name, text in self.texts(distance_m, seconds).items():
            cv2.putText(layer, text, self.origins[name], FONT, self.scale, 1, self.outline, cv2.LINE_8)
        for name, text in self.texts(distance_m, seconds).items():
            cv2.putText(layer, text, self.origins[name], FONT, self.scale, 2, self.thickness, cv2.LINE_8)
        img[layer == 1] = OUTLINE
        img[layer == 2] = 255
        return layer > 0


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
