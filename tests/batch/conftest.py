"""A small fisheye-straight render, its copies as a batch's datasets, and `pipemap run`'s result of it."""

from __future__ import annotations

import shutil

import pytest
import yaml
from typer.testing import CliRunner

from pipemap.cli import app

SIM = dict(preset="fisheye-straight", width=320, height=240, frames=40, seed=0, spacing_m=0.015)


@pytest.fixture(scope="session")
def batch_data(tmp_path_factory):
    """(folder of the datasets a, b and bad, pipemap run's result folder of a). bad names a mask image
    that is corrupt, which `pipemap run` refuses in one line."""
    from pipemap.sim.simulate import simulate

    base = tmp_path_factory.mktemp("batch")
    kw = dict(SIM)
    first = simulate(kw.pop("preset"), base / "data" / "a", **kw)
    shutil.copytree(first, base / "data" / "b")
    bad = shutil.copytree(first, base / "data" / "bad")
    doc = yaml.safe_load((bad / "dataset.yaml").read_text())
    (bad / "dataset.yaml").write_text(yaml.safe_dump(dict(doc, mask="mask.png"), sort_keys=False))
    (bad / "mask.png").write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    reference = base / "reference"
    result = CliRunner().invoke(app, ["run", str(first), "--out", str(reference)])
    assert result.exit_code == 0, result.output
    return base / "data", reference
