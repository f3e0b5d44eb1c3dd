"""The run.json record every method writes."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from pipemap.config import Settings
from pipemap.results import RUN_FORMAT, run_record, write_run_json
from pipemap.sim.presets import fisheye_camera


def _dataset(tmp_path):
    return SimpleNamespace(root=tmp_path, camera=fisheye_camera(320, 240), radius_m=0.2)


def test_common_keys_lead_and_method_keys_follow(tmp_path):
    rec = run_record("sparse-cylinder", _dataset(tmp_path), Settings(), frames=np.int64(40), keyframes=12,
                     trajectory="keyframes", mount={"angle_deg": 90.0}, footage={}, problems=["x"], quality=None,
                     seconds={"motion": 1.23456}, distance_along_pipe_m=np.float64(1.5))
    keys = list(rec)
    assert keys[:13] == ["format", "version", "method", "input", "camera", "pipe_radius_m", "trajectory", "frames",
                         "keyframes", "mount", "footage", "problems", "quality"]
    assert keys[-2:] == ["settings", "seconds"] and rec["seconds"] == {"motion": 1.235}
    # every setting but how a batch spreads its runs, which changes no map
    assert set(rec["settings"]) == set(Settings().to_dict()) - {"batch"}
    write_run_json(tmp_path, rec)
    back = json.loads((tmp_path / "run.json").read_text())
    assert back["format"] == RUN_FORMAT and back["frames"] == 40 and back["distance_along_pipe_m"] == 1.5
    assert back["camera"]["model"] == "polynomial"


def test_bad_records_are_refused(tmp_path):
    common = dict(frames=1, keyframes=1, mount=None, footage={}, problems=[], quality=None, seconds={})
    with pytest.raises(ValueError, match="trajectory"):
        run_record("network", _dataset(tmp_path), Settings(), trajectory="poses", **common)
    with pytest.raises(ValueError, match="repeat common"):
        run_record("network", _dataset(tmp_path), Settings(), trajectory="frames", **common, **{"format": "x"})


def test_result_differences_name_files_and_keys(tmp_path):
    from pipemap.results import result_differences

    a, b = tmp_path / "a", tmp_path / "b"
    for folder, angle, seconds in ((a, float("nan"), 1.0), (b, float("nan"), 2.0)):
        (folder / "unrolled").mkdir(parents=True)
        (folder / "run.json").write_text(json.dumps({"frames": 40, "passes": [{"angle_deg": angle}],
                                                     "seconds": {"total": seconds}}))
        (folder / "unrolled" / "p.png").write_bytes(b"same")
    assert result_differences(a, b) == []  # wall times aside; NaN (written as NaN) equals NaN
    assert result_differences(a, b, ()) == ["run.json: seconds.total"]
    (b / "run.json").write_text(json.dumps({"frames": 39, "passes": [{"angle_deg": 1.0}], "seconds": {}}))
    (b / "unrolled" / "p.png").write_bytes(b"other")
    (b / "extra.csv").write_text("x")
    assert result_differences(a, b) == [f"extra.csv: only in {b}", "run.json: frames", "run.json: passes[0].angle_deg",
                                        "unrolled/p.png"]
