"""`pipemap batch` on a local Dask cluster: the result folders are `pipemap run`'s, a run with a corrupt
image fails alone in one line, complete runs are skipped, a worker killed mid-run loses nothing, and
Ctrl-C leaves only complete result folders."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time

import yaml
from typer.testing import CliRunner

from pipemap.batch.engine import dask_client, run_batch
from pipemap.batch.manifest import read_runs
from pipemap.cli import app
from pipemap.config import BatchSettings
from pipemap.results import result_differences

runner = CliRunner()


def _summary(out):
    with open(out / "batch.csv") as fh:
        return {row["run"]: row for row in csv.DictReader(fh)}


def test_batch_maps_as_run_does_and_a_bad_run_fails_alone(batch_data, tmp_path):
    data, reference = batch_data
    manifest = tmp_path / "runs.yaml"
    manifest.write_text(yaml.safe_dump({"format": "pipemap-batch/1", "runs": [
        str(data / "a"), {"dataset": str(data / "b"), "name": "b2", "set": ["seed=0"]}, str(data / "bad")]}))
    out = tmp_path / "out"
    args = ["batch", str(manifest), "--out", str(out), "--workers", "2", "--set", "batch.processes=false"]
    first = runner.invoke(app, args)
    assert first.exit_code == 1, first.output  # one run failed
    rows = _summary(out)
    assert [r["status"] for r in rows.values()] == ["mapped", "mapped", "failed"]
    reason = rows["bad"]["problems"]
    assert reason == f"{data / 'bad' / 'mask.png'}: cannot read mask image (missing, empty or corrupt)"
    assert f"bad: {reason}" in first.output.replace("\n", "")
    # the same files as `pipemap run`, but for wall times (and b's path, which run.json records)
    assert result_differences(out / "a", reference) == []
    assert result_differences(out / "b2", reference, ("seconds", "time_s", "points_per_second", "input")) == []
    record = json.loads((out / "a" / "run.json").read_text())
    junctions = yaml.safe_load((out / "a" / "junctions.yaml").read_text())["junctions"]
    assert (rows["a"]["frames"], rows["a"]["keyframes"]) == ("40", str(record["keyframes"]))
    assert rows["a"]["junctions"] == str(len(junctions)) and float(rows["a"]["seconds"]) > 0
    assert sorted(p.name for p in out.iterdir()) == ["a", "b2", "batch.csv"]  # no temporary folder left

    again = runner.invoke(app, args)
    rows = _summary(out)
    assert (rows["a"]["status"], rows["b2"]["status"], rows["bad"]["status"]) == ("skipped", "skipped", "failed")
    assert "runs to map" in again.output and "1 of 3 runs" in again.output  # only the failed one is tried again
    assert result_differences(out / "a", reference) == []


def test_all_complete_starts_no_cluster(batch_data, tmp_path):
    data, reference = batch_data
    out = tmp_path / "out"
    out.mkdir()
    (out / "batch.csv").write_text("run\n")
    os.symlink(reference, out / "a")  # a complete result folder
    runs = read_runs(str(data / "a"))

    def no_cluster():
        raise AssertionError("a cluster was started")

    rows = run_batch(runs, out, no_cluster, 1)
    assert [(r["run"], r["status"], r["frames"]) for r in rows] == [("a", "skipped", 40)]
    rows = run_batch(read_runs(str(data / "a"), overrides=("seed=3",)), out, no_cluster, 1)
    assert rows[0]["problems"].startswith("mapped earlier with other settings or method")


def test_a_worker_killed_mid_run_loses_nothing(batch_data, tmp_path):
    data, reference = batch_data
    out = tmp_path / "out"
    killed = {}

    def kill_one(client, todo):
        def watch():
            pids = client.run(os.getpid)
            deadline = time.time() + 60
            while time.time() < deadline and not killed:
                for worker, keys in client.processing().items():
                    name = next((r.name for r in todo if keys and f"-{r.name}-" in keys[0]), None)
                    if name and list(out.glob(f".{name}.partial-*")):  # inside the run's result folder
                        os.kill(pids[worker], signal.SIGKILL)
                        killed.update(name=name, pid=pids[worker])
                        return
                time.sleep(0.05)

        threading.Thread(target=watch, daemon=True).start()

    runs = read_runs(str(data / "[ab]"))
    rows = run_batch(runs, out, lambda: dask_client(None, BatchSettings(retries=2), workers=2), 1, on_start=kill_one)
    assert killed, "no worker was caught mid-run"
    assert [r["status"] for r in rows] == ["mapped", "mapped"]
    assert result_differences(out / killed["name"], reference, ("seconds", "time_s", "points_per_second", "input")) \
        == []
    assert sorted(p.name for p in out.iterdir()) == ["a", "b", "batch.csv"]


def test_ctrl_c_leaves_only_complete_result_folders(batch_data, tmp_path):
    data, _ = batch_data
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "pipemap", "batch", str(data / "[ab]"), "--out", str(out),
                             "--workers", "2"], start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 60
    while time.time() < deadline and not list(out.glob(".*.partial-*")):
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: to the batch and its workers
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "interrupted" in stderr
    left = sorted(p.name for p in out.iterdir())
    assert "batch.csv" in left and not [n for n in left if n.startswith(".")]
    rows = _summary(out)
    for name in ("a", "b"):
        assert (rows[name]["status"] == "mapped") == (name in left)
        assert rows[name]["status"] in ("mapped", "interrupted")
        if name in left:
            assert json.loads((out / name / "run.json").read_text())["frames"] == 40


def test_batch_input_problems_are_one_line(batch_data, tmp_path):
    data, _ = batch_data
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    cases = [(["--out", str(tmp_path / "mine")], "holds no batch.csv of an earlier batch"),
             (["--out", str(tmp_path / "o"), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers: sets"),
             (["--out", str(tmp_path / "o"), "--set", "batch.retries=-1"], "--set: batch.retries")]
    for extra, words in cases:
        res = runner.invoke(app, ["batch", str(data / "a"), *extra])
        assert res.exit_code == 2 and words in res.output and "Traceback" not in res.output, res.output
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep" and not (tmp_path / "o").exists()
