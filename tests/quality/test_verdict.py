"""Ratings from figures: limits, the worst check wins, the one-line verdict; the free radius
scales with the poses' translations; the motion model finds a slipped step."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.frontend.tracks import Keyframe
from pipemap.quality import FAILED, GOOD, SUSPECT, Check, RunVerdict, SectionVerdict, free_radius, motion_slips
from pipemap.quality.verdict import above, below


def test_limits_rate_a_figure():
    assert above("x", 0.5, (1.0, 2.0), "x").rating == GOOD
    assert above("x", 1.5, (1.0, 2.0), "x").rating == SUSPECT
    c = above("x", 2.5, (1.0, 2.0), "reprojection RMS (px)")
    assert c.rating == FAILED and c.reason == "reprojection RMS (px) 2.5 (limit 2)"
    assert below("y", 0.3, (0.5, 0.25), "y").rating == SUSPECT
    assert below("y", 0.2, (0.5, 0.25), "y").rating == FAILED
    assert above("x", None, (1.0, 2.0), "x").rating == GOOD  # not measured: no claim


def test_run_verdict_line_names_the_worst_reason():
    good = SectionVerdict(0, "straight", 0, 99, 30, [Check("a", 1.0, GOOD)])
    odd = SectionVerdict(1, "straight", 100, 199, 30, [Check("free radius", 0.06, FAILED, "free radius is off "
                                                             "the given one by 6.0 % (limit 5.0 %)")])
    run = RunVerdict([good, odd, SectionVerdict(2, "junction", 200, 220, 5)])
    assert run.rating == FAILED and run.counts() == {GOOD: 2, SUSPECT: 0, FAILED: 1}
    assert run.line() == ("map failed: 2 sections good, 1 section failed: section 1: free radius is off the "
                          "given one by 6.0 % (limit 5.0 %)")
    assert RunVerdict([good]).line() == "map good: 1 section good"
    d = run.to_dict()
    assert d["rating"] == FAILED and d["sections"][1]["reasons"] and d["sections"][0]["reasons"] == []


def _keyframes_on_a_cylinder(radius: float, steps: int, step_m: float, seed: int = 0):
    """Cameras along the axis of a cylinder (x axis), wall points seen by all of them: exact bearings."""
    rng = np.random.default_rng(seed)
    n = 400
    h = rng.uniform(0.3, 1.5, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    X = np.c_[h, radius * np.cos(phi), radius * np.sin(phi)]
    R = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]).T  # camera z along world x
    kfs, poses = [], []
    for k in range(steps):
        c = np.array([k * step_m, 0.0, 0.0])
        b = (X - c) @ R
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        kfs.append(Keyframe(k, k, k / 10, np.zeros((n, 2)), b, np.arange(n), np.ones(n, bool), np.zeros(n, bool),
                            np.eye(3), np.zeros(3), k > 0))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, c
        poses.append(T)
    return kfs, np.array(poses)


@pytest.mark.parametrize("scale", [1.0, 1.05, 0.97])
def test_free_radius_scales_with_the_translations(scale):
    kfs, poses = _keyframes_on_a_cylinder(0.2, 12, 0.02)
    poses[:, :3, 3] *= scale
    r, n = free_radius(kfs, poses, 0, 11, np.zeros(3), np.array([1.0, 0, 0]), 30)
    assert n > 150
    assert r == pytest.approx(0.2 * scale, rel=1e-6)


def test_free_radius_needs_parallax():
    kfs, poses = _keyframes_on_a_cylinder(0.2, 3, 1e-4)
    assert free_radius(kfs, poses, 0, 2, np.zeros(3), np.array([1.0, 0, 0]), 30)[0] is None


def test_motion_model_finds_a_slipped_step():
    rng = np.random.default_rng(0)
    times = np.cumsum(rng.choice([2, 3], 101)) / 30.0  # keyframes two or three frames apart
    speed = 0.05 + 0.01 * np.sin(times)  # a smooth speed change is no slip
    along = np.r_[0.0, np.cumsum(speed[1:] * np.diff(times))]
    assert motion_slips(along, times) == 0.0
    along[41:] += 0.005  # one registration one period off
    assert motion_slips(along, times) == pytest.approx(0.01)
    assert motion_slips(along[:3], times[:3]) is None


def test_network_verdict_rates_each_section_from_its_figures():
    from types import SimpleNamespace as NS

    from pipemap.config import QualitySettings
    from pipemap.geometry.cylinder import Cylinder
    from pipemap.quality import network_verdict

    from dataclasses import replace

    kfs, poses = _keyframes_on_a_cylinder(0.2, 30, 0.02)
    kfs = [replace(kf, index=3 * k, pose_valid=k not in (0, 20)) for k, kf in enumerate(kfs)]  # lost at 20
    sections = [NS(number=0, first=0, last=9, kind="straight", scale="cylinder", linked=False),
                NS(number=1, first=10, last=19, kind="junction", scale="cylinder", linked=True),
                NS(number=2, first=20, last=29, kind="straight", scale="unit", linked=False)]
    windows = [NS(section=0, rms_px=0.4, cylinder_rms_m=0.001), NS(section=2, rms_px=1.6, cylinder_rms_m=0.001)]
    axis = Cylinder(np.zeros(3), np.array([1.0, 0, 0]), 0.2)
    mapped = [NS(number=0, cylinder=axis), NS(number=2, cylinder=axis)]
    junctions = [NS(id="T1", first=10, last=19, method="path")]
    q = network_verdict(sections, windows, kfs, poses, mapped, junctions, [], None, 0.2, QualitySettings(), 0.6)
    s0, s1, s2 = q.sections
    assert s0.rating == GOOD and s0.figures["free_radius_m"] == pytest.approx(0.2, rel=1e-6)
    assert s1.rating == SUSPECT and "T1 has a straight section on one side only" in s1.reasons[0]
    assert s2.rating == FAILED and s2.reasons[0] == "no metric scale: no window could be solved"
    assert any("reprojection RMS (px) 1.6" in r for r in s2.reasons)
    assert any("tracking was lost before it (frames 57-60)" in r for r in s2.reasons)
    assert q.gaps == [{"after_frame": 57, "before_frame": 60, "section": 2}]
    assert q.line().startswith("map failed: 1 section good, 1 section suspect, 1 section failed: section 2: no metric")


def test_straight_verdict_rates_the_mount_that_sets_the_scale():
    from types import SimpleNamespace as NS

    from pipemap.config import QualitySettings
    from pipemap.quality import straight_verdict

    times = np.arange(50) / 30.0
    along = 0.05 * times
    firm = NS(determined=True, source="long bundle", sigma=np.array([0.01, 0.01, 1e-4, 1e-4]), offset_m=np.zeros(2),
              angle_deg=90.0)
    loose = NS(determined=False, source="long batch", sigma=None, offset_m=np.array([0.0, -0.065]), angle_deg=90.0)
    wide = NS(determined=True, source="batch", sigma=np.array([0.01, 0.01, 0.0, 2e-3]), offset_m=np.zeros(2),
              angle_deg=90.0)
    q = QualitySettings()
    assert straight_verdict("sparse-cylinder", np.arange(50), times, along, firm, 0.2, q).rating == GOOD
    v = straight_verdict("sparse-cylinder", np.arange(50), times, along, loose, 0.2, q)
    assert v.rating == SUSPECT and "do not fix the camera's offset" in v.sections[0].reasons[0]
    # 2 mm of offset sigma at 200 mm from the wall: 1 % of scale, one sigma
    v = straight_verdict("dense-hybrid", np.arange(50), times, along, wide, 0.2, q)
    assert v.rating == SUSPECT and v.sections[0].figures["mount_offset_sigma_m"] == pytest.approx(2e-3)
    # the same sigma with the camera 100 mm behind the axis: 300 mm from the wall it looks at, 0.67 % of scale
    behind = NS(determined=True, source="batch", sigma=wide.sigma, offset_m=np.array([0.0, -0.1]), angle_deg=90.0)
    v = straight_verdict("dense-hybrid", np.arange(50), times, along, behind, 0.2, q)
    assert v.sections[0].checks[-1].value == pytest.approx(2e-3 / 0.3)
    # ... and 100 mm beyond it, 100 mm from the wall: 2 % of scale, failed
    beyond = NS(determined=True, source="batch", sigma=wide.sigma, offset_m=np.array([0.0, 0.1]), angle_deg=90.0)
    assert straight_verdict("dense-hybrid", np.arange(50), times, along, beyond, 0.2, q).rating == FAILED


def test_wall_distance_along_the_view_matches_the_ray_cast():
    from pipemap.quality.straight_checks import wall_distance_along_view

    # a camera at (C_X, C_Y) looking towards +Y, tilted 60 deg to the axis: the ray (0, sin a, cos a)
    c = np.array([0.03, -0.05])
    a = np.radians(60.0)
    t = np.linspace(0, 1, 200001)
    y = c[1] + t * np.sin(a)
    hit = t[np.argmax(np.hypot(c[0], y) >= 0.2)]
    assert wall_distance_along_view(c, 60.0, 0.2) == pytest.approx(hit, abs=1e-5)


def _bowed_section(radius: float, length: float, sagitta: float, step: float = 0.05, seed: int = 0):
    """Cameras along the axis of a pipe that bows `sagitta` across its `length` (an arc in the x-y plane, as a
    long run's heading drift bends its map), each seeing the wall 0.3-1.5 m ahead of it: exact bearings."""
    rng = np.random.default_rng(seed)
    bow = length**2 / (8 * sagitta)  # the arc's radius

    def axis(s):  # point and unit tangent of the axis at arc length s from the middle
        a = s / bow
        return np.c_[bow * np.sin(a), bow * (1 - np.cos(a)), 0 * a], np.c_[np.cos(a), np.sin(a), 0 * a]

    s = rng.uniform(-length / 2, length / 2 + 1.6, 3000 * int(length))
    phi = rng.uniform(0, 2 * np.pi, len(s))
    p, t = axis(s)
    n1 = np.c_[-t[:, 1], t[:, 0], 0 * s]
    X = p + radius * (np.cos(phi)[:, None] * n1 + np.sin(phi)[:, None] * np.array([0.0, 0, 1]))
    kfs, poses = [], []
    for k, sk in enumerate(np.arange(-length / 2, length / 2, step)):
        c, tk = (v[0] for v in axis(np.array([sk])))
        R = np.column_stack([np.cross(tk, [0.0, 0, 1]), [0.0, 0, -1], tk])  # camera z along the axis
        ids = np.flatnonzero((s > sk + 0.3) & (s < sk + 1.5))
        b = (X[ids] - c) @ R
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        n = len(ids)
        kfs.append(Keyframe(k, k, k / 10, np.zeros((n, 2)), b, ids, np.ones(n, bool), np.zeros(n, bool),
                            np.eye(3), np.zeros(3), k > 0))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, c
        poses.append(T)
    return kfs, np.array(poses), X


def test_a_long_bowed_section_keeps_its_free_radius_stretch_by_stretch():
    """A 20 m section bowed 30 cm (the map of a long run whose heading drifts) at the right scale: against one
    straight axis its points read per cents off the radius, against its 8 m stretches' own axes they do not
    (measured: 2.9 % and 0.04 %); a 3 % scale error still shows."""
    from pipemap.geometry.cylinder import fit_cylinder
    from pipemap.quality.network_checks import section_free_radius
    kfs, poses, X = _bowed_section(0.2, 20.0, 0.3)
    whole = fit_cylinder(X, 0.2, direction=np.array([1.0, 0, 0])).cylinder
    last = len(kfs) - 1
    straight, _ = section_free_radius(kfs, poses, 0, last, whole, 0.2, 30)
    r, n = section_free_radius(kfs, poses, 0, last, whole, 0.2, 30, (X, np.arange(len(X)), 0.005))
    assert n > 10000
    assert abs(straight / 0.2 - 1) > 0.02
    assert abs(r / 0.2 - 1) < 0.001
    poses[:, :3, 3] *= 1.03
    r, _ = section_free_radius(kfs, poses, 0, last, whole, 0.2, 30, (X * 1.03, np.arange(len(X)), 0.005))
    assert r / 0.2 == pytest.approx(1.03, abs=0.003)


def test_a_tee_whose_free_solve_turned_off_its_angle_is_suspect():
    from types import SimpleNamespace as NS

    from pipemap.backend.join import JoinReport
    from pipemap.config import QualitySettings
    from pipemap.quality import network_verdict

    kfs, poses = _keyframes_on_a_cylinder(0.2, 20, 0.02)
    sections = [NS(number=0, first=0, last=9, kind="junction", scale="cylinder", linked=True),
                NS(number=1, first=10, last=19, kind="junction", scale="cylinder", linked=True)]
    junctions = [NS(id="T1", first=0, last=9, method="tee-model"), NS(id="T2", first=10, last=19, method="tee-model")]
    joins = [JoinReport("T1", "tee-model", angle_deg=89.5, free_angle_deg=88.6, angle_held=True,
                        free_angle_off_deg=1.4),
             JoinReport("T2", "tee-model", angle_deg=90.0, free_angle_deg=89.7, angle_held=True,
                        free_angle_off_deg=0.3)]
    q = network_verdict(sections, [], kfs, poses, [], junctions, joins, None, 0.2, QualitySettings(), 0.6)
    t1, t2 = q.sections
    assert t1.rating == SUSPECT and "T1's free solve turned 1.40 deg from a tee's angle" in t1.reasons[0]
    assert t1.figures["tee_free_angle_deg"] == 88.6
    assert t2.rating == GOOD  # held by no more than its sockets deflect


def test_a_dropped_pass_whose_axes_still_turn_is_suspect():
    from types import SimpleNamespace as NS

    from pipemap.backend.evidence import DroppedPass
    from pipemap.config import QualitySettings
    from pipemap.quality import network_verdict

    kfs, poses = _keyframes_on_a_cylinder(0.2, 20, 0.02)
    sections = [NS(number=0, first=0, last=9, kind="junction", scale="cylinder", linked=True),
                NS(number=1, first=10, last=19, kind="junction", scale="cylinder", linked=True)]
    dropped = [DroppedPass("T1", 0, 9, 5.06, "not a junction"), DroppedPass("T2", 10, 19, 0.3, "not a junction")]
    q = network_verdict(sections, [], kfs, poses, [], [], [], None, 0.2, QualitySettings(), 0.6, dropped=dropped)
    turned, flicker = q.sections
    assert turned.rating == SUSPECT
    assert turned.reasons == ["the axes turn across it where nothing branches (T1 dropped), by 5.1 deg (limit 2.0 deg)"]
    assert flicker.rating == GOOD  # classification flicker: the axes run on
