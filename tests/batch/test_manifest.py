"""The runs a manifest lists: YAML, CSV or a glob; per-run settings; problems named by file and entry."""

from __future__ import annotations

import pytest

from pipemap.batch.manifest import read_runs
from pipemap.errors import PipemapError


def _datasets(tmp_path, names=("a", "b")):
    for name in names:
        (tmp_path / name).mkdir()
        (tmp_path / name / "dataset.yaml").write_text("format: pipemap-dataset/2\n")
    return tmp_path


def test_yaml_manifest_with_per_run_settings(tmp_path):
    _datasets(tmp_path)
    (tmp_path / "s.yaml").write_text("bundle:\n  window: 60\n")
    (tmp_path / "runs.yaml").write_text(
        "format: pipemap-batch/1\nruns:\n  - a\n  - {dataset: b, name: b2, method: network, config: s.yaml, "
        "set: [bundle.step=20]}\n")
    a, b = read_runs(str(tmp_path / "runs.yaml"), overrides=("seed=4",))
    assert (a.name, a.dataset, a.method) == ("a", tmp_path / "a", "auto")
    assert (a.settings.seed, a.settings.bundle.window, a.settings.bundle.step) == (4, 100, 50)
    assert (b.name, b.dataset, b.method) == ("b2", tmp_path / "b", "network")
    assert (b.settings.seed, b.settings.bundle.window, b.settings.bundle.step) == (4, 60, 20)


def test_csv_manifest_and_a_run_that_cannot_start(tmp_path):
    _datasets(tmp_path)
    (tmp_path / "runs.csv").write_text("dataset,name,method,set\na,,,bundle.window=40;seed=2\nb,bee,,bundle.tau=-1\n")
    a, b = read_runs(str(tmp_path / "runs.csv"))
    assert (a.name, a.settings.bundle.window, a.settings.seed, a.problem) == ("a", 40, 2, None)
    assert b.name == "bee" and b.settings is None
    assert b.problem.startswith(f"{tmp_path / 'runs.csv'}: line 3: --set: bundle.tau")


def test_glob_of_dataset_folders(tmp_path):
    _datasets(tmp_path, ("r1", "r2"))
    (tmp_path / "notes").mkdir()
    runs = read_runs(str(tmp_path / "*"), method="dense-lk")
    assert [(r.name, r.method) for r in runs] == [("r1", "dense-lk"), ("r2", "dense-lk")]


@pytest.mark.parametrize("text, words", [
    ("runs: []\n", "runs: expected a non-empty list"),
    ("format: pipemap-batch/9\nruns: [a]\n", "format: expected 'pipemap-batch/1'"),
    ("runs:\n  - {dataset: a, speed: 3}\n", r"runs\[0\]: unknown key 'speed'"),
    ("runs: [a, a]\n", r"runs\[1\]: name: two runs are named 'a'"),
    ("runs:\n  - {dataset: a, name: ../x}\n", "cannot name a result folder"),
])
def test_bad_manifests_name_file_and_entry(tmp_path, text, words):
    _datasets(tmp_path)
    (tmp_path / "runs.yaml").write_text(text)
    with pytest.raises(PipemapError, match=words):
        read_runs(str(tmp_path / "runs.yaml"))


def test_a_run_may_not_set_the_batch(tmp_path):
    _datasets(tmp_path)
    (tmp_path / "runs.yaml").write_text("runs:\n  - {dataset: a, set: [batch.workers=3], method: warp}\n  - b\n")
    bad, good = read_runs(str(tmp_path / "runs.yaml"))
    assert "unknown method 'warp'" in bad.problem and good.problem is None
    (tmp_path / "runs.yaml").write_text("runs:\n  - {dataset: a, set: [batch.workers=3]}\n")
    assert "batch settings apply to the whole batch" in read_runs(str(tmp_path / "runs.yaml"))[0].problem


def test_nothing_matches(tmp_path):
    with pytest.raises(PipemapError, match="no manifest file and no dataset folder"):
        read_runs(str(tmp_path / "none*"))


def test_one_dataset_by_folder_or_yaml(tmp_path):
    _datasets(tmp_path)
    by_folder, = read_runs(str(tmp_path / "a"))
    by_yaml, = read_runs(str(tmp_path / "a" / "dataset.yaml"))
    assert (by_folder.name, by_folder.dataset) == (by_yaml.name, by_yaml.dataset) == ("a", tmp_path / "a")
    with pytest.raises(PipemapError, match="manifest not found"):
        read_runs(str(tmp_path / "runs.yaml"))
