"""The camera's mount in the pipe (straight/mount.py): its geometry on exact data, then the estimate on a
seeded render of a wall camera turned 40 deg from square against the simulator's truth, and the dense
methods turned square to the wall by it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipemap.config import Settings
from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.evaluation.evaluate import evaluate
from pipemap.geometry.rotations import exp_so3
from pipemap.sim.simulate import simulate
from pipemap.straight.dense import estimate_shifts, run_dense
from pipemap.straight.mount import estimate_mount
from pipemap.straight.registration import adaptive_full_search
from pipemap.straight.scale import pixels_per_metre, wall_depth
from pipemap.straight.sparse.batch import mount_of
from pipemap.straight.sparse.geometry import R0, rotation_from_travel, wall_points
from pipemap.straight.undistort import Rectifier

TO_PIPE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # simulator world (x along, z up) -> (X, Y, h)


def _turned(mount_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    a, r = np.radians(90.0 - mount_deg), np.radians(roll_deg)
    return rotation_from_travel(np.array([np.cos(a) * np.cos(r), np.cos(a) * np.sin(r), np.sin(a)]))


# --- geometry -------------------------------------------------------------------------------------------


def test_rotation_from_travel_gives_the_mount():
    np.testing.assert_allclose(rotation_from_travel(np.array([1.0, 0.0, 0.0])), R0, atol=1e-12)
    for angle, roll in ((50.0, 0.0), (75.0, 3.0), (90.0, -2.0)):
        R = _turned(angle, roll)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        m = mount_of(R, np.array([0.01, -0.02, 0.0]))
        assert np.degrees(m[0]) == pytest.approx(angle) and np.degrees(m[1]) == pytest.approx(roll)
        assert R[:, 2] @ np.array([1.0, 0.0, 0.0]) == pytest.approx(0.0, abs=1e-12)  # looks towards +Y, not X
    with pytest.raises(ValueError, match="along the pipe"):
        rotation_from_travel(np.array([0.0, 0.0, 1.0]))


def test_mount_does_not_depend_on_where_round_the_pipe_the_robot_rides():
    R, C = _turned(60.0, 1.0), np.array([-0.03, -0.04, 0.2])
    turn = exp_so3(np.array([0.0, 0.0, 0.7]))  # about the pipe axis
    np.testing.assert_allclose(mount_of(turn @ R, turn @ C), mount_of(R, C), atol=1e-12)


def test_square_view_of_a_square_camera_is_the_undistorted_image(tmp_path):
    ds = simulate("wall-camera-90", tmp_path / "w", width=160, height=120, frames=1, seed=0)
    cam = load_dataset(ds).camera
    plain, square = Rectifier(cam, 0.5), Rectifier(cam, 0.5, mount=R0)
    np.testing.assert_allclose(square.K, plain.K, atol=1e-9)
    assert square.size == plain.size


def test_turned_view_moves_along_x_only_and_as_zeta_says():
    """Rays of the view turned square to the wall meet the wall at a depth that depends on the row alone, so a
    move along the axis shifts every pixel of a row by the same f dh / z(row) along x (scale.py)."""
    from pipemap.camera import PinholeCamera

    cam = PinholeCamera(320, 240, dict(fx=241.0, fy=241.0, cx=159.5, cy=119.5, k1=-0.12, k2=0.02, p1=0, p2=0, k3=0))
    radius, C = 0.19378, np.array([-0.03, -0.04, 0.0])
    rect = Rectifier(cam, 1.0, mount=_turned(50.0))
    K, f = rect.K, rect.focal_px
    v, u = np.mgrid[10:rect.size[1] - 10:20, 10:rect.size[0] - 10:20].astype(float)
    rays = np.stack([(u.ravel() - K[0, 2]) / f, (v.ravel() - K[1, 2]) / f, np.ones(u.size)], axis=-1)
    X, ok = wall_points(R0, C, rays / np.linalg.norm(rays, axis=1, keepdims=True), radius)  # the virtual camera
    dh = 1e-3
    moved = (X - C - dh * np.array([0.0, 0.0, 1.0])) @ R0
    du = f * moved[:, 0] / moved[:, 2] + K[0, 2] - u.ravel()
    dv = f * moved[:, 1] / moved[:, 2] + K[1, 2] - v.ravel()
    assert ok.all() and np.abs(dv).max() < 1e-9
    expect = -f * dh / wall_depth((v.ravel() - K[1, 2]) / f, radius, C[1], C[0])
    np.testing.assert_allclose(du, expect, rtol=1e-9)
    rows = (int(K[1, 2]) - 5, int(K[1, 2]) + 5)
    assert pixels_per_metre(f, K[1, 2], radius, C[1], rows, C[0]) == pytest.approx(
        np.mean(f / wall_depth((np.arange(*rows) - K[1, 2]) / f, radius, C[1], C[0])))


def test_rows_resampled_to_the_wall_move_alike():
    """With the wall's depth per row, every row of the turned view is resampled so that neighbouring pixels of any
    row are the same axial distance z_ref / f apart on the wall (followed through the maps, the lens and the wall),
    where the plain view's rows differ by 7 % across the band."""
    import cv2

    from pipemap.camera import PinholeCamera

    cam = PinholeCamera(320, 240, dict(fx=241.0, fy=241.0, cx=159.5, cy=119.5, k1=-0.12, k2=0.02, p1=0, p2=0, k3=0))
    radius, C = 0.19378, np.array([-0.03, -0.04, 0.0])

    def spacing(rect):  # axial distance on the wall between neighbouring pixels of each row, every 10th row
        mx, my = (m[5:-5:10, 20:-20] for m in rect.maps)
        src = np.stack([mx.ravel(), my.ravel()], axis=-1).reshape(-1, 1, 2).astype(np.float64)
        K = np.array([[241.0, 0, 159.5], [0, 241.0, 119.5], [0, 0, 1]])  # scale 1: the camera itself
        xy = cv2.undistortPoints(src, K, rect.dist).reshape(-1, 2)
        rays = np.column_stack([xy, np.ones(len(xy))]) @ rect.rotation.T
        X, ok = wall_points(R0, C, rays / np.linalg.norm(rays, axis=1, keepdims=True), radius)
        assert ok.all()
        return np.diff((X[:, 2]).reshape(mx.shape), axis=1)

    depth = lambda v: wall_depth(v, radius, C[1], C[0])  # noqa: E731
    rect = Rectifier(cam, 1.0, mount=_turned(50.0), row_depth=depth)
    h = rect.size[1]
    z_ref = depth(np.array([((h - 1) / 2 - rect.K[1, 2]) / rect.focal_px]))[0]
    step = spacing(rect)
    np.testing.assert_allclose(step.mean(axis=1), z_ref / rect.focal_px, rtol=2e-5)
    np.testing.assert_allclose(step, z_ref / rect.focal_px, rtol=1e-3)  # float32 maps
    assert np.ptp(rect.row_gain) > 0.1  # the rows moved up to 17 % apart
    plain = spacing(Rectifier(cam, 1.0, mount=_turned(50.0)))
    assert np.ptp(plain.mean(axis=1)) / plain.mean() > 0.07


def test_full_search_widens_its_range_to_the_motion():
    rng = np.random.default_rng(3)
    import cv2

    big = cv2.GaussianBlur(rng.uniform(0, 255, (200, 400)).astype(np.float32), (0, 0), 2.0)
    I0, I1 = big[40:160, 100:260], big[40:160, 60:220]  # the content moved 40 px right
    s = adaptive_full_search(I0, I1, search=(4, 2), prior=(0, 0))
    np.testing.assert_array_equal(s.t, (40.0, 0.0))
    # a sequence whose shift grows far beyond the starting range registers at the default settings
    frames = [big[40:160, 200 - 9 * k:360 - 9 * k] for k in range(6)] + [big[40:160, 100:260]]
    shifts, _ = estimate_shifts(frames, "dense-full-search", Settings().dense, (30, 90))
    assert np.all(np.isfinite(shifts)) and shifts.sum(axis=0)[0] == pytest.approx(100.0)


# --- the estimate on a render ---------------------------------------------------------------------------




def test_mount_of_an_oblique_camera_matches_the_truth(oblique_wall, oblique_dense):
    """50 deg from the pipe axis, 3 cm beside and 4 cm below it, at 480x360 over 1 m: the angle and roll within
    0.2 deg and the offset within 1 mm of the truth averaged over the same keyframes, each error within three
    of its stated sigmas (plus a floor). Started square to the wall, the report's batch finds 55 deg and an
    offset 60 mm off."""
    out, res = oblique_dense
    m = res.mount
    gt = load_dataset(oblique_wall).ground_truth_poses()
    truth = np.mean([mount_of(TO_PIPE @ gt.rotations[i], gt.positions[i] @ TO_PIPE.T) for i in m.keyframes], axis=0)
    err = np.array([m.angle_deg - np.degrees(truth[0]), m.roll_deg - np.degrees(truth[1]),
                    m.offset_m[0] - truth[2], m.offset_m[1] - truth[3]])
    assert m.determined and m.source in ("batch", "long bundle") and len(m.keyframes) >= 10
    assert np.all(np.abs(err[:2]) < 0.2) and np.all(np.abs(err[2:]) < 1e-3), err
    floor = np.array([0.02, 0.05, 1e-4, 1e-4])
    assert m.sigma is not None and np.all(np.abs(err) < 3 * m.sigma + floor), (err, m.sigma)
    block = json.loads((out / "run.json").read_text())["mount"]
    assert block["angle_to_axis_deg"] == pytest.approx(m.angle_deg)
    assert block["C_Y_sigma_m"] == pytest.approx(m.sigma[3])
    assert block["keyframes"] == list(m.keyframes) and block["source"] == m.source


def test_dense_run_turned_square_by_the_mount(oblique_wall, oblique_dense, tmp_path):
    """The mount turns every frame square to the wall and its offset gives zeta: 1 m within 0.5 %. The report's
    square camera on the same frames, with the offset given, is far off: the oblique view is no translation."""
    out, res = oblique_dense
    run = json.loads((out / "run.json").read_text())
    assert run["scale_source"] == "estimated mount"
    assert run["seconds"]["mount"] > 0 and run["seconds"]["mount"] == pytest.approx(res.seconds["mount"], abs=1e-3)
    assert run["rectified_by"] in ("the estimated mount", "the mean pipe axis of the offset stations (turning to it "
                                   "changed the scale by more than dense.rerectify_min_pct)")
    d = evaluate(out, oblique_wall, write=False).distance.forward
    assert d.ground_truth > 0.9 and d.abs_error_pct < 0.5, d
    square = Settings()
    square.sparse.offset_long_keyframes = 40  # as the oblique_dense fixture's run
    square.dense.mount = "square"
    square.dense.camera_offset_m = -0.04
    run_dense(oblique_wall, tmp_path / "square", square, "dense-hybrid")
    assert evaluate(tmp_path / "square", oblique_wall, write=False).distance.forward.abs_error_pct > 5


def test_a_camera_that_sees_no_texture_is_a_clear_error(tmp_path):
    ds = simulate("white-card", tmp_path / "card", width=64, height=48, seed=0)
    with pytest.raises(PipemapError, match="mount cannot be estimated") as err:
        estimate_mount(load_dataset(ds), Settings())
    assert "\n" not in str(err.value) and "dataset.yaml" in str(err.value)


def test_the_wall_view_is_judged_by_the_bundle_fit_not_the_long_batch(tmp_path):
    """The long batch (eqs. 45-49) holds every keyframe at one rotation, so its RMS also holds the crawler's
    wobble (3.5 px on the 6-inch pipe at the report's frame density, whose bundle batch fits within 1 px): a
    recording is refused only when the bundle batch itself cannot fit it."""
    import dataclasses
    from types import SimpleNamespace

    from pipemap.straight.mount import Mount, require_wall_view

    mount = Mount(np.eye(3), 90.0, 0.0, np.array([0.0, -0.025]), None, False, "long batch", (0, 1), 100, rms_px=3.5,
                  observations=1000, fit_rms_px=0.6)
    require_wall_view(SimpleNamespace(yaml_path=tmp_path / "dataset.yaml"), Settings(), mount)  # not refused
    misfit = dataclasses.replace(mount, fit_rms_px=3.5)
    ds = load_dataset(simulate("wall-camera-90", tmp_path / "w", width=96, height=72, frames=4, seed=1))
    with pytest.raises(PipemapError, match=r"does not fit these images \(mount batch reprojection RMS 3.5 px"):
        require_wall_view(ds, Settings(), misfit)
