"""Which of the batches' offset estimates the sparse odometry keeps (sparse/odometry.py `_long_batch`), on
synthetic batch results: the first bundle batch, the long bundle and eqs. 45-49 stubbed with the figures of a
6-inch run whose long bundle knew C_Y to 0.4 mm (0.48 % of the wall distance, beyond offset_max_sigma) while
the robot's wobble had put eqs. 45-49 6 mm off."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipemap.camera import PinholeCamera
from pipemap.config import QualitySettings, SparseSettings
from pipemap.quality import straight_verdict
from pipemap.quality.verdict import GOOD, SUSPECT
from pipemap.straight.mount import Mount
from pipemap.straight.sparse import odometry as od
from pipemap.straight.sparse.batch import BatchResult
from pipemap.straight.sparse.odometry import SparseOdometry, report_agrees
from pipemap.straight.sparse.run import _offset_choice

RADIUS = 0.0762
FIRST = dict(offset=(-0.21e-3, -27.09e-3), sigma=(0.177e-3, 0.908e-3), fraction=0.0089)
LONG = dict(offset=(0.54e-3, -25.14e-3), sigma=(0.27e-3, 0.405e-3), fraction=0.0048)
WOBBLED = (0.48e-3, -18.94e-3)  # eqs. 45-49 on the same keyframes


def _result(offset, sigma, n: int) -> BatchResult:
    C = np.zeros((n, 3))
    C[:, :2] = offset
    C[:, 2] = np.arange(n) * 4e-3
    cov = np.diag([1e-6, 1e-6, sigma[0] ** 2, sigma[1] ** 2])
    return BatchResult(np.repeat(np.eye(3)[None], n, 0), C, np.array(offset), 0.45, 1000, 300, 0.0,
                       np.array(sigma), np.r_[np.pi / 2, 0.0, offset], cov, 0.5)


def _odometry(monkeypatch, first: dict, long: dict | None, report, **settings) -> tuple[SparseOdometry, list]:
    """An odometry whose first batch has run (`first`) with stubs for the long bundle (`long`, None: it fails)
    and eqs. 45-49 (`report`, the offset they return); returns it and the list of eqs. 45-49 calls."""
    camera = PinholeCamera(320, 240, dict(fx=240.0, fy=240.0, cx=159.5, cy=119.5, k1=0, k2=0, p1=0, p2=0, k3=0))
    odo = SparseOdometry(camera, RADIUS, SparseSettings(**settings))
    kfs = [SimpleNamespace(index=i, R=np.eye(3), C=np.zeros(3), gid=np.arange(50), uv=np.zeros((50, 2)),
                           bearings=np.tile([0.0, 0.0, 1.0], (50, 1)), hr=None) for i in range(12)]
    odo.keyframes = kfs
    odo.offset = odo._summary(_result(first["offset"], first["sigma"], 4), first["fraction"], "batch", kfs[:4])
    runs = [] if long is None else [(_result(long["offset"], long["sigma"], 4), long["fraction"])]
    monkeypatch.setattr(odo, "_run_bundle", lambda ks: runs.pop(0) if runs else (None, np.inf))
    monkeypatch.setattr(odo, "_from_best_start", lambda ks, solve: solve(ks))
    monkeypatch.setattr(odo, "_replace_poses", lambda ks, R, C: None)
    monkeypatch.setattr(odo, "_follow", lambda ks, pick: None)
    calls = []

    def eqs_45_49(batch, camera, radius, R, offset0, heights):
        calls.append(offset0)
        return SimpleNamespace(offset=np.array(report), heights=np.zeros(len(heights)), rms_px=0.9, pairs=5000)

    monkeypatch.setattr(od, "optimise_offset", eqs_45_49)
    monkeypatch.setattr(od.OffsetBatch, "from_keyframes", classmethod(lambda cls, *a, **k: np.zeros(5000)))
    return odo, calls


def test_a_long_bundle_beyond_the_limit_is_kept_over_eqs_45_49_it_rules_out(monkeypatch):
    odo, calls = _odometry(monkeypatch, FIRST, LONG, WOBBLED)
    odo._long_batch(odo.keyframes)
    off = odo.offset
    assert calls, "eqs. 45-49 run where no bundle estimate determines the offset"
    assert off.used == "long bundle" and off.offset[1] == pytest.approx(-25.14e-3)
    assert not off.determined and odo.refine_dof() == "crawler"
    assert [(e.source, e.kept) for e in off.estimates] == [("batch", False), ("long bundle", True),
                                                          ("long batch", False)]
    assert off.estimates[-1].z > 10  # 6.2 mm at 0.4 mm of sigma
    # run.json says which estimate set the offset, how well it is known, and what else there was
    record = _offset_choice(off, odo.sparse.offset_max_sigma)
    assert record["sigma_fraction"] == pytest.approx(0.0048) and record["max_sigma_fraction"] == 0.003
    assert [e["source"] for e in record["estimates"]] == ["batch", "long bundle", "long batch"]
    # ... and the run is still rated suspect: the offset, on which the scale rests, is looser than the limit
    mount = Mount.from_odometry(odo, 100)
    assert mount.source == "long bundle" and not mount.determined
    times = np.arange(50) / 30.0
    v = straight_verdict("sparse-cylinder", np.arange(50), times, 0.05 * times, mount, RADIUS, QualitySettings())
    assert v.rating == SUSPECT and any("do not fix the camera's offset" in r for r in v.sections[0].reasons)
    # the long batch has run: the end of the run does not run it again over every keyframe
    assert not odo._wants_long_batch()


def test_eqs_45_49_are_kept_where_the_bundle_cannot_rule_them_out(monkeypatch):
    agreeing = (0.3e-3, -25.6e-3)  # 1.2 sigma of the long bundle's C_Y
    odo, calls = _odometry(monkeypatch, FIRST, LONG, agreeing)
    odo._long_batch(odo.keyframes)
    assert odo.offset.used == "long batch" and odo.offset.offset[1] == pytest.approx(-25.6e-3)
    assert odo.offset.estimates[-1].kept and odo.offset.estimates[-1].z < 3
    assert _offset_choice(odo.offset, 0.003)["sigma_fraction"] is None  # eqs. 45-49 have no sigma of their own


def test_the_first_batch_stays_where_the_long_bundle_knows_less(monkeypatch):
    worse = dict(LONG, fraction=0.012, sigma=(0.5e-3, 1.0e-3))
    odo, calls = _odometry(monkeypatch, FIRST, worse, WOBBLED)
    odo._long_batch(odo.keyframes)
    assert odo.offset.used == "batch" and odo.offset.offset[1] == pytest.approx(-27.09e-3)  # eqs. 45-49 9 sigma off
    assert [(e.source, e.kept) for e in odo.offset.estimates] == [("batch", True), ("long bundle", False),
                                                                 ("long batch", False)]


def test_eqs_45_49_stand_in_where_no_bundle_estimate_has_a_sigma(monkeypatch):
    odo, calls = _odometry(monkeypatch, FIRST, None, WOBBLED)
    odo.offset = od.replace(odo.offset, sigma=None)
    odo._long_batch(odo.keyframes)
    assert odo.offset.used == "long batch" and odo.offset.offset[1] == pytest.approx(WOBBLED[1])


def test_a_determined_offset_needs_no_eqs_45_49(monkeypatch):
    firm = dict(FIRST, fraction=0.002, sigma=(0.05e-3, 0.08e-3))
    odo, calls = _odometry(monkeypatch, firm, dict(LONG, fraction=0.0025), WOBBLED)
    odo._long_batch(odo.keyframes)
    assert not calls and odo.offset.used == "batch" and odo.offset.determined
    assert not odo._wants_long_batch()
    mount = Mount.from_odometry(odo, 100)
    times = np.arange(50) / 30.0
    v = straight_verdict("sparse-cylinder", np.arange(50), times, 0.05 * times, mount, RADIUS, QualitySettings())
    assert v.rating == GOOD, v.sections[0].reasons


def test_agreement_is_measured_in_the_bundle_estimates_own_sigmas():
    best = SimpleNamespace(offset=np.array([0.0, -25e-3]), sigma=np.array([1e-3, 0.5e-3]))
    assert report_agrees([0.0, -26.4e-3], best, 3.0)[0]  # 2.8 sigma
    ok, z = report_agrees([0.0, -26.6e-3], best, 3.0)
    assert not ok and z == pytest.approx(3.2)
    assert report_agrees([2.5e-3, -25e-3], best, 3.0)[0]  # C_X is the looser
    assert report_agrees([0.0, -40e-3], SimpleNamespace(offset=best.offset, sigma=None), 3.0)[0]
