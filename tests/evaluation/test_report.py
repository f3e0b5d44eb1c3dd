"""report.html: plots, tables from metrics.json, thumbnails, and what it says when files are missing."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from pipemap.errors import PipemapError
from pipemap.evaluation import evaluate
from pipemap.evaluation.report import write_report
from pipemap.sim.simulate import simulate
from pipemap.trajectory import write_tum


@pytest.fixture(scope="session")
def loop_dataset(tmp_path_factory):
    """demo-loop past its first two tees, tiny frames (only the ground truth is used)."""
    return simulate("demo-loop", tmp_path_factory.mktemp("report") / "data", width=64, height=48, frames=60,
                    seed=0, spacing_m=0.06)


def make_result(folder: Path, dataset: Path, with_maps: bool = True) -> Path:
    """A result folder built from the ground truth: every 3rd pose with 5 mm of noise, the true
    junction centres moved by 1 cm, a run.json with timings, an unrolled image and a tiny PLY."""
    from pipemap.dataset import load_dataset
    from pipemap.mapping import write_appearance_ply

    ds = load_dataset(dataset)
    gt = ds.ground_truth_poses().subset(np.arange(0, 60, 3))
    rng = np.random.default_rng(0)
    folder.mkdir()
    noisy = type(gt)(gt.timestamps, gt.positions + rng.normal(0, 0.005, gt.positions.shape), gt.rotations)
    write_tum(folder / "trajectory.tum", noisy)
    net = ds.network()
    visited = [net.junction(j) for j in dict.fromkeys(net.visits)]
    doc = {"format": "pipemap-junctions/1", "junctions": [
        {"id": f"T{i + 1}", "type": "tee", "centroid": (j.centroid + [0.01, 0, 0]).tolist(), "keyframe": 0}
        for i, j in enumerate(visited)]}
    (folder / "junctions.yaml").write_text(yaml.safe_dump(doc))
    run = {"version": "test", "input": str(dataset), "frames": 60, "keyframes": len(gt), "points": 123,
           "junctions": doc["junctions"], "problems": ["section 2: a problem worth showing"],
           "seconds": {"frontend": 1.5, "straight_windows": 0.5, "total": 2.25},
           "quality": {"rating": "suspect", "line": "map suspect: 1 section good, 1 section suspect: section 1: "
                                                      "wall residual 3.0 % (limit 2.0 %)",
                       "sections": [{"section": 0, "kind": "straight", "first_frame": 0, "last_frame": 29,
                                     "keyframes": 12, "rating": "good", "reasons": []},
                                    {"section": 1, "kind": "straight", "first_frame": 30, "last_frame": 59,
                                     "keyframes": 12, "rating": "suspect",
                                     "reasons": ["wall residual 3.0 % (limit 2.0 %)"]}],
                       "gaps": [{"after_frame": 29, "before_frame": 30, "section": 1}]}}
    (folder / "run.json").write_text(json.dumps(run))
    if with_maps:
        (folder / "unrolled").mkdir()
        img = (np.arange(100 * 300) % 251).reshape(100, 300).astype(np.uint8)
        cv2.imwrite(str(folder / "unrolled" / "S1.png"), img)
        (folder / "unrolled" / "S1.json").write_text(json.dumps({"metres_per_pixel": 0.002,
                                                                 "metres_per_pixel_along": 0.002}))
        write_appearance_ply(folder / "appearance.ply", rng.normal(size=(50, 3)), rng.uniform(0, 255, 50))
    return folder


def referenced_files(html: str) -> list[str]:
    return re.findall(r'(?:src|href)="([^"]+)"', html)


def test_full_report(loop_dataset, tmp_path):
    result = make_result(tmp_path / "result", loop_dataset)
    metrics = evaluate(result, loop_dataset)
    out = write_report(result)  # the dataset is found through run.json's input
    html = out.read_text()
    refs = referenced_files(html)
    assert "report/trajectory.png" in refs and "report/timings.png" in refs and "unrolled/S1.png" in refs
    for ref in refs:
        assert not re.match(r"[a-z]+:", ref), ref  # relative links only
        assert (result / ref).is_file(), ref
    assert "<script" not in html.lower() and "http" not in html.lower()
    # the tables carry metrics.json's numbers
    assert "Table I" in html
    m = json.loads((result / "metrics.json").read_text())
    assert f"{m['ate']['rigid']['rmse_m']:.4f} m" in html
    assert 0.004 < metrics.ate_rigid.rmse < 0.012  # 5 mm of noise per axis
    for pair in metrics.junctions.pairs:
        assert f"<td>{'-'.join(pair.truth_ids)}</td>" in html
        assert f"{pair.error:+.3f}" in html
        assert abs(pair.error) < 0.021  # the centres moved by 1 cm each
    assert "a problem worth showing" in html
    assert ("map suspect: 1 section good, 1 section suspect" in html
            and "<td>wall residual 3.0 % (limit 2.0 %)</td>" in html)
    assert "tracking lost: not bridged" in html
    assert "50 points" in html  # appearance.ply's vertex count
    thumb = cv2.imread(str(result / "report" / "thumb-S1.png"), cv2.IMREAD_UNCHANGED)
    assert thumb.shape == (100, 300)  # narrower than the thumbnail width: kept as is
    assert "Missing from this result" in html and "sparse.ply" in html and "frames.csv" in html


def test_report_says_what_is_missing(loop_dataset, tmp_path):
    result = make_result(tmp_path / "result", loop_dataset, with_maps=False)
    (result / "run.json").unlink()
    (result / "junctions.yaml").unlink()
    html = write_report(result, loop_dataset).read_text()
    assert "no metrics.json" in html and "Table I" not in html
    assert "no appearance.ply" in html and "no unrolled/ images" in html
    assert "run.json records no stage timings" in html
    for name in ("junctions.yaml", "appearance.ply", "unrolled", "metrics.json", "run.json"):
        assert f"<code>{name}</code>" in html
    for ref in referenced_files(html):
        assert (result / ref).is_file(), ref


def test_report_without_trajectory_or_dataset(tmp_path):
    result = tmp_path / "empty"
    result.mkdir()
    html = write_report(result).read_text()
    assert "no trajectory.tum" in html and "<code>trajectory.tum</code>" in html
    with pytest.raises(PipemapError, match="result folder not found"):
        write_report(tmp_path / "nowhere")


def test_report_without_ground_truth_plots_the_plane_of_most_motion(loop_dataset, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(loop_dataset, data)
    shutil.rmtree(data / "ground_truth")
    result = make_result(tmp_path / "result", loop_dataset)
    html = write_report(result, data).read_text()
    assert "the dataset has no ground truth" in html and "plane of most motion" in html
    assert (result / "report" / "trajectory.png").is_file()
