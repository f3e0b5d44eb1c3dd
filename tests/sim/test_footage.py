"""Simulated inspection footage: video, overlays, gain, blur, interlacing, repeated and dropped frames,
each checked against the clean render of the same seed (small 160x120 renders)."""

import csv
import hashlib

import av
import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation, Slerp
from typer.testing import CliRunner

from pipemap.cli import app
from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.sim.capture import Capture
from pipemap.sim.effects import Gain, gain_curve, load_effects
from pipemap.sim.overlay import OverlayPainter
from pipemap.sim.render import Renderer
from pipemap.sim.simulate import plan, simulate
from pipemap.trajectory import read_tum

SIZE = dict(width=160, height=120)
N = 30
SEED = 3


def png(folder, k):
    return cv2.imread(str(folder / "images" / f"{k:06d}.png"), cv2.IMREAD_UNCHANGED)


def recording_csv(folder):
    return list(csv.DictReader((folder / "ground_truth" / "recording.csv").open()))


def psnr(a, b):
    return 10 * np.log10(255.0**2 / np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2))


def digest(folder):
    return {str(f.relative_to(folder)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(folder.rglob("*")) if f.is_file()}


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return simulate("fisheye-straight", tmp_path_factory.mktemp("fx") / "clean", frames=N, seed=SEED, **SIZE)


def render(tmp_path, name, effects, preset="fisheye-straight", **kw):
    return simulate(preset, tmp_path / name, frames=kw.pop("frames", N), seed=kw.pop("seed", SEED), effects=effects,
                    **SIZE, **kw)


def test_clean_effects_leave_the_dataset_byte_identical(tmp_path, clean):
    assert digest(render(tmp_path, "c", "clean")) == digest(clean)
    # a preset's default profile is only a default: "clean" renders the plain frames
    rec = simulate("cctv-recording", tmp_path / "rec", frames=3, seed=SEED, effects="clean", **SIZE)
    plain = simulate("cctv-straight", tmp_path / "plain", frames=3, seed=SEED, **SIZE)
    for k in range(3):
        assert png(rec, k).tobytes() == png(plain, k).tobytes()


# measured at 160x120, fisheye-straight seed 3, 30 frames: H.264 CRF 28 min 35.0 dB (median 36.7);
# MJPEG q 8 min 37.8 (38.1); MPEG-4 q 5 min 37.9 (38.3)
@pytest.mark.parametrize("video, pix_fmt, bound", [({"codec": "h264", "crf": 28}, "yuv420p", 33.0),
                                                   ({"codec": "mjpeg", "qscale": 8}, "yuvj420p", 35.5),
                                                   ({"codec": "mpeg4", "qscale": 5}, "yuv420p", 35.5)])
def test_video_decodes_to_the_written_frames_close_to_the_clean_ones(tmp_path, clean, video, pix_fmt, bound):
    out = render(tmp_path, "v", {"video": video, "link": {"drop_rate": 0.1}})
    doc = yaml.safe_load((out / "dataset.yaml").read_text())
    rows = recording_csv(out)
    assert len(rows) == N - 3  # round(0.1 * 29) slots dropped
    with av.open(str(out / doc["images"])) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == {"h264": "h264", "mjpeg": "mjpeg", "mpeg4": "mpeg4"}[video["codec"]]
        decoded = list(container.decode(video=0))
    assert len(decoded) == len(rows) == len(load_dataset(out))
    assert decoded[0].format.name == pix_fmt
    # presentation times are the slots: the dropped frames leave gaps, and the ground truth has the same times
    times = [float(r["time_s"]) for r in rows]
    np.testing.assert_allclose([f.time for f in decoded], times, atol=1e-3)
    np.testing.assert_allclose(read_tum(out / "ground_truth" / "poses.tum").timestamps, times, atol=1e-6)
    steps = np.diff(times) * 7.5
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-4)
    assert np.round(steps).sum() - len(steps) == 3  # one frame period more per dropped frame
    ds = load_dataset(out)
    ps = [psnr(frame.image, png(clean, int(row["capture_slot"]))) for frame, row in zip(ds.frames(), rows)]
    assert min(ps) > bound, ps


def test_overlay_pixels_are_where_said_and_static_text_is_identical(tmp_path, clean):
    fx = {"overlay": {"manhole": "MH1034 > MH1035"}}
    out = render(tmp_path, "o", fx)
    painter = OverlayPainter(load_effects(fx).overlay, **SIZE)
    inside = np.zeros((120, 160), bool)
    for x0, y0, x1, y1 in painter.boxes.values():
        inside[y0:y1, x0:x1] = True
    mask = cv2.imread(str(out / "ground_truth" / "overlay_mask.png"), cv2.IMREAD_UNCHANGED) > 0
    assert mask.any() and not (mask & ~inside).any()
    rows = recording_csv(out)
    manhole = None
    for row in rows:
        k = int(row["index"])
        got, want = png(out, k), png(clean, k).copy()
        drawn = painter.draw(want, float(row["distance_m"]), float(row["time_s"]))
        np.testing.assert_array_equal(got, want)  # the clean frame with exactly these texts burned in
        assert not (drawn & ~mask).any() and np.array_equal(got[~mask], png(clean, k)[~mask])
        x0, y0, x1, y1 = painter.boxes["manhole"]
        on = drawn[y0:y1, x0:x1]
        manhole = (on, got[y0:y1, x0:x1][on]) if manhole is None else manhole
        np.testing.assert_array_equal(on, manhole[0])
        np.testing.assert_array_equal(got[y0:y1, x0:x1][on], manhole[1])
    assert rows[-1]["distance_m"] != rows[0]["distance_m"]  # the counter runs


def test_gain_drift_and_steps_scale_the_intensity(tmp_path, clean):
    fx = {"gain": {"drift": [0.75, 1.3], "steps": [{"frame": 15, "factor": 1.25}]}}
    out = render(tmp_path, "g", fx)
    gains = np.array([float(r["gain"]) for r in recording_csv(out)])
    assert gains[:15].min() >= 0.75 - 1e-6 and gains.max() <= 1.3 * 1.25 + 1e-6
    ratios, saturated = [], []
    for k in range(N):
        a, b = png(clean, k).astype(float), png(out, k).astype(float)
        ok = (a > 20) & (a < 180) & (b < 250)  # lit, and unsaturated in both
        ratios.append(b[ok].mean() / a[ok].mean())
        saturated.append(np.mean(b >= 255) - np.mean(a >= 255))
    ratios = np.array(ratios)
    # fisheye-straight has gamma 1: grey levels scale with the gain (measured within 0.01 %, the same noise draws)
    np.testing.assert_allclose(ratios, gains, rtol=0.005)
    drift = gain_curve(Gain(drift=(0.75, 1.3)), N, SEED)
    assert drift.min() == pytest.approx(0.75) and drift.max() == pytest.approx(1.3)
    np.testing.assert_allclose(gains / drift, np.r_[np.ones(15), np.full(N - 15, 1.25)], rtol=1e-5)
    # gain acts before saturation: where it exceeds 1, more pixels clip at 255
    assert all(s > 0 for s, g in zip(saturated, gains) if g > 1.15)


def test_led_flicker_ripples_the_frame_mean(tmp_path, clean):
    out = render(tmp_path, "f", {"gain": {"flicker": 0.04, "flicker_period_frames": 3.0}}, frames=12)
    gains = np.array([float(r["gain"]) for r in recording_csv(out)])
    means = np.array([png(out, k).astype(float).mean() / png(clean, k).astype(float).mean() for k in range(12)])
    assert np.ptp(gains) > 0.06 and np.corrcoef(gains, means)[0, 1] > 0.99


def test_repeated_and_dropped_frames_keep_the_ground_truth_exact(tmp_path, clean):
    out = render(tmp_path, "l", {"link": {"repeat_rate": 0.2, "drop_rate": 0.1}})
    rows = recording_csv(out)
    gt, truth = read_tum(out / "ground_truth" / "poses.tum"), read_tum(clean / "ground_truth" / "poses.tum")
    record = yaml.safe_load((out / "ground_truth" / "simulation.yaml").read_text())
    assert (record["repeated_frames"], record["dropped_frames"]) == (6, 3)  # round(rate * 29)
    assert len(rows) == len(gt) == len(list((out / "images").glob("*.png"))) == N - 3
    slots = np.array([int(r["slot"]) for r in rows])
    shown = np.array([int(r["capture_slot"]) for r in rows])
    repeat = np.array([r["repeat"] == "1" for r in rows])
    dropped = np.array([int(r["dropped_before"]) for r in rows])
    assert repeat.sum() == 6 and dropped.sum() == 3
    # the recorder's clock: consecutive slots, except a gap of one frame per dropped slot; the ground truth and
    # the images' timestamps file (named in dataset.yaml) keep the gaps, a repeat has the time of its own slot
    np.testing.assert_array_equal(np.diff(slots), 1 + dropped[1:])
    np.testing.assert_allclose([float(r["time_s"]) for r in rows], slots / 7.5, atol=1e-6)
    np.testing.assert_allclose(gt.timestamps, slots / 7.5, atol=1e-6)
    assert yaml.safe_load((out / "dataset.yaml").read_text())["timestamps"] == "timestamps.txt"
    np.testing.assert_allclose(np.loadtxt(out / "timestamps.txt"), slots / 7.5, atol=1e-6)
    for k in range(len(rows)):
        if repeat[k]:  # a stalled link: the previous frame again, byte for byte, and its pose
            assert (out / f"images/{k:06d}.png").read_bytes() == (out / f"images/{k - 1:06d}.png").read_bytes()
            assert shown[k] == shown[k - 1] and slots[k] > shown[k]
        else:
            assert shown[k] == slots[k]
        # whatever was written is the clean frame of the slot it shows, posed as that slot
        assert (out / f"images/{k:06d}.png").read_bytes() == (clean / f"images/{shown[k]:06d}.png").read_bytes()
        np.testing.assert_array_equal(gt.positions[k], truth.positions[shown[k]])
        np.testing.assert_array_equal(gt.rotations[k], truth.rotations[shown[k]])


def test_same_seed_same_bytes_any_workers(tmp_path):
    a = render(tmp_path, "a", "cctv-h264", frames=12, workers=1)
    b = render(tmp_path, "b", "cctv-h264", frames=12, workers=2)
    c = render(tmp_path, "c", "cctv-h264", frames=12, workers=1, seed=SEED + 1)
    assert digest(a) == digest(b)
    assert digest(a)["video.mp4"] != digest(c)["video.mp4"]
    d = render(tmp_path, "d", {"profile": "cctv-h264", "seed": 11}, frames=12)
    assert (d / "ground_truth/recording.csv").read_text() != (a / "ground_truth/recording.csv").read_text()


@pytest.fixture(scope="module")
def cctv():
    """A fast CCTV run (3 cm per frame) without sensor noise, for the blur and field timing checks."""
    p = plan("cctv-straight", frames=12, seed=SEED, spacing_m=0.03, **SIZE)
    from dataclasses import replace

    renderer = Renderer(p.setup.scene, p.setup.camera, replace(p.setup.appearance, noise=False), seed=SEED)
    return p.trajectory, renderer


def pose_at(traj, j, tau):
    """The true pose `tau` frames after frame j (0 <= tau <= 1 or -1 <= tau <= 0)."""
    k = j + (1 if tau > 0 else -1)
    rot = Slerp([0, 1], Rotation.from_matrix(traj.rotations[[j, k]]))(abs(tau)).as_matrix()
    return rot, (1 - abs(tau)) * traj.positions[j] + abs(tau) * traj.positions[k]


def test_resampling_along_the_image_motion_predicts_the_wall_half_a_frame_on(cctv):
    traj, renderer = cctv
    capture = Capture(renderer, traj.rotations, traj.positions, load_effects({"shutter": 0.5}), np.ones(len(traj)))
    j = 5
    shading = renderer.shading(traj.rotations[j], traj.positions[j])
    albedo = shading.albedo_image()
    V = capture.velocity(j, shading.points, shading.hits.hit)
    assert np.percentile(np.hypot(V[..., 0], V[..., 1]), 99) > 5  # the wall streams several pixels per frame
    truth = renderer.shading(*pose_at(traj, j, 0.5)).albedo_image()
    moved = capture._sample(albedo, V, [0.5])
    wall = (truth > 0) & (albedo > 0)
    err_moved = np.sqrt(np.mean((moved - truth)[wall] ** 2))
    err_still = np.sqrt(np.mean((albedo - truth)[wall] ** 2))
    assert err_moved < 0.4 * err_still  # measured 0.013 vs 0.045 (albedo std 0.095)


def test_motion_blur_smears_along_the_image_motion_and_keeps_the_brightness(cctv, tmp_path):
    traj, renderer = cctv
    capture = Capture(renderer, traj.rotations, traj.positions, load_effects({"shutter": 1.0}), np.ones(len(traj)))
    j = 5
    shading = renderer.shading(traj.rotations[j], traj.positions[j])
    V = capture.velocity(j, shading.points, shading.hits.hit)
    x, y = np.meshgrid(np.arange(160) - 79.5, np.arange(120) - 59.5)
    r = np.hypot(x, y)
    outer = r > 40
    speed = np.hypot(V[..., 0], V[..., 1])
    # looking along the pipe, the wall streams radially out of the image centre
    assert np.median(((V[..., 0] * x + V[..., 1] * y) / np.maximum(speed * r, 1e-9))[outer]) > 0.99
    sharp = shading.albedo_image()
    blurred = capture.over_time(sharp, V)
    grads = []
    for img in (sharp, blurred):
        gx, gy = cv2.Sobel(img, cv2.CV_64F, 1, 0), cv2.Sobel(img, cv2.CV_64F, 0, 1)
        grads.append((np.abs(gx * x + gy * y)[outer] / r[outer], np.abs(gy * x - gx * y)[outer] / r[outer]))
    along = grads[1][0].mean() / grads[0][0].mean()
    across = grads[1][1].mean() / grads[0][1].mean()
    assert along < 0.8 and along < across - 0.05  # measured 0.72 along the motion, 0.82 across it
    kw = dict(preset="cctv-straight", frames=8, spacing_m=0.03)
    a, b = (png(render(tmp_path, name, fx, **kw), 4).astype(float)
            for name, fx in (("s", "clean"), ("b", {"shutter": 1.0})))
    assert b.mean() == pytest.approx(a.mean(), rel=0.01)


def test_interlaced_fields_are_a_quarter_frame_either_side_of_the_pose(cctv):
    traj, renderer = cctv
    capture = Capture(renderer, traj.rotations, traj.positions, load_effects({"interlace": True}), np.ones(len(traj)))
    j = 5
    shading = renderer.shading(traj.rotations[j], traj.positions[j])
    V = capture.velocity(j, shading.points, shading.hits.hit)
    frame = capture.over_time(shading.albedo_image(), V)
    early, late = (renderer.shading(*pose_at(traj, j, tau)).albedo_image() for tau in (-0.25, 0.25))
    wall = (early > 0) & (late > 0) & (frame > 0)
    for rows, near, far in ((slice(0, None, 2), early, late), (slice(1, None, 2), late, early)):
        m = wall[rows]
        err = [np.sqrt(np.mean((frame[rows] - x[rows])[m] ** 2)) for x in (near, far)]
        assert err[0] < 0.5 * err[1]  # measured 0.010-0.015 against 0.026-0.058


def test_interlaced_video_is_flagged_top_field_first(tmp_path):
    out = render(tmp_path, "i", {"profile": "pal-interlaced", "video": {"codec": "h264"}}, frames=4)
    with av.open(str(out / "video.mp4")) as container:
        assert container.streams.video[0].codec_context.field_order == 2  # AV_FIELD_TT
        assert next(container.decode(video=0)).interlaced_frame


def test_cli_camera_effects(tmp_path):
    runner = CliRunner()
    spec = tmp_path / "fx.yaml"
    spec.write_text("profile: cctv-mjpeg\nlink: {repeat_rate: 0.1}\n")
    r = runner.invoke(app, ["simulate", "fisheye-straight", "--out", str(tmp_path / "m"), "--width", "160",
                            "--height", "120", "--frames", "10", "--camera-effects", str(spec)])
    assert r.exit_code == 0, r.output
    assert "10 frames written" in r.output
    ds = load_dataset(tmp_path / "m")
    assert ds.video_path.name == "video.mov" and len(ds) == 10
    assert sum(row["repeat"] == "1" for row in recording_csv(tmp_path / "m")) == 1
    bad = runner.invoke(app, ["simulate", "fisheye-straight", "--out", str(tmp_path / "x"), "--camera-effects", "vhs"])
    assert bad.exit_code == 2 and "vhs" in bad.output and len(bad.output.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
    odd = runner.invoke(app, ["simulate", "fisheye-straight", "--out", str(tmp_path / "y"), "--width", "161",
                              "--height", "121", "--frames", "2", "--camera-effects", "cctv-h264"])
    assert odd.exit_code == 2 and "even width and height" in odd.output and not (tmp_path / "y").exists()


def test_calibration_preset_takes_no_effects(tmp_path):
    with pytest.raises(PipemapError, match="takes no camera effects"):
        simulate("calibration", tmp_path / "cal", effects="cctv-h264")
    with pytest.raises(PipemapError, match="motion_blur"):
        simulate("fisheye-straight", tmp_path / "mb", frames=2, motion_blur=2, effects="cctv-h264", **SIZE)
