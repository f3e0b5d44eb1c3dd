"""Cross-validation of a checkerboard calibration: does the camera predict views it was not fitted to?

Each fold calibrates on the other views; every held-back view then gets its board pose from its own corners
with the fold's intrinsics fixed (6 unknowns against 2 x nx x ny observations, so that the pose cannot absorb
an error of the intrinsics), and its reprojection error is the held-out error. A model that fits corner noise
instead of the lens shows a held-out error well above its training error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.camera.calibration import MIN_VIEWS, calibrate_from_corners, fit_view
from pipemap.errors import PipemapError


@dataclass
class CrossValidation:
    folds: int
    fold_of_view: list[int]  # the fold that held back each view, in input order
    held_out_rms: list[float]  # each view's error when held back, over its corners kept
    held_out_corners: list[int]  # corners kept in each held-back view's pose fit
    train_rms: list[float]  # each fold's calibration RMS

    @property
    def held_out_rms_px(self) -> float:
        """Over every held-back corner of every view."""
        e2 = np.square(self.held_out_rms) * np.asarray(self.held_out_corners)
        return float(np.sqrt(e2.sum() / max(sum(self.held_out_corners), 1)))

    @property
    def train_rms_px(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.train_rms))))

    @property
    def worst_view(self) -> int:
        return int(np.argmax(self.held_out_rms))


def cross_validate(views, board=(9, 6), square: float = 0.025, model: str = "polynomial", width: int = 1280,
                   height: int = 960, folds: int | None = None, seed: int = 0, **calibrate_kwargs) -> CrossValidation:
    """k-fold cross-validation over `views` (corner arrays as for `calibrate_from_corners`); `folds` None, or
    at least the number of views, means leave-one-out. Views are dealt to folds in a seeded random order."""
    views = [np.asarray(v, float).reshape(-1, 2) for v in views]
    n = len(views)
    if n < MIN_VIEWS + 1:
        raise PipemapError(f"cross-validation needs at least {MIN_VIEWS + 1} views, got {n}")
    if folds is not None and folds < 2:
        raise PipemapError(f"cross-validation needs at least 2 folds, got {folds}")
    k = n if folds is None or folds >= n else int(folds)
    order = np.arange(n) if k == n else np.random.default_rng(seed).permutation(n)
    fold_of_view = np.empty(n, int)
    fold_of_view[order] = np.arange(n) % k
    held_rms, held_corners, train_rms = np.zeros(n), np.zeros(n, int), []
    for f in range(k):
        train = np.nonzero(fold_of_view != f)[0]
        try:
            result = calibrate_from_corners([views[i] for i in train], board, square, model, width, height,
                                            **calibrate_kwargs)
        except PipemapError as exc:
            raise PipemapError(f"cross-validation fold {f + 1} of {k}: {exc.message}") from None
        train_rms.append(result.rms_px)
        for i in np.nonzero(fold_of_view == f)[0]:
            _, _, held_rms[i], kept = fit_view(result.camera, views[i], board, square,
                                               calibrate_kwargs.get("outlier_factor", 5.0))
            held_corners[i] = int(kept.sum())
    return CrossValidation(folds=k, fold_of_view=fold_of_view.tolist(), held_out_rms=held_rms.tolist(),
                           held_out_corners=held_corners.tolist(), train_rms=train_rms)
