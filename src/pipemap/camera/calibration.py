"""Checkerboard calibration of every pipemap camera model.

Corners are found by OpenCV and placed by a point-symmetry fit (`corners.py`); each view's board pose is
initialised from bearings (a DLT homography between the board plane and unit bearings, which stays valid past
90 deg), and intrinsics and all poses are then refined together on the pixel reprojection error by a sparse
least-squares problem whose Jacobian is analytic: the camera model's own `project_jacobian` chained with the
derivative of the board pose. Single corners far off the fit are left out of it, whole views far off dropped.
A pose maps board to camera, X_cam = exp(rvec) X_board + tvec, with inner corner (i, j) at (i, j, 0) * square.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from pipemap.camera import MODELS, CameraModel, save_camera
from pipemap.camera.corners import detect_corners
from pipemap.errors import PipemapError
from pipemap.geometry.rotations import exp_so3, log_so3, skew

NOMINAL_FOV_DEG = 95.0  # half field of view assumed by the fisheye initial guess (a 190 deg lens)
MIN_VIEWS = 3
# A corner is left out when its error exceeds this many times the median corner error, and this floor:
# a corner the detector could not place (cut by the image circle, glare, a washed-out tip) would otherwise
# cost its whole view or bend the fit. A view keeping fewer than MIN_KEPT of its corners is dropped instead.
CORNER_FLOOR_PX = 1.0
MIN_KEPT = 0.5
DENSE_LIMIT = 2000  # unknowns up to which the trust-region steps are solved exactly
# Parameters refined in the first stage, before the distortion terms are released.
_LINEAR = {"polynomial": ("k1", "u0", "v0"), "kannala_brandt": ("fx", "fy", "cx", "cy"),
           "pinhole": ("fx", "fy", "cx", "cy")}


@dataclass
class CalibrationResult:
    camera: CameraModel
    rms_px: float
    per_view_rms: list[float]  # one per kept view, in the order of `used`
    poses: list[tuple[np.ndarray, np.ndarray]]  # (rvec, tvec) board-to-camera, in the order of `used`
    iterations: int
    used: list[int]  # indices into the input views that were kept
    dropped: list[tuple[int, str]] = field(default_factory=list)  # input index, reason
    board: tuple[int, int] = (9, 6)
    square: float = 0.025
    rejected: list[tuple[int, int]] = field(default_factory=list)  # (input view, corner index) left out of the fit
    corners: list[np.ndarray] = field(default_factory=list)  # (nx * ny, 2) detected corners of each kept view
    images: list[Path] = field(default_factory=list)  # calibrate_images: the image of each kept view
    skipped: list[tuple[Path, str]] = field(default_factory=list)  # calibrate_images: images not used, why


# -- board and corners ---------------------------------------------------------------------------


def board_points(board=(9, 6), square: float = 0.025) -> np.ndarray:
    """(nx * ny, 3) inner corners on z = 0, row by row (nx per row), the order OpenCV's detectors return."""
    nx, ny = board
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    return np.stack([i.ravel() * square, j.ravel() * square, np.zeros(nx * ny)], axis=-1)


# -- initialisation --------------------------------------------------------------------------------


def initial_camera(model: str, width: int, height: int, views, obj, initial: dict | None = None,
                   max_theta_deg: float | None = None) -> CameraModel:
    """Fisheye: equidistant guess, the inscribed circle spanning the nominal field of view. Pinhole: Zhang."""
    cls = MODELS[model]
    if initial is not None:
        return cls(width, height, initial, max_theta_deg)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    if model == "pinhole":
        K = cv2.initCameraMatrix2D([obj.astype(np.float32)] * len(views), [v.astype(np.float32) for v in views],
                                   (width, height))
        return cls(width, height, dict(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], k1=0, k2=0, p1=0, p2=0, k3=0))
    f = 0.5 * min(width, height) / np.radians(max_theta_deg or NOMINAL_FOV_DEG)
    if model == "polynomial":
        params = dict(k1=f, k2=0.0, k3=0.0, k4=0.0, u0=cx, v0=cy)
    else:
        params = dict(fx=f, fy=f, cx=cx, cy=cy, k1=0.0, k2=0.0, k3=0.0, k4=0.0)
    return cls(width, height, params)


def pose_from_bearings(obj: np.ndarray, bearings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Board pose from plane points (z = 0) and unit bearings: DLT on eta x (H [X, Y, 1]) = 0."""
    xy = obj[:, :2]
    mean, scale = xy.mean(axis=0), np.sqrt(2) / np.mean(np.linalg.norm(xy - xy.mean(axis=0), axis=1))
    T = np.array([[scale, 0, -scale * mean[0]], [0, scale, -scale * mean[1]], [0, 0, 1]])
    p = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ T.T
    # skew(eta) @ kron(I3, p^T): three equations per point, two independent.
    A = np.einsum("nij,njk->nik", skew(bearings), np.kron(np.eye(3), p[:, None, :]))
    H = np.linalg.svd(A.reshape(-1, 9), full_matrices=False)[2][-1].reshape(3, 3) @ T
    if np.sum(np.einsum("ij,nj,ni->n", H, np.concatenate([xy, np.ones((len(xy), 1))], 1), bearings)) < 0:
        H = -H
    lam = 2.0 / (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
    r1, r2, t = lam * H[:, 0], lam * H[:, 1], lam * H[:, 2]
    U, _, Vt = np.linalg.svd(np.stack([r1, r2, np.cross(r1, r2)], axis=1))
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    return log_so3(R), t


# -- the least-squares problem -------------------------------------------------------------------------


def _trial_camera(camera: CameraModel, params) -> CameraModel:
    """`camera` with new parameters, validated where possible.

    The models refuse parameters whose projection is not monotone over the image; as a cost that would be
    a wall that the optimiser's path to the true camera may have to cross (a strongly distorted pinhole
    lens does), so trial cameras that fail the check keep the projection, which needs only the parameters.
    """
    try:
        return type(camera)(camera.width, camera.height, params)
    except PipemapError:
        return camera.for_optimiser(params)


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    """(V, 3, 3): d exp(w) X / d w = -skew(exp(w) X) @ J_l(w)."""
    theta = np.linalg.norm(w, axis=-1)[:, None, None]
    K = skew(w)
    small = theta < 1e-6
    ts = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(ts)) / ts**2)
    b = np.where(small, 1.0 / 6 - theta**2 / 120, (ts - np.sin(ts)) / ts**3)
    return np.eye(3) + a * K + b * (K @ K)


class CalibrationProblem:
    """Reprojection residuals of V views of one board over the free intrinsics and 6 pose parameters a view.

    x = [free intrinsics, (rvec, tvec) of view 0, (rvec, tvec) of view 1, ...]. Corners outside `mask` (V, N)
    keep their rows with zero residual and zero Jacobian, so that the problem's shape does not change.
    """

    def __init__(self, camera: CameraModel, obj: np.ndarray, observed: np.ndarray, free: np.ndarray,
                 mask: np.ndarray | None = None):
        self.camera = camera
        self.obj = np.asarray(obj, float)
        self.observed = np.asarray(observed, float)  # (V, N, 2)
        self.free = np.asarray(free, bool)
        self.n_views, self.n_points = self.observed.shape[:2]
        self.mask = np.ones((self.n_views, self.n_points), bool) if mask is None else np.asarray(mask, bool)

    def pack(self, params: np.ndarray, rvecs: np.ndarray, tvecs: np.ndarray) -> np.ndarray:
        return np.concatenate([params[self.free], np.concatenate([rvecs, tvecs], axis=1).ravel()])

    def unpack(self, x: np.ndarray):
        nf = int(self.free.sum())
        params = self.camera.params.copy()
        params[self.free] = x[:nf]
        poses = x[nf:].reshape(self.n_views, 6)
        return params, poses[:, :3], poses[:, 3:]

    def _camera(self, params) -> CameraModel:
        return _trial_camera(self.camera, params)

    def _points(self, rvecs, tvecs):
        Xr = np.einsum("vij,nj->vni", exp_so3(rvecs), self.obj)
        return Xr, Xr + tvecs[:, None, :]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        params, rvecs, tvecs = self.unpack(x)
        cam = self._camera(params)
        uv = cam.project_jacobian(self._points(rvecs, tvecs)[1])[0]
        r = np.where(self.mask[..., None], uv - self.observed, 0.0).ravel()
        return np.where(np.isfinite(r), r, 1e6)

    def jacobian(self, x: np.ndarray) -> sp.csr_matrix:
        params, rvecs, tvecs = self.unpack(x)
        cam = self._camera(params)
        Xr, Xc = self._points(rvecs, tvecs)
        _, J_point, J_params = cam.project_jacobian(Xc)
        dX_dw = -skew(Xr) @ _left_jacobian(rvecs)[:, None]  # (V, N, 3, 3)
        J_pose = np.concatenate([J_point @ dX_dw, J_point], axis=-1)  # (V, N, 2, 6)
        keep = self.mask[..., None, None]
        J_pose, J_params = J_pose * keep, J_params * keep
        m, nf = self.observed.size, int(self.free.sum())
        rows = np.arange(m)
        view_of_row = rows // (2 * self.n_points)
        r_int = np.repeat(rows, nf)
        c_int = np.tile(np.arange(nf), m)
        r_pose = np.repeat(rows, 6)
        c_pose = (nf + 6 * view_of_row[:, None] + np.arange(6)).ravel()
        data = np.concatenate([J_params[..., self.free].ravel(), J_pose.ravel()])
        shape = (m, nf + 6 * self.n_views)
        return sp.csr_matrix((data, (np.concatenate([r_int, r_pose]), np.concatenate([c_int, c_pose]))), shape=shape)

    def corner_errors(self, x: np.ndarray) -> np.ndarray:
        """(V, N) reprojection error of each corner, pixels; zero outside the mask."""
        return np.linalg.norm(self.residuals(x).reshape(self.n_views, self.n_points, 2), axis=-1)

    def view_rms(self, x: np.ndarray) -> np.ndarray:
        e2 = self.corner_errors(x) ** 2
        return np.sqrt(e2.sum(axis=1) / np.maximum(self.mask.sum(axis=1), 1))

    def rms(self, x: np.ndarray) -> float:
        """Over the corners in use, per corner (both coordinates), as OpenCV reports it."""
        return float(np.sqrt(np.sum(self.corner_errors(x) ** 2) / max(int(self.mask.sum()), 1)))

    def solve(self, x0: np.ndarray, max_nfev: int = 100):
        # The sparse Jacobian is assembled either way. Up to a few hundred views MINPACK's dense
        # Levenberg-Marquardt converges in a handful of iterations (its QR needs no threaded BLAS, which
        # thrashes on small busy machines); beyond that, a trust region with LSMR steps keeps memory sparse.
        if x0.size <= DENSE_LIMIT:
            return least_squares(self.residuals, x0, jac=lambda x: self.jacobian(x).toarray(), method="lm",
                                 x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=max_nfev)
        return least_squares(self.residuals, x0, jac=self.jacobian, method="trf", x_scale="jac", tr_solver="lsmr",
                             ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=max_nfev)


# -- calibration --------------------------------------------------------------------------------------


def calibrate_from_corners(views, board=(9, 6), square: float = 0.025, model: str = "polynomial",
                           width: int = 1280, height: int = 960, initial: dict | None = None,
                           max_theta_deg: float | None = None, fix=(), outlier_factor: float = 5.0
                           ) -> CalibrationResult:
    """Calibrate `model` from detected corners (one (nx * ny, 2) array per view).

    `fix` names parameters held at their initial value (e.g. ("k3", "k4") or ("p1", "p2", "k3")).
    Views whose error after initialisation, or after the fit, is far above the others' are dropped and
    listed in `dropped`; a PipemapError is raised when fewer than three views remain.
    """
    if model not in MODELS:
        raise PipemapError(f"unknown camera model {model!r} (expected one of {', '.join(MODELS)})", key="model")
    obj = board_points(board, square)
    views = _checked_views(views, obj, board, model, fix)
    cam = initial_camera(model, width, height, views, obj, initial, max_theta_deg)
    cam = type(cam)(width, height, cam.params)  # the field-of-view limit applies to the result only
    observed = np.stack(views)
    used, poses, dropped, iterations = _initial_poses(cam, obj, observed, views, outlier_factor)

    names = cam.param_names
    free_all = np.array([n not in fix for n in names])
    stage1 = free_all & np.array([n in _LINEAR[model] for n in names])
    cam, poses, n = _refine_in_stages(cam, obj, observed[used], poses, stage1, free_all)
    iterations += n
    cam, poses, used, mask, n = _refine_without_outliers(cam, obj, observed, views, used, poses, free_all,
                                                         outlier_factor, dropped)
    iterations += n

    try:
        final = type(cam)(width, height, cam.params, max_theta_deg)
    except PipemapError as exc:
        raise PipemapError(f"calibration gave an invalid {model} camera ({exc.message}); add views that reach "
                           "the edge of the image or fix the highest distortion term") from None
    prob = CalibrationProblem(final, obj, observed[used], free_all, mask[used])
    x = prob.pack(final.params, poses[:, :3], poses[:, 3:])
    rejected = [(u, int(i)) for u in used for i in np.nonzero(~mask[u])[0]]
    return CalibrationResult(
        camera=final, rms_px=prob.rms(x),
        per_view_rms=[float(e) for e in prob.view_rms(x)], poses=[(p[:3].copy(), p[3:].copy()) for p in poses],
        iterations=int(iterations), used=used, dropped=sorted(dropped), board=tuple(board), square=float(square),
        rejected=rejected, corners=[views[u].copy() for u in used])


def _checked_views(views, obj: np.ndarray, board, model: str, fix) -> list[np.ndarray]:
    """The views as (nx * ny, 2) arrays, refused when a view does not match the board, when there are too few
    views, or when `fix` names a parameter `model` does not have."""
    views = [np.asarray(v, float).reshape(-1, 2) for v in views]
    for k, v in enumerate(views):
        if v.shape != (len(obj), 2):
            raise ValueError(f"view {k} has {len(v)} corners, a {board[0]}x{board[1]} board has {len(obj)}")
    if len(views) < MIN_VIEWS:
        raise PipemapError(f"{len(views)} views with a detected board; calibration needs at least {MIN_VIEWS}")
    unknown = set(fix) - set(MODELS[model].param_names)
    if unknown:
        raise PipemapError(f"cannot fix {', '.join(sorted(unknown))}: "
                           f"{model} has {' '.join(MODELS[model].param_names)}")
    return views


def _initial_poses(cam: CameraModel, obj, observed, views, outlier_factor: float):
    """Each view's pose under the initial camera, views far off it dropped: used views, their poses, the
    dropped ones (input index, reason), njev."""
    used = list(range(len(views)))
    # Poses alone first, so that the outlier test sees each view at its best under the initial guess.
    poses, rms, iterations = _fit_poses(cam, obj, observed)
    keep = _inliers(rms, outlier_factor, floor_px=10.0)
    dropped = [(used[k], f"reprojection error {rms[k]:.1f} px after initialisation") for k in np.nonzero(~keep)[0]]
    used, poses = [u for u, ok in zip(used, keep) if ok], poses[keep]
    _check_count(used, views)
    return used, poses, dropped, iterations


def _refine_in_stages(cam: CameraModel, obj, observed, poses, stage1, free_all):
    """The `stage1` intrinsics and the poses, then every free intrinsic, then each view's pose again from the
    refined camera where that fits it better: camera, poses, njev."""
    cam, poses, _, _, iterations = _refine(cam, obj, observed, poses, stage1)
    cam, poses, _, _, n = _refine(cam, obj, observed, poses, free_all)
    iterations += n
    # A pose initialised under the rough first camera can sit in the mirror minimum of a planar target
    # (the tilt ambiguity of near-frontal boards); start every view again from the refined camera.
    fresh, fresh_rms, n = _fit_poses(cam, obj, observed)
    old_rms = CalibrationProblem(cam, obj, observed, np.zeros(len(cam.param_names), bool)).view_rms(poses.ravel())
    poses = np.where((fresh_rms < old_rms)[:, None], fresh, poses)
    iterations += n
    return cam, poses, iterations


def _refine_without_outliers(cam: CameraModel, obj, observed, views, used, poses, free_all, outlier_factor: float,
                             dropped: list):
    """Refine on the corners in use, after each solve leaving out the corners far off the fit (and the views left
    with too few of them) or, when no corner is, the views far off it; at most six solves. The views dropped are
    added to `dropped`. Returns camera, poses, used views, the mask of corners in use by input view, njev."""
    iterations = 0
    mask = np.ones(observed.shape[:2], bool)  # corners in use, by input view
    for attempt in range(6):
        cam, poses, rms, errors, n = _refine(cam, obj, observed[used], poses, free_all, mask[used])
        iterations += n
        if attempt == 5:
            break
        bad = mask[used] & (errors > max(outlier_factor * np.median(errors[mask[used]]), CORNER_FLOOR_PX))
        if bad.any():
            mask[np.asarray(used)] &= ~bad
            few = mask[used].mean(axis=1) < MIN_KEPT
            dropped += [(used[k], f"{int(bad[k].sum())} of {len(obj)} corners off the fit") for k in np.nonzero(few)[0]]
            used, poses = [u for u, f in zip(used, few) if not f], poses[~few]
            _check_count(used, views)
            continue
        keep = _inliers(rms, outlier_factor, floor_px=1.0)
        if keep.all():
            break
        dropped += [(used[k], f"reprojection error {rms[k]:.2f} px after calibration") for k in np.nonzero(~keep)[0]]
        used, poses = [u for u, ok in zip(used, keep) if ok], poses[keep]
        _check_count(used, views)
    return cam, poses, used, mask, iterations


def fit_view(camera: CameraModel, corners: np.ndarray, board=(9, 6), square: float = 0.025,
             outlier_factor: float = 5.0) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """One view's board pose under a fixed camera, with the calibration's corner test:
    rvec, tvec, rms over the corners kept, and the mask of corners kept."""
    obj = board_points(board, square)
    observed = np.asarray(corners, float).reshape(1, -1, 2)
    mask = np.ones(observed.shape[:2], bool)
    for attempt in range(4):
        poses, rms, _ = _fit_poses(camera, obj, observed, mask)
        errors = CalibrationProblem(camera, obj, observed, np.zeros(len(camera.params), bool), mask).corner_errors(
            poses.ravel())
        bad = mask & (errors > max(outlier_factor * np.median(errors[mask]), CORNER_FLOOR_PX))
        if attempt == 3 or not bad.any() or (mask & ~bad).mean() < MIN_KEPT:
            break
        mask &= ~bad
    return poses[0, :3], poses[0, 3:], float(rms[0]), mask[0]


def _fit_poses(cam: CameraModel, obj, observed, mask=None) -> tuple[np.ndarray, np.ndarray, int]:
    """Each view's pose from bearings under `cam`, then refined with the intrinsics held: (V, 6), rms, njev."""
    mask = np.ones(np.shape(observed)[:2], bool) if mask is None else mask
    poses = np.array([np.concatenate(pose_from_bearings(obj[m], cam.unproject(v[m])[0]))
                      for v, m in zip(observed, mask)])
    prob = CalibrationProblem(cam, obj, observed, np.zeros(len(cam.params), bool), mask)
    sol = prob.solve(poses.ravel(), max_nfev=50)
    return sol.x.reshape(-1, 6), prob.view_rms(sol.x), int(sol.njev)


def _refine(cam: CameraModel, obj, observed, poses, free, mask=None):
    """Intrinsics (where `free`) and all poses together: camera, poses, per-view rms, per-corner errors, njev."""
    prob = CalibrationProblem(cam, obj, observed, free, mask)
    sol = prob.solve(prob.pack(cam.params, poses[:, :3], poses[:, 3:]))
    params, rvecs, tvecs = prob.unpack(sol.x)
    return (_trial_camera(cam, params), np.concatenate([rvecs, tvecs], axis=1), prob.view_rms(sol.x),
            prob.corner_errors(sol.x), int(sol.njev))


def _inliers(rms: np.ndarray, factor: float, floor_px: float) -> np.ndarray:
    return rms <= max(factor * np.median(rms), floor_px)


def _check_count(used, views):
    if len(used) < MIN_VIEWS:
        raise PipemapError(f"only {len(used)} of {len(views)} views fit the camera model; "
                           f"calibration needs {MIN_VIEWS}")


# -- images and files ------------------------------------------------------------------------------------


def calibrate_images(paths, board=(9, 6), square: float = 0.025, model: str = "polynomial",
                     initial: dict | None = None, max_theta_deg: float | None = None, fix=(),
                     source: str | Path | None = None) -> CalibrationResult:
    """Detect the board in each image and calibrate; unreadable images and views without the board are
    skipped and listed in `result.skipped` as (path, reason). `source` (the glob) names the input in errors."""
    paths = [Path(p) for p in paths]
    where = source if source is not None else (paths[0].parent if paths else None)
    if not paths:
        raise PipemapError("no images given", where)
    skipped: list[tuple[Path, str]] = []
    found: list[tuple[Path, np.ndarray]] = []
    size = None
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            skipped.append((path, "unreadable image"))
            continue
        if size is None:
            size = image.shape[::-1]
        elif image.shape[::-1] != size:
            skipped.append((path, f"image is {image.shape[1]}x{image.shape[0]}, the first is {size[0]}x{size[1]}"))
            continue
        corners = detect_corners(image, board)
        if corners is None:
            skipped.append((path, f"{board[0]}x{board[1]} board not found"))
        else:
            found.append((path, corners))
    if len(found) < MIN_VIEWS:
        raise PipemapError(f"the board was found in {len(found)} of {len(paths)} images; "
                           f"calibration needs at least {MIN_VIEWS}", where)
    try:
        result = calibrate_from_corners([c for _, c in found], board, square, model, size[0], size[1],
                                        initial, max_theta_deg, fix)
    except PipemapError as exc:
        raise PipemapError(exc.message, where, exc.key) from None
    result.images = [found[k][0] for k in result.used]
    result.skipped = skipped + [(found[k][0], reason) for k, reason in result.dropped]
    return result


def save_calibration(path: str | Path, result: CalibrationResult, cross_validation=None) -> None:
    """Write the camera file with the calibration residuals (and a `CrossValidation` of the same views)
    beside the `camera:` block."""
    names = [p.name for p in result.images] or [f"view {k}" for k in result.used]
    views = [{"image": n, "rms_px": round(float(e), 4)} for n, e in zip(names, result.per_view_rms)]
    for view, u in zip(views, result.used):
        left_out = sum(1 for v, _ in result.rejected if v == u)
        if left_out:
            view["corners_left_out"] = left_out
    if cross_validation is not None:
        for view, e in zip(views, cross_validation.held_out_rms):
            view["held_out_rms_px"] = round(float(e), 4)
    calibration = {
        "rms_px": round(float(result.rms_px), 4),
        "views": views,
        "board": f"{result.board[0]}x{result.board[1]}",
        "square_m": float(result.square),
    }
    if cross_validation is not None:
        calibration["cross_validation"] = {"folds": cross_validation.folds,
                                           "train_rms_px": round(cross_validation.train_rms_px, 4),
                                           "held_out_rms_px": round(cross_validation.held_out_rms_px, 4)}
    if result.skipped:
        calibration["skipped"] = [{"image": Path(p).name, "reason": why} for p, why in result.skipped]
    save_camera(path, result.camera, extra={"calibration": calibration})
