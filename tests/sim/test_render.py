"""Rendered frames: texture where the geometry says, bright wall around a dark far end, tees,
black outside the image circle, seeded noise."""

import cv2
import numpy as np
import pytest

from pipemap.sim.lighting import shade
from pipemap.sim.presets import fisheye_camera, perspective_camera
from pipemap.sim.render import Appearance, Renderer, frame_rng
from pipemap.sim.simulate import plan

EXPOSURE = 400.0  # fixed, so that the expected grey level follows from radiance alone


@pytest.fixture(scope="module")
def straight_renderer(straight):
    cam = fisheye_camera(160, 120)
    return Renderer(straight, cam, Appearance(noise=False, exposure=EXPOSURE), seed=2)


def pose_in(straight, x=1.0):
    from pipemap.geometry.rotations import look_rotation

    return look_rotation(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])), np.array([x, 0.01, -0.04])


def test_pixel_centres_see_points_that_project_back(straight_renderer, straight):
    r = straight_renderer
    R, t = pose_in(straight)
    P, N, h, s, hits = r.surface_points(R, t)
    assert hits.hit.all()
    uv, ok = r.camera.project(P.T.astype(float))
    grid = np.stack(np.unravel_index(r.pixels.index, r.pixels.valid.shape)[::-1], -1)
    assert np.abs(uv - grid).max() < 0.01  # px (float32 geometry)


def expected_grey(r: Renderer, straight, R, t, h, phi):
    """Grey level of wall points given by (h along the first piece, phi), computed directly
    from the wall texture, the LEDs and the sensor, without ray casting."""
    pipe = straight.pipes[0]
    e1, e2 = pipe.frame
    radial = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    X = pipe.start + h[:, None] * pipe.axis + straight.radius * radial
    Pc = (X - t) @ R
    Nc = -(radial @ R)
    uv, ok = r.camera.project(Pc)
    dist = np.linalg.norm(Pc, axis=1)
    cos_inc = np.abs(np.sum(Nc * Pc, axis=1)) / dist
    ang = 1.0 / r.camera.params[0]  # pixel angle ~ 1 / k1: the footprint only picks the mip level
    albedo = r.surfaces[0].sample(h + pipe.extend_start, phi * straight.radius, dist * ang / np.maximum(cos_inc, 0.1))
    rad = shade(albedo, Pc, Nc, r.leds, r.appearance.specular_strength, r.appearance.ambient)
    theta = r.camera.colatitude(Pc)
    grey = rad * r.appearance.sensor(EXPOSURE).vignetting_factor(theta) * EXPOSURE / r.appearance.full_well * 255
    return uv, ok, np.clip(grey, 0, 255)


def test_wall_points_show_the_expected_texture_and_light(straight_renderer, straight):
    """Pixels at the projections of known wall points match the albedo-lit expectation.

    Tolerance: the image is sampled at pixel centres and interpolated bilinearly to the
    projection, so texture detail finer than a pixel spreads the values; the median error stays
    below 3 grey levels, and the same check against the wrong wall position fails clearly."""
    r = straight_renderer
    R, t = pose_in(straight)
    img = r.render((R, t), frame_rng(0, 0)).astype(np.float32)
    rng = np.random.default_rng(1)
    h = rng.uniform(1.3, 1.9, 400)
    phi = rng.uniform(-np.pi, np.pi, 400)
    uv, ok, grey = expected_grey(r, straight, R, t, h, phi)
    uv, grey = uv[ok], grey[ok]
    inside = (uv[:, 0] > 1) & (uv[:, 0] < 158) & (uv[:, 1] > 1) & (uv[:, 1] < 118)
    uv, grey = uv[inside], grey[inside]
    seen = cv2.remap(img, uv[:, 0:1].astype(np.float32), uv[:, 1:2].astype(np.float32), cv2.INTER_LINEAR)[:, 0]
    err = np.abs(seen - grey)
    assert len(err) > 200
    assert np.median(err) < 3.0 and np.percentile(err, 90) < 12.0
    # teeth: the texture 3 cm further round the wall does not match
    _, _, wrong = expected_grey(r, straight, R, t, h, phi + 0.15)
    wrong = wrong[ok][inside]
    assert np.median(np.abs(seen - wrong)) > 2 * np.median(err)


def test_straight_fisheye_frame_dark_centre_bright_ring(fisheye_dataset):
    img = cv2.imread(str(fisheye_dataset / "images" / "000010.png"), cv2.IMREAD_UNCHANGED).astype(float)
    cam = fisheye_camera(160, 120)
    v, u = np.mgrid[0:120, 0:160]
    rr = np.hypot(u - cam.params[4], v - cam.params[5])
    circle = cam.params[0] * np.radians(95)  # ~ image-circle radius
    centre = img[rr < 0.08 * circle].mean()
    ring = img[(rr > 0.55 * circle) & (rr < 0.85 * circle)].mean()
    assert centre < 0.2 * ring and ring > 60
    assert img[0, 0] == 0 and img[-1, -1] == 0  # outside the image circle


def test_tee_frame_sees_the_branch():
    p = plan("demo-loop", width=160, height=120, seed=0)
    scene = p.setup.scene
    r = Renderer(scene, p.setup.camera, Appearance(noise=False), seed=0)
    t1 = scene.junctions[0].centroid  # T1: the route turns here from S4 into S1 (the branch)
    k = int(np.argmax(np.linalg.norm(p.trajectory.positions - t1, axis=1) < 0.35))  # approaching T1
    hits = r.trace(p.trajectory.rotations[k], p.trajectory.positions[k])
    ids = np.array([q.id for q in scene.pipes])[hits.pipe]
    assert np.mean(np.char.startswith(ids, "S1")) > 0.03  # the branch through its opening
    assert np.mean(ids == "B1") > 0.01  # the closed stub straight ahead


def test_noise_is_seeded_per_frame(straight):
    cam = fisheye_camera(160, 120)
    r = Renderer(straight, cam, Appearance(), seed=0)
    pose = pose_in(straight)
    a = r.render(pose, frame_rng(7, 3))
    b = r.render(pose, frame_rng(7, 3))
    c = r.render(pose, frame_rng(8, 3))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.abs(a.astype(int) - c).mean() < 3  # only the noise differs


def test_perspective_camera_keeps_its_field_of_view_when_scaled():
    for w, h in ((1024, 768), (160, 120)):
        cam = perspective_camera(1024, 768, 70.0, -0.12, 0.02, w, h)
        b, ok = cam.unproject(np.array([[-0.5, (h - 1) / 2], [w - 0.5, (h - 1) / 2]]))
        assert abs(np.degrees(np.arccos(b[0] @ b[1])) - 70.0) < 0.05
    big, small = fisheye_camera(), fisheye_camera(640, 480)
    assert small.params[0] == pytest.approx(big.params[0] / 2) and small.max_theta_deg == 95
