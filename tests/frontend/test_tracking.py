"""The streaming front end on small renders, judged against ground truth by pipemap.evaluation.tracking."""

import json
import shutil

import cv2
import numpy as np
import pytest
from conftest import SIM_STRAIGHT, SIM_TEE, sim_wall_for

from pipemap.evaluation.tracking import evaluate_tracking, raycast_network

from pipemap.config import Settings
from pipemap.dataset import Frame
from pipemap.errors import PipemapError
from pipemap.frontend import FeatureTracker, read_frames_csv, read_tracks_csv, run_tracking, track_frames
from pipemap.frontend.flow_tracker import FlowTracker
from pipemap.frontend.guided import guided_zncc, predict_positions
from pipemap.frontend.harris import bearing_map, detect_corners, valid_mask
from pipemap.frontend.relpose import essential_from_pose
from pipemap.network import PipeNetwork, Segment
from pipemap.trajectory import read_tum


def true_pixels(scene, i, j, pixels):
    """Pixels of image i ray-cast into the true pipe and projected into image j."""
    network = PipeNetwork(scene.radius, (Segment("S1", np.zeros(3), np.array([0.0, 0.0, 20.0])),))
    bearings, _ = scene.camera.unproject(pixels)
    points, hit = raycast_network(network, scene.centres[i], bearings @ scene.rotations[i].T)
    px, valid = scene.camera.project((points - scene.centres[j]) @ scene.rotations[j])
    return px, hit & valid


def test_guided_zncc_finds_features_on_their_epipolar_region(pipe_scene):
    cam, (i, j) = pipe_scene.camera, (0, 2)
    pts, _ = detect_corners(pipe_scene.images[i], valid_mask(cam, 16), (2, 2), 100)
    truth, ok = true_pixels(pipe_scene, i, j, pts)
    pts, truth = pts[ok], truth[ok]
    R = pipe_scene.rotations[j].T @ pipe_scene.rotations[i]
    t = pipe_scene.rotations[j].T @ (pipe_scene.centres[i] - pipe_scene.centres[j])
    E = essential_from_pose(R, t / np.linalg.norm(t))
    # Predict from every fourth feature's true motion, search the others.
    known = np.arange(len(pts)) % 4 == 0
    predicted = predict_positions(pts[~known], pts[known], truth[known])
    bmap, valid = bearing_map(cam)
    bearings = cam.unproject(pts[~known])[0]
    found, pos, score = guided_zncc(pipe_scene.images[i], pipe_scene.images[j], pts[~known], bearings,
                                    predicted, E, bmap, valid, search_px=8)
    assert found.mean() > 0.6
    err = np.linalg.norm(pos[found] - truth[~known][found], axis=1)
    assert np.mean(err < 1.0) > 0.9 and np.median(err) < 0.4
    assert np.all(score[found] >= 0.8)
    # A wrong epipolar geometry excludes the true match from the search region.
    wrong = essential_from_pose(np.eye(3), np.array([1.0, 0.0, 0.0]))
    found_w, pos_w, _ = guided_zncc(pipe_scene.images[i], pipe_scene.images[j], pts[~known], bearings,
                                    predicted, wrong, bmap, valid, search_px=8)
    right = np.linalg.norm(pos_w[found_w] - truth[~known][found_w], axis=1) < 1.0
    assert right.sum() < 0.2 * found.sum()


@pytest.fixture(scope="session")
def tracked(pipe_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("track") / "out"
    result = run_tracking(pipe_dataset, out)
    return out, result


def test_tracking_keeps_a_simple_synthetic_pipe(tracked, pipe_dataset):
    # A smooth blob texture at 320 x 240, ray-cast by the tests themselves: a coarse check
    # that does not depend on the simulator.
    out, _ = tracked
    figures = evaluate_tracking(out, pipe_dataset)
    assert figures["rotation_error_deg_median"] < 0.5
    assert figures["direction_error_deg_median"] < 2.0
    assert figures["true_correspondence_fraction"] > 0.9
    assert figures["keyframe_gap_max"] <= 3 * figures["keyframe_gap_median"]


def _settings(tracking: str, anchor_lighting: str = "flattened") -> Settings:
    s = Settings()
    return s.model_copy(update={"frontend": s.frontend.model_copy(update={"tracking": tracking,
                                                                          "anchor_lighting": anchor_lighting})})


@pytest.mark.parametrize("tracking, lighting", [("flow", "flattened"), ("descriptors", "flattened"),
                                                ("flow", "quadratic"), ("flow", "plane"), ("descriptors", "quadratic")])
def test_accuracy_on_a_rendered_straight_pipe(sim_straight, tmp_path, tracking, lighting):
    out = tmp_path / "out"
    run_tracking(sim_straight, out, _settings(tracking, lighting))
    f = evaluate_tracking(out, sim_straight, wall=sim_wall_for(SIM_STRAIGHT))
    # The acceptance targets are 0.1 deg, 2 deg, 90 %, 5 keyframes on longer renders
    # (benchmarks/bench_frontend.py); these bounds catch a bad regression on 30 frames. A track
    # ends where it no longer matches its first patch (anchor.py): fewer keyframes per track here
    # (3.97), almost no false ones (99.7 % true). Median rotation error on these frames: flattened image
    # 0.027 deg (flow), 0.032 (descriptors); log brightness (`frontend.anchor_lighting`) 0.012 (quadratic),
    # 0.023 (plane), 0.040 deg (descriptors, quadratic).
    assert f["rotation_error_deg_median"] < 0.05
    assert f["direction_error_deg_median"] < 0.4
    assert f["true_correspondence_fraction"] > 0.99
    assert f["mean_track_length_straight"] >= 3.5
    assert f["keyframe_gap_max"] <= 3 * f["keyframe_gap_median"] and f["lost_keyframes"] == 0


@pytest.mark.parametrize("tracking", ["flow", "descriptors"])
def test_tracking_through_a_tee(sim_tee, tmp_path, tracking):
    out = tmp_path / "out"
    run_tracking(sim_tee, out, _settings(tracking))
    f = evaluate_tracking(out, sim_tee, wall=sim_wall_for(SIM_TEE))
    assert f["lost_keyframes"] == 0
    # In metres: the robot accelerates over the first frames, which spreads keyframes over more images.
    assert f["keyframe_gap_m_max"] <= 3 * f["keyframe_gap_m_median"]
    assert f["rotation_error_deg_median"] < 0.15 and f["rotation_error_deg_p90"] < 0.5
    assert f["direction_error_deg_median"] < 1.5
    assert f["true_correspondence_fraction"] > 0.92


@pytest.mark.parametrize("tracking", ["flow", "descriptors"])
def test_saturated_frames_do_not_break_tracking(sim_straight, tmp_path, tracking):
    data = tmp_path / "glare"
    shutil.copytree(sim_straight, data)
    for i in (12, 13):
        path = data / "images" / f"{i:06d}.png"
        cv2.imwrite(str(path), np.full_like(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), 255))
    out = tmp_path / "out"
    run_tracking(data, out, _settings(tracking))
    frames = read_frames_csv(out / "frames.csv")
    assert not frames["keyframe"][12] and not frames["keyframe"][13]
    f = evaluate_tracking(out, data, wall=sim_wall_for(SIM_STRAIGHT))
    assert f["keyframe_gap_max"] <= 3 * f["keyframe_gap_median"] and f["lost_keyframes"] == 0
    assert f["rotation_error_deg_median"] < 0.15


def test_result_files_follow_the_formats(tracked, pipe_dataset):
    out, result = tracked
    frames = read_frames_csv(out / "frames.csv")
    assert list(frames["index"]) == list(range(40))
    assert set(frames["label"]) == {"straight"}
    keyframe_images = [k.index for k in result.keyframes]
    assert list(np.nonzero(frames["keyframe"])[0]) == keyframe_images
    traj = read_tum(out / "trajectory.tum")
    assert np.allclose(traj.timestamps * 10.0, keyframe_images)
    assert np.allclose(np.linalg.norm(np.diff(traj.positions, axis=0), axis=1), 1.0)  # unit steps
    tracks = read_tracks_csv(out / "tracks.csv")
    assert len(tracks["track_id"]) == sum(len(k) for k in result.keyframes)
    assert np.all(np.diff(tracks["keyframe"]) >= 0)
    run = json.loads((out / "run.json").read_text())
    assert run["frames"] == 40 and run["settings"]["frontend"]["corners_per_region"] == 200
    # A non-empty output folder is refused, not overwritten.
    with pytest.raises(PipemapError, match="not empty"):
        run_tracking(pipe_dataset, out)


def test_keyframes_are_consistent_and_tracking_is_deterministic(pipe_scene):
    frames = pipe_scene.frames()[:16]
    a = list(track_frames(frames, pipe_scene.camera, seed=3))
    b = list(track_frames(frames, pipe_scene.camera, seed=3))
    assert len(a) >= 3 and [k.index for k in a] == [k.index for k in b]
    for ka, kb in zip(a, b):
        assert np.array_equal(ka.keypoints, kb.keypoints) and np.array_equal(ka.R, kb.R)
    for prev, kf in zip(a, a[1:]):
        assert len(np.unique(kf.track_ids)) == len(kf)
        continued = np.isin(kf.track_ids, prev.track_ids)
        assert np.array_equal(continued, kf.inliers)  # a track continues exactly when matched as an inlier
        assert np.allclose(np.linalg.norm(kf.bearings, axis=1), 1.0) and kf.pose_valid
        assert abs(np.linalg.norm(kf.t) - 1.0) < 1e-9


@pytest.mark.parametrize("tracker", [FeatureTracker, FlowTracker])
def test_a_frame_with_nothing_to_track_yields_no_keyframe(pipe_scene, tracker):
    tracker = tracker(pipe_scene.camera)
    blank = Frame(0, 0.0, np.full((240, 320), 255.0, np.float32))
    assert tracker.process(blank) == [] and tracker.finish() == []



def test_no_corners_next_to_saturated_pixels(pipe_scene):
    """`frontend.saturation_level`: a glare patch's edge is set by the light, not by the wall; corners within half a
    ZNCC patch of it are not started (and followed features that reach it end at the next keyframe)."""
    frame = pipe_scene.frames()[3]
    image = frame.image.astype(np.float32).copy()
    h, w = image.shape
    image[h // 2 - 20:h // 2 + 20, w // 4 - 20:w // 4 + 20] = 255.0  # glare on the wall left of the centre
    glare = Frame(frame.index, frame.timestamp, image)
    near = {}
    for level in (None, 250.0):
        s = Settings()
        s = s.model_copy(update={"frontend": s.frontend.model_copy(update={"saturation_level": level})})
        tracker = FlowTracker(pipe_scene.camera, s.frontend)
        _, _, corners = tracker.corners(glare)
        margin = tracker.s.zncc_patch // 2 + 1
        d = np.maximum(np.abs(corners[:, 0] - (w // 4 - 0.5)) - 20, np.abs(corners[:, 1] - (h // 2 - 0.5)) - 20)
        near[level] = int(np.sum(d < margin))
        if level is not None:
            saturated = tracker.saturated(glare)
            assert saturated[h // 2, w // 4] and saturated[h // 2, w // 4 - 20 - margin + 1]
            assert not saturated[h // 2, w // 4 - 20 - margin - 2] and not saturated[h // 4, 3 * w // 4]
    assert near[None] > 0 and near[250.0] == 0
