"""12 o'clock: the robot's up direction, estimated over the run.

A crawler rides the invert of the pipe, so its roll about the axis hardly changes along a run, and a camera
mounted on it keeps one roll too: the mean of the keyframes' image-up directions (-y of the camera), each
taken across the axis of the pipe it was in, is the robot's up (for a camera mounted upright; one mounted
turned is what the `route.up` setting is for). That estimate works whatever the camera's height in the pipe.

A second, independent estimate is reported beside it: the camera rides below the axis (the crawler sits on
the invert), so 12 o'clock is opposite the mean direction of the camera centres from the axis. It needs the
camera to sit well off the axis (a tenth of the radius or more); a camera on the axis, or a robot that
drives along a pipe's side, gives it no meaning. Their angle and the keyframes' roll spread tell whether the
image-up estimate can be trusted.
"""

from __future__ import annotations

import numpy as np

from pipemap.errors import PipemapError

MIN_SIDE_OFFSET_RADII = 0.1  # the camera-side estimate needs the camera at least this far off the axis


def nearest_legs(positions: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Index of the axis segment (starts, ends (L, 3)) nearest each position (K, 3)."""
    d = ends - starts
    q = positions[:, None, :] - starts[None]
    s = np.clip(np.einsum("kli,li->kl", q, d) / np.einsum("li,li->l", d, d), 0.0, 1.0)
    gap = q - s[..., None] * d[None]
    return np.argmin(np.einsum("kli,kli->kl", gap, gap), axis=1)


def estimate_up(rotations: np.ndarray, positions: np.ndarray, starts: np.ndarray, ends: np.ndarray, radius: float,
                choice="image") -> tuple[np.ndarray, dict]:
    """(up, record) from keyframe poses R_wc (K, 3, 3), centres (K, 3) and the straight axes they were in.
    `choice`: `image` (the mean image-up), `camera-side`, or a world vector [x, y, z] (the override)."""
    leg = nearest_legs(positions, starts, ends)
    u = ends[leg] - starts[leg]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    g = -rotations[:, :, 1]
    g = g - np.einsum("ki,ki->k", g, u)[:, None] * u
    g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
    image_up = _unit(g.mean(axis=0))
    across = image_up - np.einsum("ki,i->k", u, image_up)[:, None] * u
    roll = np.degrees(np.arctan2(np.einsum("ki,ki->k", np.cross(across, g), u), np.einsum("ki,ki->k", across, g)))
    w = positions - (starts[leg] + np.einsum("ki,ki->k", positions - starts[leg], u)[:, None] * u)
    offset = np.linalg.norm(w, axis=1)
    side = _unit(-(w / np.maximum(offset, 1e-12)[:, None]).mean(axis=0)) if len(w) else None
    usable_side = side is not None and float(np.median(offset)) >= MIN_SIDE_OFFSET_RADII * radius
    record = {"keyframes": int(len(positions)), "image_up": _list(image_up),
              "roll_spread_deg": round(float(np.std(roll)), 3),
              "camera_offset_m": round(float(np.median(offset)), 5) if len(offset) else None,
              "camera_side_up": _list(side) if usable_side else None,
              "camera_side_vs_image_deg": round(float(np.degrees(np.arccos(np.clip(side @ image_up, -1, 1)))), 3)
              if usable_side else None}
    if isinstance(choice, str) and choice == "image":
        up = image_up
    elif isinstance(choice, str) and choice == "camera-side":
        if not usable_side:
            raise PipemapError(f"the camera rides within {MIN_SIDE_OFFSET_RADII} radii of the axis: its side gives "
                               "no 12 o'clock; use route.up=image or a vector", key="route.up")
        up = side
    else:
        up = _unit(np.asarray(choice, float))
    record["method"] = choice if isinstance(choice, str) else "setting"
    record["up"] = _list(up)
    return up, record


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    n = np.linalg.norm(v)
    return v / n if n > 0 else np.array([0.0, -1.0, 0.0])


def _list(v) -> list[float]:
    return [round(float(x), 6) for x in v]


__all__ = ["estimate_up", "nearest_legs"]
