"""`pipemap run`: the stages in order, writing the result folder of spec/formats.md.

1. Tracking: every frame is classified straight / junction (fisheye paper III-B) and tracked
   (III-A) into keyframes with relative poses.
2. Mapping: the keyframes go through the metric VO (III-C) in sections of one class: straight
   sections get cylinder-regularised sliding-window SBA, junction sections are chained through
   with the relative poses and the scale of the tracks; cylinders are fitted to the straight
   sections and their ends, and each tee centre is where the end cylinders either side meet (III-D).
3. Loop closure where the route revisits a straight section (III-E).
4. Maps: the dense grey-level appearance point cloud and unrolled wall images (IV-B).
Writes trajectory.tum, junctions.yaml, sparse.ply, appearance.ply, unrolled/, frames.csv and run.json.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml
from threadpoolctl import threadpool_limits

from pipemap.backend.evidence import DroppedPass, fit_elbow_bends, type_turning_passes, weigh_junction_evidence
from pipemap.backend.join import join_sections
from pipemap.backend.network_map import (
    MappedJunction,
    MappedSection,
    map_junctions,
    map_sections,
    name_junctions,
    wall_pieces,
)
from pipemap.backend.pipe_map import PipeMap
from pipemap.backend.revisit import RevisitReport, close_network_loops
from pipemap.backend.sparse_ply import write_sparse_ply
from pipemap.backend.section_vo import StraightResult, StraightVO
from pipemap.backend.straight_beside import StraightVOBeside
from pipemap.camera import CameraModel
from pipemap.config import Settings
from pipemap.dataset import Dataset, load_dataset
from pipemap.errors import PipemapError
from pipemap.footage import FootageLog
from pipemap.frontend import make_tracker
from pipemap.frontend.angular import classification_for, scaled_settings
from pipemap.frontend.classification import SequenceClass, SequenceClassifier
from pipemap.frontend.section_labels import KeyframeClasses
from pipemap.frontend.settling import SettlingFilter
from pipemap.frontend.tracks import Keyframe
from pipemap.frontend.tracks_io import write_frames_csv
from pipemap.frontend.usable import UsableMask, usable_mask
from pipemap.geometry.bend import OFFSET_SIGMA_M
from pipemap.inspection.network_route import network_route
from pipemap.inspection.route import Route, frame_chainage, write_route
from pipemap.mapping import WallPiece, piece_from_dict, with_elbows, write_maps
from pipemap.mapping.deformation_stage import measure_deformation, sparse_deformation, write_deformation
from pipemap.mapping.wall_depth import dense_profiles
from pipemap.output import atomic_write_text, result_folder
from pipemap.quality import FrameStats, RunVerdict, network_verdict, require_mappable
from pipemap.results import run_record, write_run_json
from pipemap.trajectory import Trajectory, write_tum
from pipemap.view import check_wall_in_view


@dataclass
class FrontEndResult:
    keyframes: list[Keyframe]
    classes: SequenceClass
    image_count: int  # frames tracked (repeated frames are skipped)
    seconds: dict
    footage: FootageLog = field(default_factory=FootageLog)  # repeated, dropped and damaged frames
    mask: UsableMask | None = None  # the pixels that move with the wall
    stats: FrameStats | None = None  # lighting and texture of the frames read
    bends: np.ndarray | None = None  # keyframes classed junction for a bend's turn alone, when classed while tracking
    refused_poses: int = 0  # relative poses refused for a rotation their inliers' motion cannot have made
    continued_poses: int = 0  # RANSAC poses replaced by the previous motion continued


@dataclass
class NetworkResult:
    straight: StraightResult  # the VO's own figures: its sections, windows, keyframe image indices
    map: PipeMap  # keyframes, poses and points after the tee model and loop closure, sections, junctions
    seconds: dict
    joins: list = field(default_factory=list)  # JoinReport per junction (the tee-model solves)
    revisit: RevisitReport | None = None  # loop closure
    tees: list[MappedJunction] = field(default_factory=list)  # distinct tees in order of first passage
    quality: RunVerdict | None = None  # the sections' self-checks
    dropped: list[DroppedPass] = field(default_factory=list)  # junction passes with no turn and no side opening
    route: Route | None = None  # the axis followed, with chainage and 12 o'clock (inspection/route.py)
    bends: np.ndarray | None = None  # (keyframes,) bool: in a bend the images did not classify (frontend/turning.py)

    @property
    def sections(self) -> list[MappedSection]:
        return self.map.sections

    @property
    def junctions(self) -> list[MappedJunction]:
        return self.map.junctions

    @property
    def wall_pieces(self) -> list[dict]:  # run.json "wall_pieces"
        return self.map.wall_pieces


@dataclass
class PipelineResult:
    out_dir: Path
    image_count: int
    keyframe_count: int
    map: PipeMap
    junctions: list[MappedJunction]  # the distinct tees, named
    seconds: dict  # per stage
    footage: FootageLog = field(default_factory=FootageLog)
    mask: UsableMask | None = None
    quality: RunVerdict | None = None


# False where every core already maps a run of its own (a batch worker held to one thread): the second
# thread would only add its hand-overs to the run's time.
_PREPARE_AHEAD: ContextVar[bool] = ContextVar("prepare_ahead", default=True)


@contextlib.contextmanager
def frames_prepared_in_turn():
    """The front end reads, classifies and extracts each frame on the mapping thread itself (same result)."""
    token = _PREPARE_AHEAD.set(False)
    try:
        yield
    finally:
        _PREPARE_AHEAD.reset(token)


def _done(value) -> Future:
    future: Future = Future()
    future.set_result(value)
    return future


def track_and_classify(dataset: Dataset, settings: Settings,
                       progress: Callable[[int, int, int], None] | None = None,
                       classed: Callable[[Keyframe, bool], None] | None = None) -> FrontEndResult:
    """Stage 1: every frame classified straight / junction (III-B) and tracked (III-A).

    Reading, classifying and feature extraction of the next frame run on a second thread while
    the current one is matched (OpenCV and numpy release the GIL there); both follow frame order,
    so the result is the same as one thread's. `classed(keyframe, junction)` gets every keyframe in
    order as soon as its section class is final (section_labels.py), the last ones at the end."""
    mask = usable_mask(dataset, settings)
    tracker = make_tracker(dataset.camera, settings.frontend, settings.seed, mask.usable)
    classifier = SequenceClassifier(dataset.camera, classification_for(dataset.camera, settings.classification,
                                                                     settings.frontend.reference_px_per_deg),
                                    mask.view)
    total = len(dataset)
    keyframes: list[Keyframe] = []
    done = 0
    timing = {"read": 0.0, "classification": 0.0, "extract": 0.0}
    start = time.perf_counter()

    log = FootageLog()
    settle = SettlingFilter(settling_keyframes(settings, dataset.codec, dataset.camera))
    stats = FrameStats.for_settings(settings)
    classes = None if classed is None else keyframe_classes(settings)

    def hand_on(final: list[tuple[int, bool]]) -> None:
        for k, junction in final:
            classed(keyframes[k], junction)
    # a repeated frame (a stalled link) shows nothing new: tracked, it would be a stop of the robot
    frames = (f for f in dataset.frames(log=log) if not f.repeated)

    def prepare():
        """The next frame, read, classified and its features extracted (None at the end)."""
        t = time.perf_counter()
        frame = next(frames, None)
        if frame is None:
            return None
        timing["read"] += time.perf_counter() - t
        t = time.perf_counter()
        classifier.add(frame)
        stats.add(frame.image)
        t1 = time.perf_counter()
        features = tracker.extract(frame)
        timing["classification"] += t1 - t
        timing["extract"] += time.perf_counter() - t1
        return frame, features

    # One worker keeps the reading, classifying and extracting in frame order, two frames ahead; another finds a
    # new keyframe's corners while the tracker matches its tracks.
    with ThreadPoolExecutor(max_workers=1) as pool, ThreadPoolExecutor(max_workers=1) as helper:
        submit = pool.submit if _PREPARE_AHEAD.get() else (lambda work: _done(work()))
        if _PREPARE_AHEAD.get() and hasattr(tracker, "beside"):
            tracker.beside = helper.submit
        ahead = deque(submit(prepare) for _ in range(2))
        while True:
            item = ahead.popleft().result()
            if item is None:
                break
            ahead.append(submit(prepare))
            frame, features = item
            new = [settle(k) for k in tracker.process(frame, features)]
            keyframes.extend(new)
            if new and classes is not None:
                hand_on(classes.update(keyframes, classifier.indices, classifier.raw))
            done += 1
            if progress is not None:
                progress(done, total, len(keyframes))
        keyframes.extend(settle(k) for k in tracker.finish())
    if classes is not None:
        hand_on(classes.update(keyframes, classifier.indices, classifier.raw, done=True))
    if done == 0:
        raise PipemapError("no images could be read", dataset.root)
    wall = time.perf_counter() - start
    # frontend: the stage's wall time; read/classification/extract ran beside it on the second thread.
    seconds = {"frontend": wall, "read": timing["read"], "classification": timing["classification"],
               "extract": timing["extract"]}
    log.predicted, log.settling_left_out = dataset.predicted, settle.left_out
    return FrontEndResult(keyframes, classifier.result(), done, seconds, log, mask, stats,
                          None if classes is None else classes.bends, tracker.refused_poses,
                          tracker.continued_poses)


def section_bend(settings: Settings) -> tuple[float, float, float, float] | None:
    """(knot spacing, kink sigma rad, point sigma m, offset sigma m) of the sections' bent axes, weighed
    as the window solves weigh them (a point's distance counts 1 / sqrt(tau) metres per unit). The
    offsets get only the gauge's weak hold: the window solves decided how far the points bend, and
    a fit to the finished points need not fear heading drift. None: straight."""
    b = settings.bundle
    if b.bend_knot_m is None or b.tau <= 0:
        return None
    return b.bend_knot_m, float(np.radians(b.bend_kink_deg)), float(1.0 / np.sqrt(b.tau)), OFFSET_SIGMA_M


def bend_labels(labels: dict, keyframe_indices: np.ndarray, bends: np.ndarray | None) -> dict:
    """frames.csv's `bend` for the frames the images classified straight from each keyframe in a bend the
    camera's turn showed (frontend/turning.py) up to the next keyframe."""
    if bends is None or not np.any(bends):
        return {}
    idx = np.asarray(keyframe_indices, int)
    ends = np.r_[idx[1:], idx[-1] + 1]
    return {i: "bend" for k in np.flatnonzero(bends) for i in range(int(idx[k]), int(ends[k]))
            if labels.get(i) == "straight"}


def straight_vo(front: FrontEndResult, dataset: Dataset, settings: Settings) -> tuple[StraightVO, StraightResult,
                                                                                     np.ndarray]:
    """Stage 2's metric VO of the straight sections (III-C) chained through the junctions: the VO, its result and
    which keyframes are in a bend the images did not classify."""
    vo = StraightVO(dataset.camera, dataset.radius_m, straight_vo_settings(settings, dataset))
    classes = keyframe_classes(settings)
    c = front.classes
    for k, junction in classes.update(front.keyframes, c.indices.tolist(), c.raw_junction.tolist(), done=True):
        vo.add(front.keyframes[k], junction=junction)
    return vo, vo.finish(), classes.bends


def straight_vo_settings(settings: Settings, dataset: Dataset) -> Settings:
    """The straight VO's settings for this footage: on video whose pictures are predicted (H.264, MPEG-4) the wall
    ahead is not cut where it seems to come in (`straight_vo.wall_inward_m` None). The codec's lag puts the wall
    just ahead of the newest keyframe millimetres inside in some clock sectors of a straight pipe, and cut there
    (at the camera itself, in three of fisheye-straight seed 2's four windows) the windows came out short: forward /
    reverse -0.054 / -0.050 -> -0.271 / -0.265 %, paper-loop route A seed 1 Table I 0.545 -> 0.782 % (the same
    tracks, `bench_paired.py`)."""
    if settings.straight_vo.wall_inward_m is None or not dataset.predicted:
        return settings
    return settings.model_copy(update={"straight_vo": settings.straight_vo.model_copy(update={"wall_inward_m": None})})


def keyframe_classes(settings: Settings) -> KeyframeClasses:
    """The keyframes' section classes: the images' (filtered) and the turns of bends they missed."""
    c = settings.classification
    return KeyframeClasses(c.min_cluster_keyframes, c.turn_deg, turn_window(settings))


def turn_window(settings: Settings) -> int:
    """classification.turn_window_keyframes at the run's keyframe spacing (at_keyframe_spacing). With keyframes twice
    as far apart the unscaled window reached past the 12 keyframes of straight pipe after elbow-cross A's sweeping
    bend to the end of the route, and the bend became a tee placed from the path (Table I 6-10 %)."""
    return at_keyframe_spacing(settings.classification.turn_window_keyframes, settings.frontend, least=2)


def settling_keyframes(settings: Settings, codec: str | None, camera: CameraModel | None = None) -> int:
    """frontend.predicted_settling_keyframes at the run's keyframe spacing, on a codec it applies to and a camera
    that sees the wall beside it (else 0): the lag dies away with the pictures predicted since a track's patch was
    cut, and with keyframes twice as far apart a track's second observation is as many pictures on as its third at
    the default spacing. Unscaled, the filter left fisheye-straight as H.264 at 20 px almost no observations (the
    reverse distance -44 %). A forward perspective camera (widest colatitude under 90 deg) sees each piece of wall
    over few keyframes before it leaves the view, and its scale rests on them: with the filter its H.264 footage
    lost the scale (cctv-loop route B seeds 1 / 2 Table I 1.73 / 2.29 %, without it 0.41 / 0.22 %; cctv-recording
    seed 5 forward / reverse 0.112 / 0.641 %, without it 0.037 / 0.030 %)."""
    f = settings.frontend
    if codec not in f.settling_codecs or (camera is not None and not camera.sees_beside()):
        return 0
    return at_keyframe_spacing(f.predicted_settling_keyframes, f, least=0)


def at_keyframe_spacing(keyframes: int, frontend, least: int) -> int:
    """A count of keyframes given at the default frontend.keyframe_min_flow_px, at the run's: keyframes made further
    apart cover the same length of pipe (and the same pictures) in proportionally fewer."""
    default = type(frontend).model_fields["keyframe_min_flow_px"].default
    if frontend.keyframe_min_flow_px <= 0:  # every frame a keyframe: the count as given
        return keyframes
    return max(least, int(round(keyframes * default / frontend.keyframe_min_flow_px)))


def map_network(front: FrontEndResult, dataset: Dataset, settings: Settings,
                straight: tuple[StraightVO, StraightResult, np.ndarray] | None = None) -> NetworkResult:
    """Stage 2: metric VO of the straight sections (III-C) chained through the junctions, then the
    sections' cylinders and the tee centres (III-D), the tee model and loop closure on the map.
    `straight`: `straight_vo`'s result, when it was already run with these settings."""
    vo, result, bends = straight if straight is not None else straight_vo(front, dataset, settings)
    if vo.solve_turning_sections():
        result = vo.result()
    t = time.perf_counter()

    def fitted_sections(poses: np.ndarray, points: np.ndarray) -> list[MappedSection]:
        return map_sections(result.sections, vo.keyframes, poses, points, result.point_tracks, dataset.radius_m,
                            settings.bundle.tee_fit_length_m, settings.bundle.huber_m, section_bend(settings))

    sections = fitted_sections(result.poses, result.points)
    pipe_map = PipeMap.build(vo.keyframes, result.poses, result.points, result.point_tracks, sections,
                             map_junctions(result.sections, sections, result.poses))
    pipe_map = type_turning_passes(pipe_map, dataset.radius_m, settings)
    joins = []
    if settings.bundle.tee_model:
        exact = dataset.codec in settings.bundle.tee_angle_exact_codecs and dataset.camera.sees_beside()
        pipe_map, joins = join_sections(pipe_map, result.active, dataset.camera, dataset.radius_m, settings, exact)
    pipe_map = fit_elbow_bends(pipe_map, dataset.radius_m, settings)
    pipe_map, dropped = weigh_junction_evidence(pipe_map, settings)
    revisit = RevisitReport("no revisit" if settings.loop_closure.enabled else "disabled")
    if settings.loop_closure.enabled:  # a pipe is revisited past junctions or by reversing in it
        def image_of(k: int) -> np.ndarray:
            return dataset.read(vo.keyframes[k].index).image

        pipe_map, revisit = close_network_loops(pipe_map, dataset.camera, image_of, dataset.radius_m, settings)
        if revisit.status == "closed":  # the cylinders hang from the corrected poses: fit them again
            pipe_map.sections = fitted_sections(pipe_map.poses, pipe_map.points)
    junctions = pipe_map.junctions
    tees = name_junctions(junctions, dataset.radius_m, settings.loop_closure.same_junction_radii)
    poses = pipe_map.poses
    # World = the first keyframe's camera frame (x right, y down): 12 o'clock is first taken as its -y, then
    # estimated over the run (inspection/up.py) from the pieces' axes, which do not depend on it.
    up = -poses[0, :3, 1] if len(poses) else np.array([0.0, -1.0, 0.0])
    pipe_map.wall_pieces = wall_pieces(pipe_map.sections, junctions, up)
    axis_route = network_route(pipe_map.wall_pieces, [m.to_dict() for m in pipe_map.sections],
                          [j.pass_record() for j in junctions],
                          poses, dataset.radius_m, settings.route.up)
    if axis_route is not None:
        pipe_map.wall_pieces = with_elbows(wall_pieces(pipe_map.sections, junctions, axis_route.segments[0].up),
                                           axis_route)
    route = float(np.sum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))) if len(poses) else 0.0
    quality = network_verdict(result.sections, result.windows, vo.keyframes, poses, pipe_map.sections, junctions,
                              joins, revisit, dataset.radius_m, settings.quality, route,
                              (pipe_map.points, pipe_map.point_tracks, settings.bundle.huber_m), dropped)
    seconds = {"straight_relative": result.seconds["relative"], "straight_windows": result.seconds["windows"],
               "network": time.perf_counter() - t}
    seconds["loop_closure"] = revisit.seconds
    return NetworkResult(result, pipe_map, seconds, joins, revisit, tees, quality, dropped, axis_route, bends)


def write_junctions(path: Path, junctions: list[MappedJunction], route: Route | None = None) -> None:
    """junctions.yaml; with a route, each junction's chainage where the route first passes it."""
    first = {}
    for jid, _, chainage in (route.nodes if route is not None else ()):
        first.setdefault(jid, chainage)
    doc = {"format": "pipemap-junctions/2",
           "junctions": [dict(j.to_dict(), **({"chainage_m": round(first[j.id], 4)} if j.id in first else {}))
                         for j in junctions]}
    atomic_write_text(path, yaml.safe_dump(doc, sort_keys=False))


def write_results(folder: Path, dataset: Dataset, front: FrontEndResult, net: NetworkResult, settings: Settings,
                  seconds: dict, maps: dict | None = None, deformation: dict | None = None) -> None:
    """trajectory.tum, junctions.yaml, sparse.ply, frames.csv and run.json into `folder`."""
    t0 = time.perf_counter()
    result = net.straight
    traj = Trajectory.from_matrices(dataset.times()[result.indices], net.map.poses)
    write_tum(folder / "trajectory.tum", traj,
              header="pipemap fisheye VO: keyframe T_wc in metres, world = first keyframe's camera")
    write_junctions(folder / "junctions.yaml", net.tees, net.route)
    chainage = None
    if net.route is not None:
        write_route(folder / "route.json", net.route)
        chainage = frame_chainage(len(dataset), result.indices, net.route.follow(net.map.poses[:, :3, 3]))
    write_sparse_ply(folder / "sparse.ply", net.map.points)
    classes = front.classes
    labels = dict(zip(np.asarray(classes.indices).tolist(), classes.labels))
    labels.update(bend_labels(labels, result.indices, net.bends))
    labels.update({i: "repeated" for i in front.footage.repeated})
    write_frames_csv(folder / "frames.csv", len(dataset), result.indices.tolist(), labels, chainage)
    seconds = dict(seconds)
    seconds["write"] = time.perf_counter() - t0
    problems = [f"section {m.number}: {p}" for m in net.sections for p in m.problems]
    problems += [f"{j.id}: only one straight section beside it, centre from the camera path" for j in net.junctions
                 if j.method == "path"]
    problems += [f"{r.junction}: {r.status}" for r in net.joins if r.status != "tee-model"]
    run = run_record(
        "network", dataset, settings, frames=front.image_count, keyframes=len(result.indices), trajectory="keyframes",
        mount=None, footage=front.footage.to_dict(), problems=problems,
        quality=None if net.quality is None else net.quality.to_dict(), seconds=seconds,
        stage="run",
        frontend_pixels=scaled_settings(dataset.camera, settings.frontend),
        mask=None if front.mask is None else front.mask.to_dict(),
        points=len(net.map.points),
        lost_keyframes=sum(1 for s in result.sections[1:] if not s.linked),
        refused_poses=front.refused_poses,
        continued_poses=front.continued_poses,
        sections=[s.to_dict() for s in result.sections],
        straight_sections=[m.to_dict() for m in net.sections],
        junction_passes=[dict(j.pass_record(), method=j.method, angle_deg=round(j.angle_deg, 3),
                              axes_gap_m=round(j.gap_m, 5),
                              **({} if j.opening is None else {"side_opening": j.opening}))
                         for j in net.junctions],
        dropped_junction_passes=[d.to_dict() for d in net.dropped],
        junction_clusters=[list(c) for c in front.classes.clusters],
        wall_pieces=net.wall_pieces,
        route=None if net.route is None else {"length_m": round(net.route.length, 4),
                                              "up_estimate": net.route.up_source},
        appearance=maps,
        deformation=deformation,
        tee_solves=[r.to_dict() for r in net.joins],
        loop_closure=None if net.revisit is None else net.revisit.to_dict(),
        windows=[w.to_dict() for w in result.windows],
    )
    write_run_json(folder, run)


def track_beside_vo(dataset: Dataset, settings: Settings, progress: Callable[[int, int, int], None] | None = None
                    ) -> tuple[FrontEndResult, tuple | None]:
    """track_and_classify, with the straight-section VO fed its keyframes in a second process as they come
    (straight_beside.py; `straight_vo.beside_tracking`, and not where frames are prepared in turn or in a
    daemonic process): the front end's result and straight_vo's (None where the VO did not run beside: it
    runs after the tracking, as where no process can be started or the process died)."""
    beside = None
    # a daemonic process (a Dask worker's) may start none of its own
    if settings.straight_vo.beside_tracking and _PREPARE_AHEAD.get() and not multiprocessing.current_process().daemon:
        with contextlib.suppress(OSError):  # no semaphores, a process limit
            beside = StraightVOBeside(dataset.camera, dataset.radius_m, straight_vo_settings(settings, dataset))
    try:
        front = track_and_classify(dataset, settings, progress, None if beside is None else beside.add)
        require_mappable(front.stats, len(front.keyframes), len(dataset), len(front.footage.repeated), settings,
                         dataset.root)
        if beside is None:
            return front, None
        t = time.perf_counter()
        try:
            vo, result = beside.finish(front.keyframes)
        except PipemapError:
            raise
        except Exception:  # noqa: BLE001 - the process died (killed, out of memory): the VO runs here instead
            return front, None
        front.seconds["straight_wait"] = time.perf_counter() - t
        return front, (vo, result, front.bends)
    finally:
        if beside is not None:
            beside.close()


def write_wall_maps(folder: Path, dataset: Dataset, front: FrontEndResult, net: NetworkResult, settings: Settings,
                    stage: Callable[[str], None]) -> tuple[dict | None, dict | None]:
    """The appearance maps and the deformation stage into `folder`: (write_maps' record, the deformation
    record), None for what is off. The sparse deformation reads only the map, so it runs on a second thread
    while the appearance map samples the keyframes (not where frames are prepared in turn); the same result."""
    maps = deformation = None
    if not net.wall_pieces:
        return maps, deformation
    straight = [WallPiece.from_dict(d) for d in net.wall_pieces if d.get("kind", "line") == "line"]
    with ThreadPoolExecutor(max_workers=1) as pool:
        submit = pool.submit if _PREPARE_AHEAD.get() else (lambda work: _done(work()))
        sparse = submit(lambda: sparse_deformation(net.map, straight, dataset.radius_m, settings)) \
            if settings.deformation.enabled else None
        if settings.appearance.enabled:
            stage("appearance")
            maps = write_maps(folder, dataset, net.straight.indices, net.map.poses,
                              [piece_from_dict(d) for d in net.wall_pieces], settings,
                              usable=None if front.mask is None else front.mask.view, route=net.route)
        if sparse is None:
            return maps, deformation
        stage("deformation")
        indices = net.straight.indices

        def dense(piece):
            return dense_profiles(piece, dataset.camera, net.map.poses, lambda k: dataset.read(int(indices[k])).image,
                                  dataset.radius_m, settings.deformation)

        rows, deformation = measure_deformation(net.map, straight, dataset.radius_m, settings, dense, net.route,
                                                sparse.result())
    write_deformation(folder, rows, dataset.radius_m)
    return maps, deformation


def run_pipeline(dataset_path, out_dir, settings: Settings | None = None,
                 progress: Callable[[int, int, int], None] | None = None,
                 on_stage: Callable[[str], None] | None = None) -> PipelineResult:
    """Run every stage on the dataset at `dataset_path` and write the result folder `out_dir` atomically.

    progress(done, total, keyframes) is called after every frame of the tracking stage;
    on_stage(name) when a stage starts ("tracking", "mapping", "writing").
    """
    settings = settings or Settings()
    dataset = load_dataset(dataset_path)
    check_wall_in_view(dataset)
    start = time.perf_counter()
    stage = on_stage or (lambda name: None)
    # The front end already keeps both cores busy (a second thread prepares the next frame), and its
    # matrix products are small: OpenBLAS threads only spin against that thread (descriptor matching
    # took 17 ms of CPU a frame with two BLAS threads, 6.5 ms with one). The results are the same.
    with threadpool_limits(1, user_api="blas"), result_folder(Path(out_dir)) as tmp:
        stage("tracking")
        front, straight = track_beside_vo(dataset, settings, progress)
        stage("mapping")
        net = map_network(front, dataset, settings, straight)
        maps, deformation = write_wall_maps(tmp, dataset, front, net, settings, stage)
        stage("writing")
        seconds = dict(front.seconds)
        seconds.update(net.seconds)
        if maps is not None:
            seconds.update(maps["seconds"])
        seconds["total"] = time.perf_counter() - start
        write_results(tmp, dataset, front, net, settings, seconds, maps, deformation)
    return PipelineResult(Path(out_dir), front.image_count, len(net.straight.indices), net.map, net.tees,
                          seconds, front.footage, front.mask, net.quality)


__all__ = ["FrontEndResult", "NetworkResult", "PipelineResult", "track_and_classify", "track_beside_vo", "straight_vo",
           "map_network", "run_pipeline", "write_results", "write_junctions"]
