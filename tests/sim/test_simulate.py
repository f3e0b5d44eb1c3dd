"""Dataset folders per spec/formats.md, atomic writing, and the ground-truth trajectories."""

import hashlib

import cv2
import numpy as np
import pytest
import yaml

from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.network import load_network
from pipemap.sim.presets import TABLE_I, list_presets, table_i_corners
from pipemap.sim.simulate import plan, simulate
from pipemap.trajectory import read_tum


def test_dataset_folder_follows_the_format(fisheye_dataset):
    doc = yaml.safe_load((fisheye_dataset / "dataset.yaml").read_text())
    assert set(doc) == {"format", "name", "images", "fps", "camera", "pipe"}
    assert doc["format"] == "pipemap-dataset/1" and doc["images"] == "images/*.png" and doc["fps"] == 7.5
    assert doc["camera"]["model"] == "polynomial" and doc["camera"]["max_theta_deg"] == 95
    assert doc["pipe"] == {"radius_m": 0.2}
    ds = load_dataset(fisheye_dataset)
    assert len(ds) == 30 and (ds.camera.width, ds.camera.height) == (160, 120)
    img = cv2.imread(str(fisheye_dataset / "images" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.shape == (120, 160)
    gt = read_tum(fisheye_dataset / "ground_truth" / "poses.tum")
    assert len(gt) == len(ds)
    np.testing.assert_allclose(gt.timestamps, np.arange(30) / 7.5, atol=1e-6)
    net = load_network(fisheye_dataset / "ground_truth" / "network.yaml")
    assert net.radius_m == 0.2 and len(net.segments) == 3 and net.visits == ()


def test_poses_stay_inside_the_pipe_at_the_configured_spacing():
    for preset, route in (("demo-loop", "A"), ("demo-loop", "B"), ("paper-loop", "A"), ("fisheye-straight", "forward")):
        p = plan(preset, route=route, seed=1)
        scene = p.setup.scene
        pos = p.trajectory.positions
        assert scene.axis_distance(pos).max() < scene.radius - 0.1  # camera ~4 cm below the axis
        assert scene.contains(pos).all()
        step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
        spacing = p.setup.drive.spacing_m
        assert abs(np.median(step) / spacing - 1) < 0.1
        assert step.max() < spacing * 1.3
        # the camera looks along the way it drives
        z = p.trajectory.rotations[:-1, :, 2]
        assert np.all(np.einsum("ni,ni->n", z, np.diff(pos, axis=0)) > 0)


def test_routes_visit_the_tees_in_order():
    assert plan("demo-loop", route="A").visits == ["T1", "T2", "T3", "T4"]
    assert plan("demo-loop", route="B").visits == ["T4", "T3", "T2", "T1", "T4"]
    assert plan("paper-loop", route="B").visits == ["T4", "T3", "T2", "T1", "T4"]
    assert plan("demo-loop", route="A", frames=40).visits == []  # not yet at T1


def test_paper_loop_matches_table_i():
    c = {f"T{k + 1}": x for k, x in enumerate(table_i_corners())}
    for (a, b), d in TABLE_I.items():
        assert abs(np.linalg.norm(c[a] - c[b]) - d) / d < 0.003
    p = plan("paper-loop", frames=3)
    assert p.setup.camera.width == 1280 and p.setup.camera.params[0] == 290.0 and p.setup.fps == 7.5


def test_fewer_frames_keep_the_start_of_the_route():
    full = plan("demo-loop", route="A", seed=2)
    short = plan("demo-loop", route="A", seed=2, frames=25, width=160, height=120)
    np.testing.assert_allclose(short.trajectory.positions, full.trajectory.positions[:25])
    assert short.setup.camera.width == 160


def test_forward_reverse_drives_back_facing_forward():
    p = plan("paper-straight-16in", route="forward-reverse", seed=0)
    x = p.trajectory.positions[:, 0]
    turn = int(np.argmax(x))
    assert 0.2 * len(x) < turn < 0.8 * len(x)
    assert x[-1] - x[0] < 0.01 and x[turn] - x[0] == pytest.approx(3.391, abs=0.01)
    assert abs(len(x) - 2392) < 30  # the report's image count
    # camera x (image columns) runs along the pipe and z looks up at the wall, both ways
    R = p.trajectory.rotations
    assert np.all(R[:, 0, 0] > 0.99) and np.all(R[:, 2, 2] > 0.99)


def test_a_recheck_backs_up_and_drives_on_before_it_comes_back_out():
    p = plan("fisheye-straight", route="recheck", seed=1, width=160, height=120)
    s = (p.trajectory.positions - p.trajectory.positions[0]) @ np.array([1.0, 0.0, 0.0])
    turns = np.flatnonzero(np.diff(np.sign(np.diff(s[np.r_[True, np.diff(s) != 0]]))))
    assert len(turns) == 3  # in, back, on, out
    assert s.max() == pytest.approx(4.5, abs=1e-3) and abs(s[-1]) < 1e-3  # the pipe sags a little
    way = s[np.r_[True, np.diff(s) != 0]]
    assert np.allclose(way[turns + 1], [2.5, 1.5, 4.5], atol=1e-3)
    R = p.trajectory.rotations  # facing the same way throughout
    assert np.all(R[:, :, 2] @ np.array([1.0, 0.0, 0.0]) > 0.99)


def test_same_seed_same_bytes_other_seed_other_noise(tmp_path):
    def digest(folder):
        return [hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted((folder / "images").glob("*.png"))]

    a = simulate("demo-loop", tmp_path / "a", width=96, height=72, frames=3, seed=5)
    b = simulate("demo-loop", tmp_path / "b", width=96, height=72, frames=3, seed=5)
    c = simulate("demo-loop", tmp_path / "c", width=96, height=72, frames=3, seed=6)
    assert digest(a) == digest(b)
    assert digest(a) != digest(c)
    assert (a / "ground_truth" / "poses.tum").read_text() == (b / "ground_truth" / "poses.tum").read_text()


def test_atomic_write_refuses_and_cleans_up(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    with pytest.raises(PipemapError, match="not empty"):
        simulate("demo-loop", out, width=64, height=48, frames=2)
    assert (out / "keep.txt").read_text() == "x"

    def boom(i, n):
        if i == 2:
            raise RuntimeError("interrupted")

    fresh = tmp_path / "fresh"
    with pytest.raises(RuntimeError):
        simulate("demo-loop", fresh, width=64, height=48, frames=5, progress=boom)
    assert not fresh.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # no partial folder left behind
    empty = tmp_path / "empty"
    empty.mkdir()
    assert (simulate("demo-loop", empty, width=64, height=48, frames=2) / "dataset.yaml").exists()


def test_bad_requests_are_one_line_errors(tmp_path):
    with pytest.raises(PipemapError, match="unknown preset"):
        simulate("nope", tmp_path / "x")
    with pytest.raises(PipemapError, match="no route"):
        simulate("demo-loop", tmp_path / "x", route="C")
    with pytest.raises(PipemapError, match="frames"):
        simulate("demo-loop", tmp_path / "x", frames=0)
    with pytest.raises(PipemapError, match="width"):
        simulate("demo-loop", tmp_path / "x", width=4)
    assert not (tmp_path / "x").exists()
    assert {"paper-loop", "paper-straight-6in", "paper-straight-16in", "fisheye-straight", "demo-loop",
            "white-card"} <= set(list_presets())


def test_white_card_writes_a_gain_mask(tmp_path):
    out = simulate("white-card", tmp_path / "card", width=128, height=96, frames=4)
    doc = yaml.safe_load((out / "dataset.yaml").read_text())
    assert doc["gain_mask"] == "gain_mask.png"
    mask = cv2.imread(str(out / "gain_mask.png"), cv2.IMREAD_UNCHANGED)
    assert mask.dtype == np.uint16 and mask.shape == (96, 128) and mask.max() == 65535
    mean = np.mean([cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(float)
                    for f in sorted((out / "images").glob("*.png"))], 0)
    assert np.corrcoef(mask.ravel(), cv2.GaussianBlur(mean, (0, 0), 2).ravel())[0, 1] > 0.9
    ds = load_dataset(out)
    assert ds.has_gain_mask and len(ds) == 4


def test_perspective_dataset(six_inch_dataset):
    ds = load_dataset(six_inch_dataset)
    assert ds.camera.model == "pinhole" and ds.fps == 7.5 and ds.radius_m == pytest.approx(0.07666)
    gt = ds.ground_truth_poses()
    step = np.linalg.norm(np.diff(gt.positions, axis=0), axis=1)
    assert 0.0005 < np.median(step) < 0.002  # the report's ~1.4 mm per frame
    img = ds.read(5).image
    assert img.std() > 5 and img.mean() > 40  # a lit, textured wall fills the frame


@pytest.mark.parametrize("preset, mount", [("wall-camera-90", 90.0), ("wall-camera-75", 75.0),
                                           ("wall-camera-50", 50.0), ("cctv-straight", 0.0)])
def test_camera_mounts_and_wobble(preset, mount):
    p = plan(preset, frames=300, seed=1)
    pos, tan = p.path.evaluate(p.s)
    axis_angle = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", p.trajectory.rotations[:, :, 2], tan), -1, 1)))
    # the optical axis at the mount angle to the pipe axis; the robot rolls and pitches up to 1 deg about each axis
    assert abs(np.median(axis_angle) - mount) < 0.5
    assert np.max(np.abs(axis_angle - mount)) < 1.8
    assert np.max(np.abs(axis_angle - mount)) > 0.3  # it does wobble
    off = p.trajectory.positions - pos
    side, down = (0.03, 0.04) if preset.startswith("wall") else (0.0, 0.04)
    assert np.allclose(np.median(np.abs(off), axis=0), [0.0, side, down], atol=0.003)
