"""The camera's mount in the pipe: how it is turned relative to the pipe axis and how far it sits from it.

The sparse method's initial batch (sparse/odometry.py, sparse/batch.py) estimates the poses of its keyframes
relative to the wall of known radius; the mount is their mean in the report's pipe frame (section 2), the
robot's wobble averaged out: the angle between the optical axis and the pipe axis (90 deg: square to the
wall, less: turned towards the direction of travel), the roll of the pipe axis in the image (0: along image
x) and the offset (C_X, C_Y) from the axis, Y being the direction the camera looks in. Standard deviations
come from the bundle batch's Gauss-Newton covariance of the axis (none for the report's eqs. 45-49, which
hold the rotation; none for a measured offset kept as given).

`estimate_mount` runs the same front end and batch over the first frames of a dataset and stops as soon as
the batch has settled, so that the dense methods use the very estimate the sparse method starts from.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from pipemap.config import Settings
from pipemap.dataset import Dataset
from pipemap.errors import PipemapError
from pipemap.straight.sparse.batch import mount_of
from pipemap.straight.sparse.geometry import rotation_from_travel
from pipemap.straight.sparse.keyframes import KeyframeSelector
from pipemap.straight.sparse.odometry import SparseOdometry


@dataclass(frozen=True)
class Mount:
    rotation: np.ndarray  # (3, 3) camera -> pipe axes of the mount, looking towards +Y
    angle_deg: float  # optical axis to the pipe axis
    roll_deg: float  # the pipe axis in the image, from image x towards image y
    offset_m: np.ndarray  # (C_X, C_Y)
    sigma: np.ndarray | None  # (4,) standard deviations of angle_deg, roll_deg (deg), C_X, C_Y (m)
    determined: bool  # the images fix the offset (its sigma within sparse.offset_max_sigma of the wall distance)
    source: str  # the batch that set it: batch, long bundle, long batch (eqs. 45-49) or given (measured)
    keyframes: tuple[int, ...]  # image indices of the keyframes it came from
    frames: int  # images read to get it
    rms_px: float
    observations: int
    fit_rms_px: float = np.nan  # the bundle batch's RMS: how well the straight-pipe model fits (odometry.BatchSummary)

    @classmethod
    def from_odometry(cls, odometry: SparseOdometry, frames: int) -> "Mount | None":
        off = odometry.offset
        if off is None or not odometry.keyframes:
            return None
        first = odometry.keyframes[0]
        given = off.used == "given" or off.mount is None
        values = mount_of(first.R, first.C) if given else off.mount
        sigma = None
        if off.mount_covariance is not None and not given:
            sd = np.sqrt(np.maximum(np.diag(off.mount_covariance), 0.0))
            sigma = np.r_[np.degrees(sd[:2]), sd[2:]]
        axis = np.array([np.sin(values[0]) * np.cos(values[1]), np.sin(values[0]) * np.sin(values[1]),
                         np.cos(values[0])])  # the pipe axis in camera axes
        return cls(rotation_from_travel(axis), float(np.degrees(values[0])), float(np.degrees(values[1])),
                   np.array(values[2:], float),
                   sigma, bool(off.determined), off.used, tuple(off.keyframes), frames,
                   float(off.rms_px), int(off.observations),
                   float(off.fit_rms_px if np.isfinite(off.fit_rms_px) else off.rms_px))

    def to_dict(self) -> dict:
        sd = [None] * 4 if self.sigma is None else [float(x) if np.isfinite(x) else None for x in self.sigma]
        return {
            "angle_to_axis_deg": self.angle_deg, "angle_sigma_deg": sd[0],
            "roll_deg": self.roll_deg, "roll_sigma_deg": sd[1],
            "C_X_m": float(self.offset_m[0]), "C_X_sigma_m": sd[2],
            "C_Y_m": float(self.offset_m[1]), "C_Y_sigma_m": sd[3],
            "determined": self.determined, "source": self.source,
            "keyframes": list(self.keyframes), "frames_read": self.frames,
            "rms_px": self.rms_px, "observations": self.observations, "fit_rms_px": self.fit_rms_px,
            "note": ("the camera in the pipe frame (report section 2), mean over the keyframes listed: angle between "
                     "its optical axis and the pipe axis (90 = square to the wall, less = turned towards the "
                     "travel), roll of the pipe axis in the image (0 = along image x, positive towards image y), "
                     "offset (C_X, C_Y) from the axis with Y the direction it looks in; sigmas from the bundle "
                     "batch's covariance of the axis"),
        }

    def line(self) -> str:
        """One line for the console."""
        def pm(value, sd, scale, unit, digits):
            return f"{value * scale:.{digits}f}" + ("" if sd is None else f" +- {sd * scale:.{digits}f}") + unit
        sd = [None] * 4 if self.sigma is None else list(self.sigma)
        return (f"mount: {pm(self.angle_deg, sd[0], 1, ' deg', 2)} to the axis, "
                f"roll {pm(self.roll_deg, sd[1], 1, ' deg', 2)},"
                f" C_X {pm(self.offset_m[0], sd[2], 1e3, ' mm', 2)}, C_Y {pm(self.offset_m[1], sd[3], 1e3, ' mm', 2)}"
                f" ({self.source}, {len(self.keyframes)} keyframes)")


def estimate_mount(dataset: Dataset, settings: Settings, gain_correct: bool = True,
                   progress: Callable[[int, int], None] | None = None, start: int = 0) -> Mount:
    """The sparse method's front end and initial batch over the frames of `dataset` from `start`, read until the
    batch has settled (or the frames end). A dataset whose images cannot give the mount ends with a PipemapError."""
    sp = settings.sparse
    selector = KeyframeSelector(dataset.camera, sp, settings.seed, not (gain_correct and dataset.has_gain_mask))
    odometry = SparseOdometry(dataset.camera, dataset.radius_m, sp, settings.seed)
    most = max(sp.offset_batch_keyframes, sp.offset_long_keyframes)  # every batch has run by then
    n = 0
    for frame in dataset.frames(start, gain_correct=gain_correct):
        if frame.repeated:
            continue
        for link in selector.push(frame.index, frame.image):
            odometry.add(link, refine=False)
        n += 1
        if progress is not None:
            progress(n, len(dataset))
        if odometry.mount_settled() or len(odometry.keyframes) > most:
            break
    else:
        for link in selector.finish():
            odometry.add(link, refine=False)
    odometry.settle()
    mount = Mount.from_odometry(odometry, n)
    if mount is None:
        raise PipemapError(
            f"the camera's mount cannot be estimated: {len(odometry.keyframes)} keyframes in {n} images, too few "
            "wall points seen by two or more of them (the camera sees too little of the wall, or the robot barely "
            "moves); give dense.pixels_per_metre or dense.camera_offset_m and dense.mount=square", dataset.yaml_path)
    require_wall_view(dataset, settings, mount)
    return mount


def require_wall_view(dataset: Dataset, settings: Settings, mount: Mount | None) -> None:
    """Refuse a recording the straight-pipe model does not fit at all: the mount's bundle batch reprojects worse
    than quality.rms_px's failed limit (not the long batch's eqs. 45-49, which hold every keyframe at one rotation
    and so misfit the wobble of any crawler). The usual cause, a camera looking along the pipe, is measured and
    named."""
    limit = settings.quality.rms_px[1]
    if mount is None or not np.isfinite(mount.fit_rms_px) or mount.fit_rms_px <= limit:
        return
    from pipemap.view import ALONG, camera_view

    misfit = (f"the straight-pipe model does not fit these images (mount batch reprojection RMS {mount.fit_rms_px:.1f} "
              f"px, limit {limit:g})")
    try:
        view = camera_view(dataset, settings)
    except PipemapError:
        view = None
    if view is not None and view.looks == ALONG:
        raise PipemapError(f"{misfit}: the camera looks along the pipe ({view.reason()}); the straight-pipe methods "
                           "need a camera looking at the wall: use --method network", dataset.yaml_path)
    raise PipemapError(f"{misfit}: is this a straight pipe seen by a camera looking at its wall?", dataset.yaml_path)
