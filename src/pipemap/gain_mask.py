"""Flat-field gain mask from white-card images (2010 report, section 3.2)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipemap.dataset import read_grey
from pipemap.errors import PipemapError


def build_gain_mask(paths: list[Path], sigma_px: float = 15.0) -> tuple[np.ndarray, list[tuple[Path, str]]]:
    """Average the white-card images and smooth with a Gaussian; returns the mask (float32) and skipped files."""
    if not paths:
        raise PipemapError("no white-card images given")
    total = None
    count = 0
    skipped: list[tuple[Path, str]] = []
    for p in paths:
        try:
            img = read_grey(p)
        except PipemapError as exc:
            skipped.append((p, exc.message))
            continue
        if total is None:
            total = np.zeros(img.shape, np.float64)
        elif img.shape != total.shape:
            skipped.append((p, f"size {img.shape[1]}x{img.shape[0]} differs from the first image"))
            continue
        total += img
        count += 1
    if count == 0:
        raise PipemapError("none of the white-card images could be read", paths[0])
    return smooth_mask(total / count, sigma_px, paths[0]), skipped


def smooth_mask(mean: np.ndarray, sigma_px: float, where=None) -> np.ndarray:
    """Gaussian-smoothed average white-card image: the high-frequency noise removed, the fall-off kept."""
    mask = cv2.GaussianBlur(mean.astype(np.float32), (0, 0), sigmaX=sigma_px, sigmaY=sigma_px,
                            borderType=cv2.BORDER_REFLECT)
    if mask.max() <= 0:
        raise PipemapError("the white-card images are black; cannot make a gain mask", where)
    return mask


def save_gain_mask(path: Path, mask: np.ndarray) -> None:
    """16-bit PNG, scaled so the brightest pixel is 65535 (only the relative gain matters)."""
    scaled = np.clip(np.round(mask / mask.max() * 65535.0), 0, 65535).astype(np.uint16)
    if not cv2.imwrite(str(path), scaled):
        raise PipemapError("cannot write the gain mask", path)
