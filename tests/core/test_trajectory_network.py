import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.geometry.rotations import exp_so3, log_so3, matrix_to_quat, quat_to_matrix
from pipemap.network import Junction, PipeNetwork, Segment, load_network, save_network
from pipemap.trajectory import Trajectory, read_tum, write_tum


def test_rotation_conversions_round_trip():
    rng = np.random.default_rng(0)
    w = rng.normal(size=(200, 3))
    w *= (rng.uniform(0, np.pi - 1e-6, 200) / np.linalg.norm(w, axis=1))[:, None]
    R = exp_so3(w)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(log_so3(R), w, atol=1e-9)
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(R)), R, atol=1e-12)


def test_tum_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    traj = Trajectory(np.arange(10) / 7.5, rng.normal(size=(10, 3)), exp_so3(rng.normal(size=(10, 3))))
    write_tum(tmp_path / "t.tum", traj)
    back = read_tum(tmp_path / "t.tum")
    np.testing.assert_allclose(back.timestamps, traj.timestamps, atol=1e-6)
    np.testing.assert_allclose(back.positions, traj.positions, atol=1e-8)
    np.testing.assert_allclose(back.rotations, traj.rotations, atol=1e-8)


@pytest.mark.parametrize("line, words", [("0 1 2 3 0 0 0", "expected 8"), ("0 1 2 x 0 0 0 1", "not a number"),
                                          ("0 1 2 3 0 0 0 2", "quaternion is not unit length")])
def test_bad_tum_lines(tmp_path, line, words):
    (tmp_path / "t.tum").write_text("# header\n" + line + "\n")
    with pytest.raises(PipemapError, match=f"t.tum: line 2: {words}"):
        read_tum(tmp_path / "t.tum")


def test_network_round_trip_and_errors(tmp_path):
    net = PipeNetwork(0.2, (Segment("S1", np.zeros(3), np.array([8.15, 0, 0])),),
                      (Junction("T1", "tee", np.array([8.15, 0, 0])),), ("T1",))
    save_network(tmp_path / "n.yaml", net)
    back = load_network(tmp_path / "n.yaml")
    assert back.segments[0].length == pytest.approx(8.15) and back.visits == ("T1",)
    (tmp_path / "n.yaml").write_text((tmp_path / "n.yaml").read_text().replace("radius_m: 0.2", "radius_m: -1"))
    with pytest.raises(PipemapError, match="n.yaml: radius_m: must be positive"):
        load_network(tmp_path / "n.yaml")
