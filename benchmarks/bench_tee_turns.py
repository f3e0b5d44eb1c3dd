"""Where a loop's turns through tees lose angle: per tee, the truth against the estimate, before and after the tee
model.

    python benchmarks/bench_tee_turns.py DATA [DATA ...] [--cache /tmp/pipemap-tee-turns] [--set section.key=value]
                                         [--json-out benchmarks/results/tee_turns.json]

DATA is a simulated network dataset (ground_truth/poses.tum and network.yaml, its tees T1.. in the order the route
passes them and section S<k> running from T<k> to T<k+1>). The front end's result (keyframes, classes) is cached
under --cache, keyed by the dataset's path and the front end's overrides, and so is the straight VO's (keyed by the
overrides it depends on), so that runs with other settings for the later stages skip them. Stage 2 (`map_network`)
then runs with the settings given; no maps are written.

Angles are signed turns about the loop's normal (the truth's z; in the estimate the first keyframe's view of it), in
degrees, each against the truth's (error = estimate - truth). Per tee, for the VO's chaining (`vo`, before the tee
model) and for the map after it (`map`):
  camera     the camera's turn from the last keyframe of the section before to the first of the section after;
  ends       the turn from the end cylinder of the section before to the start cylinder of the one after (the
             truth: the pipe segments either side of the tee);
  red_end    the turn of the section before from its whole axis to its end cylinder (the truth: the section's
             chord to its last segment): how much its end bends away;
  blue_start the same for the section after, from its start cylinder to its whole axis;
  full       the turn from the whole axis of the section before to that of the one after (= red_end + ends +
             blue_start); the loop's shape follows these.
  red_cam / blue_cam  the camera's heading against its section's end (start) cylinder at the last (first) keyframe.
Table I: every distance between the tees' centres against the truth's, in % of it.
Tracks: how many keyframes the front end's tracks span (mean; share reaching 3 and 6).

--track-keyframes N cuts every track of the (cached) front end into pieces of at most N keyframes, each track's
cuts at its own seeded phase, before the straight VO: what tracks as short-lived as compressed footage's do to the
map, on a clean render's front end.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle
from itertools import combinations
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from threadpoolctl import threadpool_limits

from pipemap.backend.network_map import map_sections
from pipemap.config import load_settings
from pipemap.dataset import load_dataset
from pipemap.pipeline import map_network, section_bend, straight_vo, track_and_classify
from pipemap.trajectory import read_tum


FRONT_END = ("frontend.", "classification.", "seed=")  # overrides the front end's result depends on


def _key(data: Path, overrides: list[str]) -> str:
    """The cache name of a dataset under overrides: two datasets of one folder name are not one."""
    resolved = data.resolve()
    digest = hashlib.sha1(" ".join([str(resolved)] + sorted(overrides)).encode()).hexdigest()[:10]
    return f"{resolved.name}-{digest}"


def front_end(data: Path, cache: Path, settings, overrides: list[str] = ()):
    path = cache / f"{_key(data, [o for o in overrides if o.startswith(FRONT_END)])}-frontend.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    front = track_and_classify(load_dataset(data), settings)
    cache.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(front))
    return front


AFTER_VO = ("bundle.tee_", "evidence.", "loop_closure.")  # overrides of the stages after the straight VO


def cut_tracks(front, keyframes: int, seed: int = 0):
    """The front end with every track cut into pieces of at most `keyframes` keyframes (new consecutive ids)."""
    rng = np.random.default_rng(seed)
    first, phase, ids = {}, {}, {}
    cut = []
    for k, kf in enumerate(front.keyframes):
        new = np.empty(len(kf.track_ids), np.int64)
        for j, i in enumerate(np.asarray(kf.track_ids).tolist()):
            if i not in first:
                first[i], phase[i] = k, int(rng.integers(keyframes))
            new[j] = ids.setdefault((i, (k - first[i] + phase[i]) // keyframes), len(ids))
        cut.append(replace(kf, track_ids=new))
    return replace(front, keyframes=cut)


def track_spans(front) -> dict:
    """Keyframes from each track's first observation to its last: mean, and the share reaching 3 and 6."""
    first, last = {}, {}
    for k, kf in enumerate(front.keyframes):
        for i in np.asarray(kf.track_ids).tolist():
            first.setdefault(i, k)
            last[i] = k
    span = np.array([last[i] - first[i] for i in first]) if first else np.zeros(1)
    return {"mean": round(float(span.mean()), 3), "share_3": round(float(np.mean(span >= 3)), 3),
            "share_6": round(float(np.mean(span >= 6)), 3)}


def cached_vo(data: Path, cache: Path, front, dataset, settings, overrides: list[str]):
    """`straight_vo`'s result, cached by the dataset and the overrides it depends on."""
    path = cache / f"{_key(data, [o for o in overrides if not o.startswith(AFTER_VO)])}-vo.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    vo = straight_vo(front, dataset, settings)
    path.write_bytes(pickle.dumps(vo))
    return vo


def turn_deg(a: np.ndarray, b: np.ndarray, n: np.ndarray) -> float:
    """Signed angle about n from a to b, both projected onto the plane normal to n."""
    a, b = a - (a @ n) * n, b - (b @ n) * n
    return float(np.degrees(np.arctan2(n @ np.cross(a, b), a @ b)))


class Truth:
    """The simulated network: tee centres, the route's sections S1.. between them, camera poses per keyframe."""

    def __init__(self, data: Path, times: np.ndarray):
        net = yaml.safe_load((data / "ground_truth" / "network.yaml").read_text())
        self.tees = {j["id"]: np.asarray(j["centroid"], float) for j in net["junctions"]}
        self.segments = {s["id"]: (np.asarray(s["start"], float), np.asarray(s["end"], float))
                         for s in net["segments"]}
        gt = read_tum(data / "ground_truth" / "poses.tum")
        idx = np.clip(np.searchsorted(gt.timestamps, times - 1e-6), 0, len(gt) - 1)
        self.R = gt.rotations[idx]
        self.n = np.array([0.0, 0.0, 1.0])

    def section(self, k: int, part: str) -> np.ndarray:
        """Unit direction of S<k> along the route: its chord (`full`), first or last segment."""
        k = (k - 1) % len(self.tees) + 1
        ids = sorted(s for s in self.segments if s.startswith(f"S{k}."))
        a, b = {"full": (ids[0], ids[-1]), "first": (ids[0], ids[0]), "last": (ids[-1], ids[-1])}[part]
        d = self.segments[b][1] - self.segments[a][0]
        return d / np.linalg.norm(d)


def along(c, poses: np.ndarray, first: int, last: int) -> np.ndarray:
    d = c.direction / np.linalg.norm(c.direction)
    return d if d @ (poses[last, :3, 3] - poses[first, :3, 3]) >= 0 else -d


def tee_figures(truth: Truth, sections, junctions, poses: np.ndarray, n: np.ndarray) -> list[dict]:
    """Per tee passed between two straight sections, the signed turns of the module docstring, estimate and truth."""
    by_number = {m.number: m for m in sections}
    rows = []
    for i, j in enumerate(junctions):
        red, blue = by_number.get(j.before), by_number.get(j.after)
        if red is None or blue is None or None in (red.end, blue.start, red.cylinder, blue.cylinder):
            continue
        k = i + 1  # T<k> ends S<k-1> and starts S<k>
        rf, re = along(red.cylinder, poses, red.first, red.last), along(red.end, poses, red.first, red.last)
        bs, bf = along(blue.start, poses, blue.first, blue.last), along(blue.cylinder, poses, blue.first, blue.last)
        cam_r, cam_b = poses[red.last, :3, 2], poses[blue.first, :3, 2]
        t_rf, t_re, t_bs, t_bf = truth.section(k - 1, "full"), truth.section(k - 1, "last"), \
            truth.section(k, "first"), truth.section(k, "full")
        tc_r, tc_b = truth.R[red.last][:, 2], truth.R[blue.first][:, 2]
        est = {"camera": turn_deg(cam_r, cam_b, n), "ends": turn_deg(re, bs, n), "red_end": turn_deg(rf, re, n),
               "blue_start": turn_deg(bs, bf, n), "full": turn_deg(rf, bf, n), "red_cam": turn_deg(re, cam_r, n),
               "blue_cam": turn_deg(bs, cam_b, n)}
        tru = {"camera": turn_deg(tc_r, tc_b, truth.n), "ends": turn_deg(t_re, t_bs, truth.n),
               "red_end": turn_deg(t_rf, t_re, truth.n), "blue_start": turn_deg(t_bs, t_bf, truth.n),
               "full": turn_deg(t_rf, t_bf, truth.n), "red_cam": turn_deg(t_re, tc_r, truth.n),
               "blue_cam": turn_deg(t_bs, tc_b, truth.n)}
        sign = np.sign(tru["ends"]) or 1.0  # report turns positive the way the truth turns
        rows.append({"tee": j.id, "keyframes": [red.last, blue.first],
                     "estimate": {q: round(sign * v, 4) for q, v in est.items()},
                     "truth": {q: round(sign * v, 4) for q, v in tru.items()},
                     "error": {q: round(sign * (est[q] - tru[q]), 4) for q in est}})
    return rows


def section_figures(truth: Truth, sections, junctions, poses: np.ndarray, n: np.ndarray) -> list[dict]:
    """Per straight section beside a tee, the error of the camera's heading against the section's whole axis: the
    median over its middle half, at its first and at its last keyframe (deg)."""
    pipe = {}
    for i, j in enumerate(junctions):
        pipe.setdefault(j.before, i)  # T<i+1> ends S<i>
        pipe.setdefault(j.after, i + 1)
    rows = []
    for m in sections:
        if m.number not in pipe or m.cylinder is None:
            continue
        axis, t_axis = along(m.cylinder, poses, m.first, m.last), truth.section(pipe[m.number], "full")
        ks = np.arange(m.first, m.last + 1)
        err = np.array([turn_deg(axis, poses[k, :3, 2], n) - turn_deg(t_axis, truth.R[k][:, 2], truth.n)
                        for k in ks])
        middle = err[len(ks) // 4: max(len(ks) // 4 + 1, 3 * len(ks) // 4)]
        rows.append({"section": m.number, "keyframes": [m.first, m.last],
                     "middle_deg": round(float(np.median(middle)), 4), "first_deg": round(float(err[0]), 4),
                     "last_deg": round(float(err[-1]), 4)})
    return rows


def table_one(truth: Truth, tees) -> list[dict]:
    est = {t.id: np.asarray(t.centroid, float) for t in tees}
    rows = []
    for a, b in combinations(sorted(set(est) & set(truth.tees)), 2):
        t, e = np.linalg.norm(truth.tees[a] - truth.tees[b]), np.linalg.norm(est[a] - est[b])
        rows.append({"pair": f"{a}-{b}", "truth_m": round(float(t), 4), "estimate_m": round(float(e), 4),
                     "error_pct": round(float(100 * (e - t) / t), 3)})
    return rows


def measure(data: Path, cache: Path, overrides: list[str], track_keyframes: int | None = None) -> dict:
    settings = load_settings(None, overrides)
    dataset = load_dataset(data)
    with threadpool_limits(1, user_api="blas"):
        front = front_end(data, cache, settings, overrides)
        keyed = list(overrides)
        if track_keyframes is not None:
            front = cut_tracks(front, track_keyframes)
            keyed.append(f"track_keyframes={track_keyframes}")
        net = map_network(front, dataset, settings, cached_vo(data, cache, front, dataset, settings, keyed))
    truth = Truth(data, dataset.times()[net.straight.indices])
    poses = net.map.poses
    n = poses[0, :3, :3] @ truth.R[0].T @ truth.n  # the truth's normal as the first keyframe sees it
    vo_sections = map_sections(net.straight.sections, net.map.keyframes, net.straight.poses, net.straight.points,
                               net.straight.point_tracks, dataset.radius_m, settings.bundle.tee_fit_length_m,
                               settings.bundle.huber_m, section_bend(settings))
    tees = tee_figures(truth, net.map.sections, net.junctions, poses, n)
    vo = tee_figures(truth, vo_sections, net.junctions, net.straight.poses, n)
    for row, before in zip(tees, vo):
        row["vo"] = {"estimate": before["estimate"], "error": before["error"]}
    table = table_one(truth, net.tees)
    return {"data": str(data), "overrides": overrides, "track_keyframes": track_keyframes,
            "tracks": track_spans(front), "tees": tees, "table_one": table,
            "sections": section_figures(truth, net.map.sections, net.junctions, poses, n),
            "table_one_max_pct": max((abs(r["error_pct"]) for r in table), default=None),
            "tee_solves": [r.to_dict() for r in net.joins]}


def show(r: dict) -> None:
    cut = "" if r["track_keyframes"] is None else f" tracks cut at {r['track_keyframes']} keyframes"
    print(f"{r['data']} {' '.join(r['overrides'])}{cut}")
    t = r["tracks"]
    print(f"  tracks span {t['mean']:.2f} keyframes on average, {100 * t['share_3']:.1f} % reach 3, "
          f"{100 * t['share_6']:.1f} % reach 6")
    keys = ["camera", "ends", "red_end", "blue_start", "full", "red_cam", "blue_cam"]
    print("  tee  " + "".join(f"{k:>11}" for k in keys) + "   (error, deg: map | vo)")
    for t in r["tees"]:
        print(f"  {t['tee']:<4} " + "".join(f"{t['error'][k]:+11.3f}" for k in keys))
        print(f"  {'vo':<4} " + "".join(f"{t['vo']['error'][k]:+11.3f}" for k in keys))
        print("  true " + "".join(f"{t['truth'][k]:+11.3f}" for k in keys))
    print("  camera heading against its section's axis (error, deg): " + ", ".join(
        f"S{x['section']} first {x['first_deg']:+.3f} middle {x['middle_deg']:+.3f} last {x['last_deg']:+.3f}"
        for x in r["sections"]))
    print("  Table I: " + ", ".join(f"{x['pair']} {x['error_pct']:+.3f} %" for x in r["table_one"])
          + f"; max {r['table_one_max_pct']:.3f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, nargs="+")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/pipemap-tee-turns"))
    ap.add_argument("--set", action="append", default=[], help="settings override section.key=value (repeatable)")
    ap.add_argument("--track-keyframes", type=int, default=None,
                    help="cut every track into pieces of at most this many keyframes before the straight VO")
    ap.add_argument("--json-out", default=str(Path(__file__).parent / "results" / "tee_turns.json"))
    args = ap.parse_args()
    if args.track_keyframes is not None and args.track_keyframes < 1:
        ap.error("--track-keyframes must be at least 1")
    results = []
    for data in args.data:
        r = measure(data, args.cache, args.set, args.track_keyframes)
        show(r)
        results.append(r)
    Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json_out).write_text(json.dumps({"benchmark": "tee_turns", "results": results}, indent=2) + "\n")
    print(f"wrote {args.json_out}")


if __name__ == "__main__":
    main()
