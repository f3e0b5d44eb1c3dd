"""Synthetic sparse windows of a straight pipe with exact ground truth, for bundle-adjustment tests and
benchmarks: a crawler's fisheye camera moving down a cylinder, wall points observed over short tracks with
pixel noise and gross outliers, and an initial guess at the wrong scale."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipemap.camera import PolynomialCamera
from pipemap.geometry.cylinder import Cylinder, rot_x, rot_z
from pipemap.geometry.rotations import exp_so3, look_rotation

from tracks import tracked_runs

RADIUS = 0.2


@dataclass
class PipeWindow:
    camera: PolynomialCamera
    cylinder: Cylinder  # ground truth
    R: np.ndarray  # (N, 3, 3) true T_wc
    t: np.ndarray  # (N, 3)
    points: np.ndarray  # (M, 3) true
    obs_camera: np.ndarray  # (K,) keyframe index of each observation
    obs_point: np.ndarray  # (K,) point index
    obs_pixels: np.ndarray  # (K, 2) noisy, with outliers
    outlier: np.ndarray  # (K,) bool: gross outliers
    R0: np.ndarray  # initial guess
    t0: np.ndarray
    points0: np.ndarray


def fisheye_640() -> PolynomialCamera:
    return PolynomialCamera(640, 480, dict(k1=150.0, k2=-3.0, k3=0.5, k4=0.0, u0=320.3, v0=239.6), 95)


def make_pipe_window(n_frames=80, n_points=3000, step=0.01, noise_px=0.5, outlier_frac=0.05, scale0=0.9,
                     seed=0, track=(3, 7), sag_m=0.0) -> PipeWindow:
    """A straight pipe window with exact ground truth; see the module docstring. sag_m: the pipe
    is instead two pieces that meet sag_m low (-y) half-way along the window, and the crawler
    follows its floor (the true cylinder is then the straight line between the ends)."""
    rng = np.random.default_rng(seed)
    cam = fisheye_640()
    k = np.arange(n_frames)
    # Pipe frame: axis along z. The crawler rides below the axis and wobbles.
    c = np.stack([0.02 + 0.02 * np.sin(2 * np.pi * k / 40), -0.05 + 0.01 * np.cos(2 * np.pi * k / 25), step * k], -1)
    fwd = np.stack([0.03 * np.sin(2 * np.pi * k / 30), 0.02 * np.cos(2 * np.pi * k / 45), np.ones(n_frames)], -1)
    R = look_rotation(fwd, np.array([0.0, -1.0, 0.0])) @ rot_z(0.05 * np.sin(2 * np.pi * k / 35))
    length = step * (n_frames - 1)

    def sag(z):  # the axis's offset along y, and its slope
        half = length / 2
        return (-sag_m * np.clip(np.where(z < half, z / half, (length - z) / half), 0.0, 1.0),
                np.where((z > 0) & (z < length), np.where(z < half, -sag_m / half, sag_m / half), 0.0))

    if sag_m:
        off, slope = sag(c[:, 2])
        c[:, 1] += off
        R = rot_x(-np.arctan(slope)) @ R  # pitched with the piece it rides on
    # Then the whole scene goes to a general place in the world.
    G = exp_so3(np.array([0.3, -0.5, 0.2]))
    g = np.array([1.0, -2.0, 0.5])
    R, t = G @ R, c @ G.T + g
    cyl = Cylinder(g, G @ np.array([0.0, 0.0, 1.0]), RADIUS)
    z = rng.uniform(-0.02, step * (n_frames - 1) + 0.3, n_points)
    phi = rng.uniform(-np.pi, np.pi, n_points)
    X = np.stack([RADIUS * np.cos(phi), RADIUS * np.sin(phi) + sag(z)[0], z], -1) @ G.T + g
    cams, pts, pix, used = tracked_runs(cam, R, t, X, rng, track, min_seen=2, min_colatitude_deg=25.0,
                                        max_range_m=None)
    X = X[used]
    pix = pix + rng.normal(0.0, noise_px, pix.shape)
    outlier = rng.random(len(pix)) < outlier_frac
    ang = rng.uniform(0, 2 * np.pi, outlier.sum())
    pix[outlier] += rng.uniform(5, 40, outlier.sum())[:, None] * np.stack([np.cos(ang), np.sin(ang)], -1)
    # Initial guess: the wrong scale about the first camera, plus perturbations; the first pose is exact.
    R0 = R @ exp_so3(rng.normal(0, np.radians(0.3), (n_frames, 3)))
    t0 = t[0] + scale0 * (t - t[0]) + rng.normal(0, 0.002, t.shape)
    R0[0], t0[0] = R[0], t[0]
    X0 = t[0] + scale0 * (X - t[0]) + rng.normal(0, 0.003, X.shape)
    return PipeWindow(cam, cyl, R, t, X, cams, pts, pix, outlier, R0, t0, X0)
