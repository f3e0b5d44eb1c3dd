"""Metric relative pose of two images of one place seen on two visits (fisheye paper III-E).

SIFT descriptors at the region-Harris corners of both images (the front end's detector, on the
same lighting-flattened image), ratio-test and mutual matching, five-point MSAC on the bearings
to reject wrong matches, then metric scale from the pipe walls: each inlier bearing of image i
meets the cylinder fitted around keyframe i at a metric point, and likewise for image j. With
the rotation of the five-point solution the translation follows linearly from those points, and
a Levenberg-Marquardt refinement of all six degrees of freedom (Huber-weighted angular errors of
both point sets, analytic Jacobian) gives the pose and, from its Jacobian, the covariance the pose
graph weighs it by.

Why the five-point translation is not simply rescaled: loop-closure pairs are chosen at equal
distances to a tee, so their baseline can be a few millimetres, where the direction of the
five-point translation is noise; the metric points fix all three components instead.

Conventions: T_ij is the pose of camera j in camera i's frame (X_i = R_ij X_j + t_ij), i.e.
T_wi^-1 T_wj, and its covariance is that of the right perturbation (rho, phi) of
pipemap.geometry.se3, as the pose graph expects.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipemap.backend.angular import angular_residuals, refine_huber, tangent_bases
from pipemap.camera import CameraModel
from pipemap.config import Settings
from pipemap.frontend.harris import detect_corners, flatten_lighting, valid_mask
from pipemap.frontend.relpose import estimate_relative_pose
from pipemap.frontend.angular import frontend_for, pixel_angle, pixel_scale
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import skew
from pipemap.geometry.se3 import camera_point_jacobian, retract, to_matrix, world_to_camera

_I3 = np.eye(3)


@dataclass(frozen=True)
class LoopEdge:
    """A measured loop closure between two keyframes; indices are set by the caller."""

    T_ij: np.ndarray  # (4, 4) pose of camera j in camera i's frame
    covariance: np.ndarray  # (6, 6) of the right perturbation (rho, phi) of T_ij
    inliers: int  # matches consistent with the pose in both directions
    rms_rad: float  # RMS angular error of the inlier bearings
    matches: int  # descriptor matches before RANSAC


@dataclass(frozen=True)
class PlaceFeatures:
    points: np.ndarray  # (N, 2) pixels
    bearings: np.ndarray  # (N, 3)
    descriptors: np.ndarray  # (N, 128) float32


def place_features(camera: CameraModel, image: np.ndarray, settings: Settings) -> PlaceFeatures:
    """Region-Harris corners of the front end with SIFT descriptors.

    Each keypoint is oriented along the image radius through it: a roll of the robot about the
    optical axis turns the fisheye image about its centre, so radial orientation makes the
    descriptors invariant to the roll that differs between two visits of a pipe.
    """
    if np.shape(image)[:2] != (camera.height, camera.width):
        raise ValueError(f"image of shape {np.shape(image)} does not fit the {camera.width}x{camera.height} camera")
    s = frontend_for(camera, settings.frontend)
    lc = settings.loop_closure
    size = lc.sift_size_px * pixel_scale(camera, settings.frontend.reference_px_per_deg)
    # The descriptor window reaches about 3 keypoint sizes out; keep it inside the image circle.
    margin = int(np.ceil(3.0 * size)) + 1
    img = np.ascontiguousarray(image, dtype=np.float32)
    mask = valid_mask(camera, margin)
    if s.flatten_lighting:
        img, lit = flatten_lighting(img, s.lighting_sigma_px, s.dark_level, contrast_limit=s.contrast_limit)
        mask = mask & lit
        img = img + 128.0
    points, _ = detect_corners(img, mask, tuple(s.regions), s.corners_per_region, s.harris_k, s.harris_block_px,
                               min_distance_px=s.min_distance_px, quality=s.harris_quality)
    if len(points) == 0:
        return PlaceFeatures(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 128), np.float32))
    centre, _ = camera.project(np.array([0.0, 0.0, 1.0]))
    angle = np.degrees(np.arctan2(points[:, 1] - centre[1], points[:, 0] - centre[0])) % 360.0
    keypoints = [cv2.KeyPoint(float(u), float(v), float(size), float(a), 0.0, 0, k)
                 for k, (u, v, a) in enumerate(zip(points[:, 0], points[:, 1], angle))]
    grey = np.clip(img, 0, 255).astype(np.uint8)
    kept, desc = cv2.SIFT_create().compute(grey, keypoints)
    if desc is None or len(kept) == 0:
        return PlaceFeatures(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 128), np.float32))
    idx = np.array([k.class_id for k in kept])
    bearings, ok = camera.unproject(points[idx])
    return PlaceFeatures(points[idx][ok], bearings[ok], desc[ok].astype(np.float32))


def match_sift(desc_i: np.ndarray, desc_j: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours in L2 whose distance passes the ratio test against the second best
    in both directions: (index_i (M,), index_j (M,))."""
    if len(desc_i) < 2 or len(desc_j) < 2:
        return np.zeros(0, int), np.zeros(0, int)
    d2 = (np.sum(desc_i**2, 1)[:, None] + np.sum(desc_j**2, 1)[None, :] - 2.0 * desc_i @ desc_j.T)
    d = np.sqrt(np.maximum(d2, 0.0))
    two_j = np.argpartition(d, 1, axis=1)[:, :2]
    two_i = np.argpartition(d, 1, axis=0)[:2, :]
    rows, cols = np.arange(len(desc_i)), np.arange(len(desc_j))
    a, b = d[rows, two_j[:, 0]], d[rows, two_j[:, 1]]
    best_j = np.where(a <= b, two_j[:, 0], two_j[:, 1])
    pass_i = np.minimum(a, b) < ratio * np.maximum(a, b)
    a, b = d[two_i[0], cols], d[two_i[1], cols]
    best_i = np.where(a <= b, two_i[0], two_i[1])
    pass_j = np.minimum(a, b) < ratio * np.maximum(a, b)
    good = pass_i & (best_i[best_j] == rows) & pass_j[best_j]
    return rows[good], best_j[good]


class _TwoWayProblem:
    """Angular errors of image-i wall points seen from camera j and image-j wall points seen from camera i,
    as a function of the right perturbation delta of T_ij = (R, t). Jacobians are taken at delta = 0: the
    solver moves the pose and linearises again (`moved`), as on any manifold."""

    def __init__(self, R, t, X_i, b_j, X_j, b_i):
        self.R, self.t = R, t
        self.X_i, self.b_j, self.B_j = X_i, b_j, tangent_bases(b_j)
        self.X_j, self.b_i, self.B_i = X_j, b_i, tangent_bases(b_i)

    def moved(self, delta) -> "_TwoWayProblem":
        return _TwoWayProblem(*retract(self.R, self.t, delta), self.X_i, self.b_j, self.X_j, self.b_i)

    def subset(self, keep) -> "_TwoWayProblem":
        return _TwoWayProblem(self.R, self.t, self.X_i[keep], self.b_j[keep], self.X_j[keep], self.b_i[keep])

    def residuals(self, delta=None, jacobian: bool = False):
        """Residuals (4M,): M 2-vectors for the i points in camera j, then M for the j points in camera i."""
        R, t = (self.R, self.t) if delta is None else retract(self.R, self.t, delta)
        in_j = world_to_camera(R, t, self.X_i)  # X_i seen from camera j
        in_i = self.X_j @ R.T + t  # X_j seen from camera i
        if not jacobian:
            r = np.concatenate([angular_residuals(in_j, self.b_j, self.B_j),
                                angular_residuals(in_i, self.b_i, self.B_i)])
            return r.ravel()
        if delta is not None and np.any(delta):
            raise ValueError("the Jacobian is taken at delta = 0; move the problem first")
        r_j, A_j = angular_residuals(in_j, self.b_j, self.B_j, True)
        r_i, A_i = angular_residuals(in_i, self.b_i, self.B_i, True)
        J_j = A_j @ camera_point_jacobian(in_j)
        # d(R exp(phi) X + t + R rho) = R d rho - R [X]x d phi
        dx = np.concatenate([np.broadcast_to(R, (len(self.X_j), 3, 3)), -R @ skew(self.X_j)], axis=-1)
        J_i = A_i @ dx
        r = np.concatenate([r_j, r_i]).ravel()
        return r, np.concatenate([J_j, J_i]).reshape(-1, 6)

    def errors(self) -> np.ndarray:
        """Angular error per match (M,): the larger of its two directions."""
        r = self.residuals().reshape(2, -1, 2)
        return np.max(np.linalg.norm(r, axis=-1), axis=0)


def _translation_given_rotation(R, X_i, b_j, X_j, b_i) -> np.ndarray:
    """t of X_j = R X_i + t from b_j x (R X_i + t) = 0 and (R b_i) x (X_j - t) = 0, each row divided by
    the point's range so that it weighs like an angle."""
    rb_i = b_i @ R.T
    A = np.concatenate([skew(b_j) / np.linalg.norm(X_i, axis=1)[:, None, None],
                        skew(rb_i) / np.linalg.norm(X_j, axis=1)[:, None, None]])
    y = np.concatenate([-np.einsum("mij,mj->mi", skew(b_j), X_i @ R.T) / np.linalg.norm(X_i, axis=1)[:, None],
                        np.einsum("mij,mj->mi", skew(rb_i), X_j) / np.linalg.norm(X_j, axis=1)[:, None]])
    t, *_ = np.linalg.lstsq(A.reshape(-1, 3), y.ravel(), rcond=None)
    return t


def _wall_points(cylinder: Cylinder, bearings: np.ndarray, window_radii: float) -> tuple[np.ndarray, np.ndarray]:
    """Where bearings from the camera (at the origin) meet the wall, and which to use: those within
    `window_radii` radii along the axis of the camera. Further out the wall is seen at grazing angles,
    where a small error of the fitted cylinder moves the point a long way, and it may already be a
    tee's opening rather than the straight pipe."""
    X, _, ok = cylinder.intersect_bearings(_I3, np.zeros(3), bearings)
    along = cylinder.axial(np.where(ok[:, None], X, 0.0)) - cylinder.axial(np.zeros(3))
    return X, ok & (np.abs(along) < window_radii * cylinder.radius)


def relative_pose(camera: CameraModel, image_i: np.ndarray, image_j: np.ndarray, cylinder_i: Cylinder,
                  cylinder_j: Cylinder, settings: Settings | None = None, seed: int | tuple[int, ...] = 0
                  ) -> LoopEdge | None:
    """Metric pose of camera j in camera i's frame from their images and the pipe wall around each.

    `cylinder_i` / `cylinder_j` are the fitted pipe walls in the frames of camera i / camera j. Returns
    None when fewer than `settings.loop_closure.min_inliers` matches agree (the caller drops the pair).
    """
    settings = settings or Settings()
    lc, fe = settings.loop_closure, settings.frontend
    fi = place_features(camera, image_i, settings)
    fj = place_features(camera, image_j, settings)
    ii, jj = match_sift(fi.descriptors, fj.descriptors, lc.match_ratio)
    matches = len(ii)
    if matches < lc.min_inliers:
        return None
    b_i, b_j = fi.bearings[ii], fj.bearings[jj]
    threshold = max(np.radians(fe.ransac_angle_deg), fe.ransac_threshold_px * pixel_angle(camera))
    rng = np.random.default_rng([int(x) for x in np.atleast_1d(seed)] + [0x100])
    five = estimate_relative_pose(b_i, b_j, threshold, fe.ransac_confidence, rng, fe.ransac_max_trials,
                                  min_inliers=lc.min_inliers, refine=False)
    if five is None:
        return None
    X_i, ok_i = _wall_points(cylinder_i, b_i, lc.wall_window_radii)
    X_j, ok_j = _wall_points(cylinder_j, b_j, lc.wall_window_radii)
    use = five.inliers & ok_i & ok_j
    if use.sum() < lc.min_inliers:
        return None
    t = _translation_given_rotation(five.R, X_i[use], b_j[use], X_j[use], b_i[use])
    # X_j = R X_i + t  <=>  T_ij = (R^T, -R^T t)
    problem = _TwoWayProblem(five.R.T, -five.R.T @ t, X_i[use], b_j[use], X_j[use], b_i[use])
    for _ in range(2):  # refine, drop what disagrees with the refined pose, refine again
        problem = refine_huber(problem, threshold)
        keep = problem.errors() < threshold
        if keep.sum() < lc.min_inliers:
            return None
        problem = problem.subset(keep)
    problem = refine_huber(problem, threshold)
    r, J = problem.residuals(jacobian=True)
    # Covariance of the right perturbation from the Gauss-Newton Hessian and the residuals' own scale
    # (an approximation: each match enters twice, and the fitted walls' errors are not in it -- hence
    # the floor).
    sigma2 = float(r @ r) / max(len(r) - 6, 1)
    covariance = sigma2 * np.linalg.inv(J.T @ J)
    floor = np.array([lc.min_sigma_m] * 3 + [np.radians(lc.min_sigma_deg)] * 3) ** 2
    covariance = covariance + np.diag(floor)
    rms = float(np.sqrt(np.mean(np.sum(r.reshape(-1, 2) ** 2, axis=1))))
    return LoopEdge(to_matrix(problem.R, problem.t), covariance, int(len(problem.X_i)), rms, matches)


__all__ = ["LoopEdge", "PlaceFeatures", "place_features", "match_sift", "angular_residuals", "relative_pose"]
