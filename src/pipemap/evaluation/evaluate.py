"""`pipemap evaluate`: read a result folder and a dataset's ground truth, compute every metric,
write `metrics.json`. The maths lives in `metrics.py`, `sections.py` and `wall_error.py`; this module
only reads and writes."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from pipemap.errors import PipemapError
from pipemap.yamlfile import read_yaml
from pipemap.evaluation.metrics import (
    ASSOCIATION_TOLERANCE_S,
    AteResult,
    DistanceTravelled,
    JunctionTable,
    associate,
    ate,
    distance_travelled,
    junction_table,
    path_length,
    percent,
)
from pipemap.evaluation.sections import SectionError, read_sections, section_errors
from pipemap.evaluation.wall_error import AppearanceWall, appearance_wall
from pipemap.network import JUNCTION_TYPES, PipeNetwork, load_network
from pipemap.output import atomic_write_text
from pipemap.trajectory import Trajectory, read_tum

METRICS_FORMAT = "pipemap-metrics/1"
JUNCTIONS_FORMAT = "pipemap-junctions/2"
JUNCTIONS_FORMATS = ("pipemap-junctions/1", JUNCTIONS_FORMAT)  # the versions read


@dataclass(frozen=True)
class EvaluationResult:
    dataset: str
    estimated_poses: int
    ground_truth_poses: int
    associated_poses: int
    ate_rigid: AteResult  # SE(3) alignment: the result claims metric scale
    ate_sim3: AteResult  # Sim(3) alignment: shape error once scale is factored out
    gt_path_length: float  # over the associated poses only, so keyframe subsets compare fairly
    est_path_length: float
    distance: DistanceTravelled | None = None  # straight (one-segment) networks
    turnaround_time_s: tuple[float, float] | None = None  # (ground truth, estimate)
    junctions: JunctionTable | None = None  # networks with junctions and a junctions.yaml
    sections: tuple[SectionError, ...] = ()  # straight sections one by one (run.json lists them)
    appearance_wall: AppearanceWall | None = None  # appearance.ply against the true wall
    notes: tuple[str, ...] = field(default_factory=tuple)  # why a table is absent

    @property
    def path_length_error(self) -> float:
        return self.est_path_length - self.gt_path_length

    @property
    def path_length_error_pct(self) -> float:
        return percent(self.path_length_error, self.gt_path_length)

    def ate_rmse_pct(self, a: AteResult) -> float:
        """ATE RMSE as a percentage of the ground-truth path length."""
        return percent(a.rmse, self.gt_path_length)

    def as_dict(self) -> dict:
        def ate_dict(a: AteResult) -> dict:
            return {**a.as_dict(), "rmse_pct_of_path": self.ate_rmse_pct(a)}

        distance = None
        if self.distance is not None:
            distance = self.distance.as_dict()
            distance["turnaround_time_s"] = (
                None
                if self.turnaround_time_s is None
                else {"ground_truth": self.turnaround_time_s[0], "estimate": self.turnaround_time_s[1]}
            )
        return _finite_or_none(
            {
                "format": METRICS_FORMAT,
                "dataset": self.dataset,
                "poses": {
                    "estimated": self.estimated_poses,
                    "ground_truth": self.ground_truth_poses,
                    "associated": self.associated_poses,
                    "association_tolerance_s": ASSOCIATION_TOLERANCE_S,
                },
                "ate": {"rigid": ate_dict(self.ate_rigid), "sim3": ate_dict(self.ate_sim3)},
                "path_length": {
                    "ground_truth_m": self.gt_path_length,
                    "estimate_m": self.est_path_length,
                    "error_m": self.path_length_error,
                    "error_pct": self.path_length_error_pct,
                },
                "distance_travelled": distance,
                "junctions": None if self.junctions is None else self.junctions.as_dict(),
                "sections": [x.as_dict() for x in self.sections],
                "appearance_wall": None if self.appearance_wall is None else self.appearance_wall.as_dict(),
                "notes": list(self.notes),
            }
        )


def _finite_or_none(value):
    """JSON has no NaN: undefined figures (a percentage of a zero length) become null."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


@dataclass(frozen=True)
class EstimatedJunction:
    """One entry of a result's junctions.yaml; an elbow's angle and bend radius where estimated."""

    id: str
    type: str
    centroid: np.ndarray
    keyframe: int | None = None
    angle_deg: float | None = None
    bend_radius_m: float | None = None


def _optional_positive(item: dict, name: str, path: Path, key: str, upper: float = math.inf) -> float | None:
    if item.get(name) is None:
        return None
    try:
        x = float(item[name])
    except (TypeError, ValueError):
        raise PipemapError("not a number", path, f"{key}.{name}") from None
    if not 0 < x < upper:
        raise PipemapError(f"must be a number above 0{'' if upper == math.inf else f' and below {upper:g}'}", path,
                           f"{key}.{name}")
    return x


def _estimated_junction(item, path: Path, key: str, version: int) -> EstimatedJunction:
    if not isinstance(item, dict) or "id" not in item:
        raise PipemapError("expected {id, type, centroid, keyframe}", path, key)
    try:
        c = np.asarray(item.get("centroid"), dtype=float)
    except (TypeError, ValueError):
        c = np.zeros(0)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise PipemapError("expected a list of 3 finite numbers", path, key + ".centroid")
    jtype = str(item.get("type", "tee"))
    if version >= 2 and jtype not in JUNCTION_TYPES:
        raise PipemapError(f"unknown junction type {jtype!r} (expected one of {', '.join(JUNCTION_TYPES)})", path,
                           key + ".type")
    angle = _optional_positive(item, "angle_deg", path, key, 180.0)
    bend = _optional_positive(item, "bend_radius_m", path, key)
    if (angle is not None or bend is not None) and jtype != "elbow":
        raise PipemapError(f"only an elbow has angle_deg and bend_radius_m (this is a {jtype})", path, key)
    keyframe = item.get("keyframe")
    try:
        keyframe = None if keyframe is None else int(keyframe)
    except (TypeError, ValueError):
        raise PipemapError("expected a keyframe number", path, key + ".keyframe") from None
    return EstimatedJunction(str(item["id"]), jtype, c, keyframe, angle, bend)


def read_junction_list(path: str | Path) -> list[EstimatedJunction]:
    """Read a result's `junctions.yaml` (pipemap-junctions/1 or /2), in the order the camera passes them."""
    path = Path(path)
    data = read_yaml(path, "junctions file")
    if data.get("format") not in JUNCTIONS_FORMATS:
        raise PipemapError(f"expected '{JUNCTIONS_FORMAT}' (or '{JUNCTIONS_FORMATS[0]}'), found "
                           f"{data.get('format')!r}", path, "format")
    version = JUNCTIONS_FORMATS.index(data["format"]) + 1
    items = data.get("junctions")
    if items is None:
        items = []
    if not isinstance(items, list):
        raise PipemapError("expected a list of {id, type, centroid, keyframe}", path, "junctions")
    out: list[EstimatedJunction] = []
    for i, item in enumerate(items):
        j = _estimated_junction(item, path, f"junctions[{i}]", version)
        if any(o.id == j.id for o in out):
            raise PipemapError(f"junction id {j.id!r} appears twice", path, f"junctions[{i}].id")
        out.append(j)
    return out


def read_junctions(path: str | Path) -> tuple[list[str], np.ndarray]:
    """A result's `junctions.yaml` as ids and (N, 3) centroids, in order (read_junction_list for the rest)."""
    items = read_junction_list(path)
    return [j.id for j in items], np.asarray([j.centroid for j in items], float).reshape(-1, 3)


def _dataset_name(dataset_dir: Path) -> str:
    # Only the name is wanted; dataset.yaml is validated by the dataset reader, not here.
    try:
        data = yaml.safe_load((dataset_dir / "dataset.yaml").read_text())
        if isinstance(data, dict) and data.get("name"):
            return str(data["name"])
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        pass
    return dataset_dir.resolve().name


def _folder(path: Path, what: str) -> Path:
    if not path.is_dir():
        raise PipemapError(f"{what} folder not found" if not path.exists() else f"{what} is not a folder", path)
    return path


def evaluate(result_dir: str | Path, dataset_dir: str | Path, write: bool = True) -> EvaluationResult:
    """Compare a result folder with a dataset's ground truth; write `result_dir/metrics.json`
    unless `write` is False. Every problem with the inputs raises PipemapError naming the file."""
    result_dir = _folder(Path(result_dir), "result")
    dataset_dir = _folder(Path(dataset_dir), "dataset")
    est_path = result_dir / "trajectory.tum"
    gt_path = dataset_dir / "ground_truth" / "poses.tum"
    net_path = dataset_dir / "ground_truth" / "network.yaml"
    junctions_path = result_dir / "junctions.yaml"
    if not gt_path.exists():
        raise PipemapError("no ground-truth poses: this dataset cannot be evaluated", gt_path)
    est = read_tum(est_path)
    gt = read_tum(gt_path)
    network = load_network(net_path) if net_path.exists() else None

    est_i, gt_i = associate(est.timestamps, gt.timestamps, ASSOCIATION_TOLERANCE_S)
    if len(est_i) < 2:
        found = "no timestamps" if len(est_i) == 0 else "only 1 timestamp"
        raise PipemapError(
            f"{found} in common with ground truth {gt_path} (tolerance {ASSOCIATION_TOLERANCE_S:g} s); need at least 2",
            est_path,
        )
    est_m: Trajectory = est.subset(est_i)
    gt_m: Trajectory = gt.subset(gt_i)

    notes: list[str] = []
    distance, turnaround = None, None
    junctions, wall = None, None
    ate_rigid = ate(est_m.positions, gt_m.positions, with_scale=False)
    if network is None:
        notes.append("no ground_truth/network.yaml: distance-travelled, junction and appearance-wall tables skipped")
    else:
        distance, turnaround = _straight_run(network, est_m, gt_m, notes)
        junctions = _junctions(network, junctions_path, notes)
        wall = _appearance_wall(result_dir, network, est, gt, ate_rigid, notes)

    result = EvaluationResult(
        dataset=_dataset_name(dataset_dir),
        estimated_poses=len(est),
        ground_truth_poses=len(gt),
        associated_poses=len(est_i),
        ate_rigid=ate_rigid,
        ate_sim3=ate(est_m.positions, gt_m.positions, with_scale=True),
        gt_path_length=path_length(gt_m.positions),
        est_path_length=path_length(est_m.positions),
        distance=distance,
        turnaround_time_s=turnaround,
        junctions=junctions,
        sections=tuple(section_errors(read_sections(result_dir / "run.json"), est, gt)),
        appearance_wall=wall,
        notes=tuple(notes),
    )
    if write:
        write_metrics(result_dir / "metrics.json", result)
    return result


def _straight_run(network: PipeNetwork, est: Trajectory, gt: Trajectory, notes: list[str]):
    axis = straight_axis(network)
    if axis is None:
        notes.append("the network is not one straight pipe: distance travelled is not defined")
        return None, None
    d = distance_travelled(est.positions, gt.positions, axis)
    turnaround = None
    if d.forward_and_reverse:
        turnaround = (float(gt.timestamps[d.gt_turnaround_index]), float(est.timestamps[d.est_turnaround_index]))
    return d, turnaround


def straight_axis(network: PipeNetwork, max_bend_deg: float = 2.0) -> np.ndarray | None:
    """The axis of a network that is one straight pipe, possibly built of several slightly sagging or
    misaligned pieces joined end to end; None for a network with junctions or bends."""
    if network.junctions or not network.segments or any(seg.is_arc for seg in network.segments):
        return None
    first, last = network.segments[0], network.segments[-1]
    axis = last.end - first.start
    if np.linalg.norm(axis) == 0:
        return None
    axis = axis / np.linalg.norm(axis)
    cos_min = np.cos(np.radians(max_bend_deg))
    if any(float(seg.axis @ axis) < cos_min for seg in network.segments):
        return None
    return axis


def _junctions(network: PipeNetwork, path: Path, notes: list[str]) -> JunctionTable | None:
    if not network.junctions:
        return None
    if not path.exists():
        notes.append("the result has no junctions.yaml: junction table skipped")
        return None
    estimated = read_junction_list(path)
    ids = [j.id for j in estimated]
    centroids = np.asarray([j.centroid for j in estimated], float).reshape(-1, 3)
    # Without a recorded route, the network's own junction order stands in for the visit order.
    visits = network.visits or tuple(j.id for j in network.junctions)
    table = junction_table(ids, centroids, visits, {j.id: j.centroid for j in network.junctions},
                           {j.id: j for j in network.junctions}, estimated)
    missing = [e.truth_id for e in table.elbows if e.estimate_angle_deg is None or e.estimate_bend_radius_m is None]
    if missing:
        notes.append(f"{path.name} does not estimate the angle or bend radius of elbow(s) {', '.join(missing)}")
    if not table.counts_agree:
        notes.append(
            f"{path.name} lists {table.estimated_count} junctions, the ground-truth route visits "
            f"{table.truth_count}: only the first {len(table.matches)} are matched, in order"
        )
    return table


def _appearance_wall(result_dir: Path, network: PipeNetwork, est: Trajectory, gt: Trajectory, ate_rigid: AteResult,
                     notes: list[str]) -> AppearanceWall | None:
    if not (result_dir / "appearance.ply").exists():
        notes.append("the result has no appearance.ply: appearance-wall error skipped")
        return None
    wall = appearance_wall(result_dir, network, est, gt, ate_rigid.alignment)
    notes.extend(wall.notes)
    return wall


def write_metrics(path: str | Path, result: EvaluationResult) -> None:
    """Write metrics.json atomically (temporary file, then rename)."""
    path = Path(path)
    text = json.dumps(result.as_dict(), indent=2, allow_nan=False) + "\n"
    try:
        atomic_write_text(path, text)
    except OSError as exc:
        raise PipemapError(f"cannot write: {exc.strerror or exc}", path) from None
