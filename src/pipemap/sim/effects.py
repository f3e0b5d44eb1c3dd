"""Camera effects: what real inspection footage does to a clean rendered picture, seeded.

Applied in the order a crawler camera and its recorder apply them:

1. the camera: gain (a slow drift, steps where the auto exposure jumps, LED flicker) scales the
   radiance before the sensor's noise, saturation and 8-bit quantisation; motion blur and
   interlacing sample the radiance along each pixel's own image motion (capture.py);
2. the camera control unit burns in text: a distance counter, the date and clock, a manhole id
   (overlay.py);
3. the link and recorder: a stalled link writes the previous frame again (a repeat), a lost frame
   is never written (a drop); the recorder encodes H.264, MJPEG or MPEG-4 video (recorder.py).

`CameraEffects` is a pydantic model, so a YAML file is checked key by key; `load_effects` takes
a profile name, a YAML file, a mapping or a model. A YAML file may start from a profile
(`profile: cctv-h264`) and override parts of it.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from pipemap.errors import PipemapError
from pipemap.yamlfile import read_yaml

__all__ = ["CameraEffects", "Video", "Overlay", "Gain", "GainStep", "Link", "PROFILES", "load_effects",
           "gain_curve", "link_schedule", "WRITTEN", "REPEAT", "DROP"]


class _Part(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Video(_Part):
    """Lossy video instead of PNG frames: one file, 4:2:0 chroma, grey frames as grey-in-YUV."""

    codec: Literal["h264", "mjpeg", "mpeg4"] = Field("h264", description="libx264, MJPEG or MPEG-4 part 2")
    crf: float = Field(23.0, ge=0, le=51, description="H.264 constant rate factor: 0 lossless, 23 x264's default, "
                       "28 a typical inspection recording")
    qscale: int = Field(4, ge=1, le=31, description="MJPEG and MPEG-4 quantiser scale, ffmpeg's -q:v: 2 best, 31 worst")
    preset: str = Field("medium", description="x264 speed preset")
    gop: int | None = Field(None, ge=1, description="frames between key frames (None: the encoder's default)")


class Overlay(_Part):
    """Text burned into every frame, white with a dark outline, at fixed places."""

    distance: bool = Field(True, description="bottom left: the distance counter, metres driven along the route "
                           "from the first frame (ground truth; counts down when the robot reverses)")
    clock: bool = Field(True, description="top left: date and time of the frame's slot")
    manhole: str | None = Field(None, description="top right: fixed text such as 'MH1034 > MH1035'")
    start: datetime = Field(datetime(2024, 3, 18, 10, 15, 0), description="clock time of the first frame")
    text_height: float = Field(1 / 24, gt=0, le=0.2, description="height of a digit as a fraction of the image height")


class GainStep(_Part):
    """The auto exposure jumps: from `frame` (or `fraction` of the run) on, the gain is x `factor`."""

    frame: int | None = Field(None, ge=1)
    fraction: float | None = Field(None, gt=0, lt=1)
    factor: float = Field(..., gt=0)

    @model_validator(mode="after")
    def _one_position(self):
        if (self.frame is None) == (self.fraction is None):
            raise ValueError("a gain step takes exactly one of frame or fraction")
        return self

    def slot(self, n: int) -> int:
        return int(self.frame) if self.frame is not None else int(round(self.fraction * n))


class Gain(_Part):
    """Multiplicative gain on the radiance, before saturation and quantisation:
    drift(frame) x the steps so far x (1 + flicker * sin(2 pi frame / flicker_period_frames + phase))."""

    drift: tuple[float, float] | None = Field(None, description="(low, high): a slow seeded drift that spans "
                                               "exactly this range over the run")
    drift_cycles: float = Field(1.0, gt=0, description="slow swings of the drift over the run")
    steps: tuple[GainStep, ...] = ()
    flicker: float = Field(0.0, ge=0, lt=1, description="amplitude of the LED flicker ripple")
    flicker_period_frames: float = Field(3.3, gt=0, description="period of the ripple (LED PWM beating with the "
                                         "frame rate)")

    @model_validator(mode="after")
    def _range(self):
        if self.drift is not None and not 0 < self.drift[0] <= self.drift[1]:
            raise ValueError(f"drift takes (low, high) with 0 < low <= high, got {self.drift}")
        return self

    @property
    def active(self) -> bool:
        return self.drift is not None or bool(self.steps) or self.flicker > 0


class Link(_Part):
    """A stalled link repeats the previous written frame in its slot; a lost frame leaves its slot
    empty. Exactly round(rate * (frames - 1)) slots of each kind, at seeded places (never the first)."""

    repeat_rate: float = Field(0.0, ge=0, lt=1)
    drop_rate: float = Field(0.0, ge=0, lt=1)

    @model_validator(mode="after")
    def _total(self):
        if self.repeat_rate + self.drop_rate >= 1:
            raise ValueError("repeat_rate + drop_rate must stay below 1")
        return self


class CameraEffects(_Part):
    """Inspection footage's defects, applied after rendering. All defaults: the clean dataset."""

    video: Video | None = Field(None, description="None: PNG frames")
    overlay: Overlay | None = None
    gain: Gain = Gain()
    shutter: float = Field(0.0, ge=0, le=1, description="motion blur: the shutter's open time as a fraction of "
                           "the frame interval, centred on the frame's pose (0: none)")
    interlace: bool = Field(False, description="two fields, top (even rows) first, a quarter frame before and "
                            "after the frame's pose")
    link: Link = Link()
    seed: int | None = Field(None, description="None: the simulation's seed")

    @property
    def clean(self) -> bool:
        """Nothing to do: the dataset is byte-identical to one rendered without effects."""
        return (self.video is None and self.overlay is None and not self.gain.active and self.shutter == 0
                and not self.interlace and self.link.repeat_rate == 0 and self.link.drop_rate == 0)

    def to_dict(self) -> dict:
        return self.model_dump(mode="json")


_CCTV_TEXT = dict(distance=True, clock=True)
_DRIFT_AND_STEPS = dict(drift=(0.75, 1.3), steps=[dict(fraction=0.35, factor=1.2), dict(fraction=0.7, factor=0.8)])
PROFILES: dict[str, dict[str, Any]] = {
    "clean": {},
    # The recording: H.264 at CRF 28, counter and clock, gain x0.75-x1.3 with two steps, a flaky link.
    "cctv-h264": dict(video=dict(codec="h264", crf=28), overlay=_CCTV_TEXT,
                      gain=_DRIFT_AND_STEPS,
                      link=dict(repeat_rate=0.05, drop_rate=0.01)),
    # An older recorder: MJPEG, the manhole ids on screen, LED flicker, a slightly blurred picture.
    "cctv-mjpeg": dict(video=dict(codec="mjpeg", qscale=8),
                       overlay=dict(_CCTV_TEXT, manhole="MH1034 > MH1035"),
                       gain=dict(drift=(0.85, 1.15), flicker=0.03), shutter=0.5, link=dict(repeat_rate=0.02)),
    # An analogue PAL camera through a frame grabber: interlaced, blurred, MPEG-4, drops and repeats.
    "pal-interlaced": dict(video=dict(codec="mpeg4", qscale=5), overlay=dict(_CCTV_TEXT, manhole="MH7 > MH8"),
                           gain=dict(drift=(0.8, 1.2), flicker=0.02), shutter=0.5, interlace=True,
                           link=dict(repeat_rate=0.03, drop_rate=0.02)),
    # The picture's defects without compression (PNG frames), to take the compression apart from the rest.
    "cctv-png": dict(overlay=_CCTV_TEXT,
                     gain=_DRIFT_AND_STEPS,
                     link=dict(repeat_rate=0.05, drop_rate=0.01)),
}


def _validate(data: dict, where: str) -> CameraEffects:
    try:
        return CameraEffects.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"]) or None
        raise PipemapError(err["msg"], where, key) from None


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_effects(spec: str | Path | dict | CameraEffects | None) -> CameraEffects:
    """A profile name (PROFILES), a YAML file, a mapping or a CameraEffects; None is `clean`.
    A file or mapping with `profile: NAME` starts from that profile and overrides its keys."""
    if spec is None:
        return CameraEffects()
    if isinstance(spec, CameraEffects):
        return spec
    where = "camera effects"
    if isinstance(spec, (str, Path)):
        if str(spec) in PROFILES:
            return _validate(PROFILES[str(spec)], f"camera effects profile {spec}")
        path = Path(spec)
        if not path.is_file():
            raise PipemapError(f"unknown camera effects {str(spec)!r}: neither a profile "
                               f"({', '.join(PROFILES)}) nor a YAML file")
        spec, where = read_yaml(path, "camera effects file"), str(path)
    if not isinstance(spec, dict):
        raise PipemapError(f"expected a mapping, got {type(spec).__name__}", where)
    data = dict(spec)
    base = data.pop("profile", None)
    if base is not None:
        if base not in PROFILES:
            raise PipemapError(f"unknown profile {base!r} (expected one of {', '.join(PROFILES)})", where, "profile")
        data = _merge(PROFILES[base], data)
    return _validate(data, where)


def effects_rng(seed: int, stream: int) -> np.random.Generator:
    """Independent, reproducible random streams of one run's effects."""
    return np.random.default_rng([int(seed) % 2**63, 0xEFFEC7, int(stream)])


def gain_curve(gain: Gain, n: int, seed: int) -> np.ndarray:
    """(n,) gain of every frame slot (1 where nothing is asked)."""
    f = np.arange(n, dtype=float)
    out = np.ones(n)
    rng = effects_rng(seed, 1)
    phases = rng.uniform(0, 2 * np.pi, 3)
    if gain.drift is not None:
        lo, hi = gain.drift
        x = f / max(n - 1, 1) * 2 * np.pi * gain.drift_cycles
        wave = np.cos(x + phases[0]) + 0.3 * np.cos(2.3 * x + phases[1])
        span = wave.max() - wave.min()
        u = (wave - wave.min()) / span if span > 1e-12 else np.full(n, 0.5)
        out *= lo * (hi / lo) ** u  # geometric: a drift up and one down look alike in log exposure
    for step in gain.steps:
        out[step.slot(n):] *= step.factor
    if gain.flicker:
        out *= 1 + gain.flicker * np.sin(2 * np.pi * f / gain.flicker_period_frames + phases[2])
    return out


WRITTEN, REPEAT, DROP = 0, 1, 2


def link_schedule(link: Link, n: int, seed: int) -> np.ndarray:
    """(n,) int8 per slot: WRITTEN, REPEAT (the previous written frame again) or DROP (nothing)."""
    kinds = np.full(n, WRITTEN, np.int8)
    if n < 2:
        return kinds
    n_rep = int(round(link.repeat_rate * (n - 1)))
    n_drop = int(round(link.drop_rate * (n - 1)))
    order = effects_rng(seed, 2).permutation(np.arange(1, n))
    kinds[order[:n_drop]] = DROP
    kinds[order[n_drop : n_drop + n_rep]] = REPEAT
    return kinds
