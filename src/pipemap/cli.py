"""The `pipemap` command: thin wrappers that parse arguments and call library functions."""

from __future__ import annotations

import contextlib
import functools
import glob as globmod
import os
import sys
from pathlib import Path
from typing import Callable, List, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from pipemap import __version__
from pipemap.errors import PipemapError

app = typer.Typer(
    name="pipemap",
    help="Metric maps of pipe networks from a crawler robot's single camera.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
console = Console()
err_console = Console(stderr=True)

FORCE_OPTION = typer.Option(False, "--force", help="Replace an existing output; the old one is removed only once the "
                                                    "new one is complete.")


def friendly(fn: Callable) -> Callable:
    """Turn input problems into one line on stderr and a non-zero exit code, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except PipemapError as exc:
            err_console.print(f"pipemap: error: {exc.line()}", markup=False, highlight=False, soft_wrap=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt:
            err_console.print("pipemap: interrupted; nothing was written", markup=False)
            raise typer.Exit(130) from None
        except (typer.Exit, typer.Abort):
            raise
        except Exception as exc:  # noqa: BLE001 - the last line of defence for the user
            if os.environ.get("PIPEMAP_DEBUG"):
                raise
            first = str(exc).splitlines()[0] if str(exc) else ""
            err_console.print(
                f"pipemap: internal error: {type(exc).__name__}: {first} (set PIPEMAP_DEBUG=1 for details)",
                markup=False,
                highlight=False,
                soft_wrap=True,
            )
            raise typer.Exit(1) from None

    return wrapper


def expand_glob(pattern: str) -> list[Path]:
    paths = sorted(Path(p) for p in globmod.glob(os.path.expanduser(pattern)))
    paths = [p for p in paths if p.is_file()]
    if not paths:
        raise PipemapError("no files match", pattern)
    return paths


@contextlib.contextmanager
def frame_progress(label: str, keyframes: bool = False):
    """A transient progress bar over frames on stderr; yields progress(done, total[, keyframes]).
    Without a terminal (a log, a pipe) it stays silent, so errors remain one line."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    if not err_console.is_terminal:
        yield lambda done, total, kf=0: None
        return

    columns = [TextColumn(label), BarColumn(), MofNCompleteColumn()]
    if keyframes:
        columns.append(TextColumn("{task.fields[kf]} keyframes"))
    with Progress(*columns, TimeRemainingColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task("frames", total=None, kf=0)

        def progress(done: int, total: int, kf: int = 0) -> None:
            bar.update(task, completed=done, total=total, kf=kf)

        yield progress


def stage_notice(name: str) -> None:
    """One line on stderr when a pipeline stage starts (terminal only, like the progress bars)."""
    if err_console.is_terminal and name != "tracking":
        err_console.print(f"[dim]{name}...[/dim]")


def version_callback(value: bool) -> None:
    if value:
        console.print(f"pipemap {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=version_callback, is_eager=True,
                                 help="Print the version."),
) -> None:
    """Metric maps of pipe networks from a crawler robot's single camera."""


@app.command()
@friendly
def info(
    dataset: Path = typer.Argument(..., help="Dataset folder or its dataset.yaml."),
    quick: bool = typer.Option(False, "--quick", help="Do not read every frame (readable, repeated and damaged frames "
                               "are then not counted)."),
) -> None:
    """Check a dataset folder against the format and summarise it; reads every frame once to count the
    readable, repeated and damaged ones."""
    from pipemap.dataset import FootageLog, load_dataset

    ds = load_dataset(dataset)
    n = len(ds)
    if n == 0:
        raise PipemapError("the recording holds no frames", ds.source.path)
    log = FootageLog()
    first = None
    if quick:
        first = next(iter(list(ds.frames(stop=1, log=log))), None)  # reads and checks one frame (size, gain mask)
    else:
        with frame_progress("checking frames") as progress:
            for frame in ds.frames(log=log):
                first = first if first is not None else frame
                progress(frame.index + 1, n)
    if first is None and not quick:
        detail = f": {log.damage[0].line()}" if log.damage else ""
        raise PipemapError(f"none of the {n} frames can be read{detail}", ds.source.path)
    unchecked = "not checked (--quick)"
    times = ds.times()
    table = Table(title=f"dataset {ds.name}", show_header=False)
    table.add_row("folder", str(ds.root))
    table.add_row("recording", ds.describe())
    table.add_row("frames", f"{n} ({times[-1] + ds.frame_period:.1f} s at {ds.fps:g} fps)")
    if abs(ds.frame_period * ds.fps - 1.0) > 1e-6:
        table.add_row("frame rate", f"the recording's frames are {1.0 / ds.frame_period:.3g} per second, "
                                    f"dataset.yaml says {ds.fps:g}")
    table.add_row("readable", unchecked if quick else f"{log.frames} of {n}")
    if quick:
        table.add_row("repeated", unchecked)
    else:
        spans = log.to_dict()["repeated_frames"]
        listed = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in spans[:8]) + (", ..." if len(spans) > 8 else "")
        table.add_row("repeated", f"{len(log.repeated)} ({listed})" if log.repeated else "none")
    drops = ds.drops()
    if not ds.source.timed:
        dropped = "not known (the frames carry no times)"
    else:
        where = ", ".join(str(i) for i, _ in drops[:8]) + (", ..." if len(drops) > 8 else "")
        gaps = f"{len(drops)} gap{'s' if len(drops) > 1 else ''}"
        dropped = f"{sum(k for _, k in drops)} in {gaps} (before frame{'s' if len(drops) > 1 else ''} {where})" \
            if drops else "none"
    table.add_row("dropped", dropped)
    if quick:
        cut = ds.source.cut()  # known without decoding
        damage = unchecked + (f"; {cut.line()}" if cut is not None else "")
    else:
        damage = "; ".join(d.line() for d in log.damage) or "none"
    table.add_row("damage", damage)
    method, why = ds.deinterlacing
    table.add_row("de-interlacing", f"{method} (auto: {why})" if ds.deinterlace == "auto" else method)
    if ds.mask is not None:
        table.add_row("mask", f"{ds.mask_path} ({ds.mask.mean():.0%} of the pixels usable)")
    table.add_row("camera", repr(ds.camera))
    table.add_row("pipe radius", f"{ds.radius_m:.4f} m")
    table.add_row("gain mask", str(ds.gain_mask_path) if ds.has_gain_mask else "none")
    if first is not None:
        table.add_row("first frame mean grey", f"{float(first.image.mean()):.1f}")
    gt = ds.ground_truth_poses()
    table.add_row("ground truth", f"{len(gt)} poses, path {gt.path_length():.3f} m" if gt is not None else "none")
    console.print(table)


@app.command()
@friendly
def settings(
    config: Optional[Path] = typer.Option(None, "--config", help="YAML settings file."),
    set_: List[str] = typer.Option([], "--set", help="Override one setting: section.key=value (repeatable)."),
) -> None:
    """Print the effective settings (the papers' values unless overridden) as YAML."""
    import yaml

    s = _load_settings(config, set_)
    typer.echo(yaml.safe_dump(s.to_dict(), sort_keys=False), nl=False)


@app.command()
@friendly
def simulate(
    preset: str = typer.Argument(..., help="Scene to render (listed above)."),
    out: Path = typer.Option(..., "--out", help="Dataset folder to create (must not exist or be empty)."),
    width: Optional[int] = typer.Option(None, "--width", help="Image width (intrinsics scale with it)."),
    height: Optional[int] = typer.Option(None, "--height", help="Image height."),
    frames: Optional[int] = typer.Option(None, "--frames", help="Render only the first N frames of the route."),
    seed: int = typer.Option(0, "--seed", help="Seed of textures, wobble, speed and sensor noise."),
    route: Optional[str] = typer.Option(None, "--route",
                                        help="The preset's route variant (e.g. A, B, forward-reverse)."),
    spacing: Optional[float] = typer.Option(None, "--spacing", help="Metres between frames (default: the preset's)."),
    motion_blur: int = typer.Option(1, "--motion-blur", help="Sub-frames averaged per frame (1: no blur)."),
    texture: Optional[str] = typer.Option(None, "--texture", help="Wall style: procedural, brick or gravel (photos)."),
    specular: Optional[float] = typer.Option(None, "--specular", help="Strength of the wall's highlight (default: "
                                             "the preset's; 0: a matte wall)."),
    workers: Optional[int] = typer.Option(None, "--workers", help="Rendering processes (default: one per core)."),
    camera_effects: Optional[str] = typer.Option(
        None, "--camera-effects", help="Inspection footage's defects: a profile ("
        + ", ".join(__import__("pipemap.sim.effects", fromlist=["PROFILES"]).PROFILES)
        + ") or a YAML file of CameraEffects (may start from 'profile: NAME'): video, overlay, gain, shutter, "
        "interlace, link. Default: the preset's (none for most)."),
    force: bool = FORCE_OPTION,
) -> None:
    """Render a synthetic dataset with exact ground truth (dataset.yaml, images/ or a video, ground_truth/)."""
    from pipemap.output import forced
    from pipemap.sim.simulate import simulate as render_dataset
    from pipemap.trajectory import read_tum

    with forced(out, force), frame_progress(f"rendering {preset}") as progress:
        render_dataset(preset, out, width=width, height=height, frames=frames, seed=seed, route=route,
                       progress=progress, spacing_m=spacing, motion_blur=motion_blur, texture=texture,
                       workers=workers, effects=camera_effects, specular=specular)
    poses = out / "ground_truth" / "poses.tum"
    n = len(read_tum(poses)) if poses.exists() else len(list((out / "images").glob("*.png")))
    console.print(f"{preset}: {n} frames written to {out}")


simulate.__doc__ = (simulate.__doc__ or "") + "\n\n" + "\n\n".join(
    f"{k}: {v}" for k, v in __import__("pipemap.sim.presets", fromlist=["list_presets"]).list_presets().items())


def parse_board(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise PipemapError(f"expected inner corners as COLSxROWS, e.g. 9x6, got {text!r}", "--board") from None
    if cols < 2 or rows < 2:
        raise PipemapError("a board needs at least 2x2 inner corners", "--board")
    return cols, rows


@app.command()
@friendly
def calibrate(
    images: str = typer.Argument(..., help='Glob of checkerboard images, e.g. "calib/*.png".'),
    board: str = typer.Option("9x6", "--board", help="Inner corners, columns x rows."),
    square: float = typer.Option(0.025, "--square", help="Square size in metres."),
    model: str = typer.Option("polynomial", "--model", help="polynomial | kannala_brandt | pinhole."),
    out: Path = typer.Option(Path("camera.yaml"), "--out", help="Camera file to write."),
    max_theta_deg: Optional[float] = typer.Option(None, "--max-theta-deg", help="Field of view half-angle to record."),
    fix: List[str] = typer.Option([], "--fix", help="Keep a parameter at its initial value (repeatable), e.g. k3."),
    folds: int = typer.Option(0, "--folds", help="Cross-validate in N folds (>= 2; leave-one-out when N >= the views): "
                              "each view's error when calibrated without it. 0: off."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output file."),
) -> None:
    """Calibrate a camera from checkerboard images: RMS and per-view reprojection error, then the camera block."""
    from pipemap.camera import MODELS
    from pipemap.camera.calibration import calibrate_images, save_calibration
    from pipemap.camera.crossval import cross_validate
    from pipemap.output import check_new_file, replacing

    if model not in MODELS:
        raise PipemapError(f"unknown camera model {model!r} (expected one of {', '.join(MODELS)})", "--model")
    if not square > 0:
        raise PipemapError("must be positive", "--square")
    if folds < 0 or folds == 1:
        raise PipemapError("must be 0 (off) or at least 2", "--folds")
    cols_rows = parse_board(board)
    check_new_file(out, force)
    paths = expand_glob(images)
    with console.status(f"calibrating {model} from {len(paths)} images"):
        result = calibrate_images(paths, cols_rows, square, model, max_theta_deg=max_theta_deg, fix=tuple(fix),
                                  source=images)
    cv = None
    if folds:
        with console.status(f"cross-validating in {min(folds, len(result.corners))} folds"):
            try:
                cv = cross_validate(result.corners, cols_rows, square, model, result.camera.width, result.camera.height,
                                    folds, max_theta_deg=max_theta_deg, fix=tuple(fix))
            except PipemapError as exc:
                raise PipemapError(exc.message, images, "--folds") from None
    title = f"{model} calibration: RMS {result.rms_px:.3f} px over {len(result.images)} views"
    if cv is not None:
        title += f"; held out in {cv.folds} folds {cv.held_out_rms_px:.3f} px"
    table = Table(title=title)
    table.add_column("image")
    table.add_column("RMS (px)", justify="right")
    if cv is not None:
        table.add_column("held out (px)", justify="right")
    for k, (path, rms) in enumerate(zip(result.images, result.per_view_rms)):
        left_out = sum(1 for v, _ in result.rejected if v == result.used[k])
        cells = [f"{rms:.3f}" + (f" ({left_out} corner{'s' * (left_out > 1)} left out)" if left_out else "")]
        table.add_row(Path(path).name, *cells, *([f"{cv.held_out_rms[k]:.3f}"] if cv is not None else []))
    for path, why in result.skipped:
        table.add_row(Path(path).name, f"skipped: {why}")
    console.print(table)
    console.print(repr(result.camera), markup=False)
    with replacing(out) as tmp:
        save_calibration(tmp, result, cv)
    console.print(f"camera written to {out}")


@app.command("gain-mask")
@friendly
def gain_mask(
    images: str = typer.Argument(..., help='Glob of white-card images, e.g. "card/*.png".'),
    out: Path = typer.Option(Path("gain_mask.png"), "--out", help="16-bit PNG to write."),
    sigma: Optional[float] = typer.Option(None, "--sigma",
                                          help="Gaussian smoothing in pixels (default from settings)."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output file."),
) -> None:
    """Build a flat-field gain mask from white-card images (2010 report, section 3.2)."""
    from pipemap.config import Settings
    from pipemap.gain_mask import build_gain_mask, save_gain_mask
    from pipemap.output import check_new_file, replacing

    check_new_file(out, force)
    paths = expand_glob(images)
    mask, skipped = build_gain_mask(paths, sigma if sigma is not None else Settings().gain_mask.sigma_px)
    for p, why in skipped:
        err_console.print(f"skipped {p}: {why}", markup=False)
    with replacing(out) as tmp:
        save_gain_mask(tmp, mask)
    rel = mask / mask.max()
    console.print(
        f"gain mask from {len(paths) - len(skipped)} images -> {out} "
        f"(relative gain {rel.min():.3f}..1.000, mean {rel.mean():.3f})"
    )


def _load_settings(config: Optional[Path], set_: List[str]):
    from pipemap.config import load_settings

    return load_settings(config, set_)


CONFIG_OPTION = typer.Option(None, "--config", help="YAML settings file (defaults: the papers' values).")
SET_OPTION = typer.Option([], "--set", help="Override one setting: section.key=value (repeatable).")


@app.command()
@friendly
def track(
    dataset: Path = typer.Argument(..., help="Dataset folder or its dataset.yaml."),
    out: Path = typer.Option(..., "--out", help="Result folder to create (must not exist or be empty)."),
    config: Optional[Path] = CONFIG_OPTION,
    set_: List[str] = SET_OPTION,
    force: bool = FORCE_OPTION,
) -> None:
    """Run the fisheye front end alone: keyframes, feature tracks, relative poses (unit steps).

    Writes frames.csv, trajectory.tum (rotations exact, one unit of translation per keyframe
    step), tracks.csv and run.json.
    """
    from pipemap.frontend import run_tracking
    from pipemap.output import forced

    settings = _load_settings(config, set_)
    with forced(out, force, [dataset]), frame_progress("tracking", keyframes=True) as progress:
        result = run_tracking(dataset, out, settings, progress=progress)
    console.print(f"{result.image_count} frames, {len(result.keyframes)} keyframes, "
                  f"{result.frames_per_second:.1f} frames/s -> {out}")


@app.command("run")
@friendly
def run_command(
    dataset: Path = typer.Argument(..., help="Dataset folder or its dataset.yaml."),
    out: Path = typer.Option(..., "--out", help="Result folder to create (must not exist or be empty)."),
    method: str = typer.Option("auto", "--method",
                               help="auto | network (alias fisheye) | dense-full-search | dense-lk | dense-hybrid | "
                                    "sparse-cylinder. auto: network for a camera looking along the pipe, "
                                    "dense-hybrid for one looking at its wall."),
    config: Optional[Path] = CONFIG_OPTION,
    set_: List[str] = SET_OPTION,
    strict: bool = typer.Option(False, "--strict", help="exit with status 3 when any section is rated suspect or "
                                "failed (the result folder is still written)"),
    force: bool = FORCE_OPTION,
) -> None:
    """Map a dataset and write trajectory.tum, frames.csv, run.json (and sparse.ply, or unrolled/).

    network (any camera looking along the pipe: fisheye or forward-looking perspective): feature
    tracking, straight/junction labels, metric straight-section VO with cylinder-regularised
    sliding-window SBA, tees, loop closure, appearance maps. dense-* (dense-hybrid for a camera
    looking at the wall of a straight pipe, the 2010 report): image registration by full search,
    Lucas-Kanade or both; sparse-cylinder: sparse VO held to the wall. auto measures which way the
    camera looks over the first frames and says what it chose."""
    from pipemap.output import forced

    settings = _load_settings(config, set_)
    with forced(out, force, [dataset]):
        quality = _map(dataset, out, method, settings)
    _verdict(quality, strict)


def _map(dataset: Path, out: Path, method: str, settings):
    """`pipemap run` without its output rule: map with `method` and print what was found; the self-checks."""
    from pipemap.methods import NETWORK_METHODS, check_method, choose_method, map_dataset
    from pipemap.straight import DENSE_METHODS

    check_method(method, key="--method")
    if method == "auto":
        with console.status("checking which way the camera looks"):
            method, view = choose_method(dataset, settings)
        console.print(f"method: {method} ({view.reason()})", markup=False)
    if method in DENSE_METHODS:
        with frame_progress(method) as progress:
            dense = map_dataset(dataset, out, method, settings, progress=progress)
        console.print(f"{len(dense.indices)} frames registered ({method}) -> {out}")
        if dense.mount is not None:
            console.print(dense.mount.line(), markup=False)
        console.print(f"scale: {dense.zeta:.1f} px/m from {dense.zeta_source}", markup=False)
        return dense.quality
    if method not in NETWORK_METHODS:
        with frame_progress(method) as progress:
            sparse = map_dataset(dataset, out, method, settings, progress=progress)
        console.print(f"{sparse.frames} frames, {len(sparse.indices)} keyframes ({method}), camera offset from "
                      f"the axis C_X {sparse.offset[0] * 1e3:.2f} mm, C_Y {sparse.offset[1] * 1e3:.2f} mm -> {out}")
        if sparse.mount is not None:
            console.print(sparse.mount.line(), markup=False)
        return sparse.quality
    with frame_progress("tracking", keyframes=True) as progress:
        result = map_dataset(dataset, out, method, settings, progress=progress, on_stage=stage_notice)
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in result.seconds.items())
    console.print(f"{result.image_count} frames, {result.keyframe_count} keyframes, "
                  f"{len(result.junctions)} junctions, {len(result.map.points)} points -> {out}  ({stages})")
    if result.footage.repeated or result.footage.drops or result.footage.damage:
        console.print(result.footage.line(), markup=False)
    if result.mask is not None and result.mask.usable is not None:
        m = result.mask.to_dict()
        console.print(f"mask: {100 * m['masked_fraction']:.1f} % of the image not used"
                      + (" (dataset mask" + (" and static overlay)" if result.mask.static else ")") if m["given"]
                         else " (static overlay found in the footage)"), markup=False)
    return result.quality


@app.command()
@friendly
def batch(
    manifest: str = typer.Argument(..., help="A manifest of runs (.yaml or .csv: dataset, and optionally name, "
                                   "method, config, set) or a quoted glob of dataset folders, e.g. \"runs/*\"."),
    out: Path = typer.Option(..., "--out", help="Folder for one result folder per run (named after the run) and "
                             "batch.csv; the same command again goes on where the last one stopped."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Address of a running Dask scheduler, e.g. "
                                            "tcp://10.0.0.5:8786 (default: a cluster on this machine)."),
    workers: Optional[int] = typer.Option(None, "--workers", min=1, help="Workers of the local cluster, one run at "
                                          "a time each (default: batch.workers, one per core)."),
    method: str = typer.Option("auto", "--method", help="Method of the runs whose manifest entry names none (as "
                               "pipemap run --method)."),
    config: Optional[Path] = CONFIG_OPTION,
    set_: List[str] = SET_OPTION,
) -> None:
    """Map many datasets at once, one Dask task per run, and print (and write batch.csv) each run's status,
    frames, keyframes, junctions, wall time and problems. Runs already complete are skipped; a run that
    fails is reported in one line and the others go on; exit status 1 when any failed."""
    try:
        table = _batch(manifest, out, scheduler, workers, method, config, set_)
    except KeyboardInterrupt:
        err_console.print(f"pipemap: interrupted; {out} holds only complete result folders (see "
                          f"{out / 'batch.csv'}); the same command goes on", markup=False, highlight=False)
        raise typer.Exit(130) from None
    _batch_table(table)
    failed = sum(1 for row in table if row["status"] == "failed")
    if failed:
        raise typer.Exit(1)


def _batch(manifest: str, out: Path, scheduler: Optional[str], workers: Optional[int], method: str,
           config: Optional[Path], set_: List[str]) -> list[dict]:
    from pipemap.batch.engine import dask_client, run_batch
    from pipemap.batch.manifest import read_runs
    from pipemap.methods import check_method

    check_method(method, key="--method")
    settings = _load_settings(config, set_).batch  # a wrong batch-wide setting stops the batch at once
    if scheduler and workers:
        raise PipemapError("sets the local cluster's size; the cluster at --scheduler has its own workers",
                           "--workers")
    runs = read_runs(manifest, method, config, tuple(set_))

    def started(client, todo) -> None:
        where = f"the cluster at {scheduler}" if scheduler else "a local cluster"
        workers_up = len(client.nthreads())
        console.print(f"{len(todo)} of {len(runs)} runs to map on {where} ({workers_up} workers)", markup=False)
        console.print(f"dashboard: {client.dashboard_link}", markup=False, highlight=False, soft_wrap=True)

    def progress(p) -> None:
        row = p.row
        what = f"{row['frames']} frames in {row['seconds']} s" if row["status"] == "mapped" else row["problems"]
        console.print(f"[{p.done}/{p.total}] {row['run']}: {row['status']}, {what}  (batch: "
                      f"{p.frames_per_second:.1f} frames/s)", markup=False, highlight=False)

    table = run_batch(runs, out, lambda: dask_client(scheduler, settings, workers), settings.threads_per_run,
                      on_start=started, on_progress=progress, local=not scheduler)
    if not any(row["status"] in ("mapped", "failed") for row in table):
        console.print(f"all {len(table)} runs were complete already; nothing to map", markup=False)
    return table


def _batch_table(rows: list[dict]) -> None:
    """The summary as a table, then each run's problems on a line of its own (they are sentences)."""
    columns = ("run", "status", "method", "frames", "keyframes", "junctions", "seconds", "quality")
    table = Table(title="batch")
    for col in columns:
        table.add_column(col, justify="right" if col in ("frames", "keyframes", "junctions", "seconds") else "left")
    style = {"mapped": "green", "skipped": "dim", "failed": "red", "interrupted": "yellow"}
    for row in rows:
        cells = [escape(str(row[c])) for c in columns]
        cells[1] = f"[{style[row['status']]}]{cells[1]}[/]" if row["status"] in style else cells[1]
        table.add_row(*cells)
    console.print(table)
    for row in rows:
        if row["problems"]:
            console.print(f"{row['run']}: {row['problems']}", markup=False, highlight=False, soft_wrap=True)


def _verdict(quality, strict: bool) -> None:
    """The sections' ratings as a table (all of them when any is not good), then the one-line verdict;
    with --strict, exit status 3 unless the map is good."""
    if quality is None:
        return
    from pipemap.quality import GOOD

    if quality.rating != GOOD:
        table = Table(title="self-checks", show_lines=False)
        for col in ("section", "kind", "frames", "keyframes", "rating", "why"):
            table.add_column(col)
        for s in quality.sections:
            table.add_row(str(s.number), s.kind, f"{s.first_frame}-{s.last_frame}", str(s.keyframes), s.rating,
                          "; ".join(s.reasons))
        for gap in quality.gaps:
            table.add_row("gap", "", f"{gap['after_frame']}-{gap['before_frame']}", "", "", "not bridged")
        console.print(table)
    style = {"good": "green", "suspect": "yellow", "failed": "red"}[quality.rating]
    console.print(f"[{style}]{escape(quality.line())}[/{style}]", highlight=False)
    if strict and quality.rating != GOOD:
        raise typer.Exit(3)


@app.command()
@friendly
def evaluate(
    result_dir: Path = typer.Argument(..., help="Result folder with trajectory.tum (and junctions.yaml)."),
    dataset_dir: Path = typer.Argument(..., help="Dataset folder with ground_truth/."),
    force: bool = typer.Option(False, "--force", help="Replace the result's metrics.json of an earlier evaluation."),
) -> None:
    """Compare a result with the ground truth; write RESULT_DIR/metrics.json and print the tables."""
    from pipemap.evaluation import evaluate as evaluate_result
    from pipemap.evaluation import print_tables

    metrics = result_dir / "metrics.json"
    if metrics.exists() and not force:
        raise PipemapError("already exists; pass --force to replace it", metrics)
    result = evaluate_result(result_dir, dataset_dir)
    print_tables(result, console)
    console.print(f"metrics written to {result_dir / 'metrics.json'}")


def _pair(text: str, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise PipemapError(f"expected numbers separated by commas, got {text!r}", what) from None
    if len(values) not in (2, 3):
        raise PipemapError(f"expected 2 or 3 numbers, got {text!r}", what)
    return values


@app.command()
@friendly
def locate(
    result_dir: Path = typer.Argument(..., help="Result folder of pipemap run."),
    frame: int = typer.Option(..., "--frame", help="Frame index (as in frames.csv)."),
    pixel: List[str] = typer.Option(..., "--pixel", help="Pixel U,V (repeatable)."),
    config: Optional[Path] = typer.Option(None, "--config", help="YAML settings file (locate.* sigmas)."),
    set_: List[str] = typer.Option([], "--set", help="Override one setting: section.key=value (repeatable)."),
) -> None:
    """The wall point seen at a pixel: chainage, clock position (deg, 0 = 12 o'clock, clockwise looking along
    the survey) and 3D point, with one-sigma uncertainties. For many pixels use `pipemap observations`."""
    from pipemap.inspection.locate import locate_pixels, open_result

    s = _load_settings(config, set_)
    px = [_pair(p, "--pixel")[:2] for p in pixel]
    loc = locate_pixels(open_result(result_dir), frame, px, s.locate)
    how = {"keyframe": "a keyframe's own pose",
           "interpolated": "pose interpolated between the keyframes either side",
           "registered": "position interpolated between the keyframes, orientation registered to the nearest one's "
                         "image"}.get(loc.pose, loc.pose)
    console.print(f"frame {frame}: {how}", highlight=False)
    for (u, v), ok, c, k, p, sc, sk in zip(px, loc.ok, loc.chainage, loc.clock_deg, loc.points, loc.sigma_chainage,
                                           loc.sigma_clock_deg):
        if not ok:
            console.print(f"{u:g},{v:g}: the ray meets no mapped wall", highlight=False)
            continue
        hours = round(k / 30, 1) % 12 or 12.0
        console.print(f"{u:g},{v:g}: chainage {c:.3f} m +/- {sc:.3f}, clock {k:.1f} deg +/- {sk:.1f} "
                      f"({hours:.1f} o'clock), point {p[0]:.4f} {p[1]:.4f} {p[2]:.4f}", highlight=False)


@app.command()
@friendly
def observations(
    result_dir: Path = typer.Argument(..., help="Result folder of pipemap run."),
    obs_csv: Path = typer.Argument(..., help="CSV of observations: frame,u,v[,u2,v2][,id,code,remark,continuous]."),
    out: Optional[Path] = typer.Option(None, "--out", help="Output CSV (default RESULT/observations.csv)."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output file."),
) -> None:
    """Locate an inspector's observations: write them back with section, nodes, chainage and clock from/to."""
    from pipemap.inspection.locate import open_result
    from pipemap.inspection.observations import locate_observation, read_observations, write_observations

    target = out or result_dir / "observations.csv"
    rows = read_observations(obs_csv)
    res = open_result(result_dir)
    located = [locate_observation(res, r) for r in rows]
    write_observations(target, located, force)
    console.print(f"{len(located)} observations located, written to {target}", highlight=False)


@app.command()
@friendly
def export(
    result_dir: Path = typer.Argument(..., help="Result folder of pipemap run."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for sections.csv and network.geojson "
                                       "(default: the result folder)."),
    start_manhole: Optional[str] = typer.Option(None, "--start-manhole", help="E,N[,Z] of the start manhole."),
    end_manhole: Optional[str] = typer.Option(None, "--end-manhole", help="E,N[,Z] of the end manhole."),
    crs: Optional[str] = typer.Option(None, "--crs", help="The manholes' projected coordinate system, e.g. "
                                      "EPSG:27700 (written as the GeoJSON crs member)."),
    force: bool = typer.Option(False, "--force", help="Replace existing files."),
) -> None:
    """Sections as CSV and the network as GeoJSON (local metric frame; georeferenced with both manholes)."""
    from pipemap.inspection.export import dumps_geojson, network_geojson, sections_csv
    from pipemap.inspection.result_route import load_route
    from pipemap.mapping.pieces import read_run
    from pipemap.output import atomic_write_text, check_new_file

    if (start_manhole is None) != (end_manhole is None):
        raise PipemapError("give both --start-manhole and --end-manhole, or neither")
    folder = out or result_dir
    route = load_route(result_dir, read_run(result_dir))
    a = None if start_manhole is None else _pair(start_manhole, "--start-manhole")
    b = None if end_manhole is None else _pair(end_manhole, "--end-manhole")
    doc = network_geojson(route, a, b, crs)
    if out is not None and not out.exists():
        if not out.parent.is_dir():
            raise PipemapError("folder does not exist", out.parent)
        out.mkdir()
    for name in ("sections.csv", "network.geojson"):
        check_new_file(folder / name, force)
    atomic_write_text(folder / "sections.csv", sections_csv(route))
    atomic_write_text(folder / "network.geojson", dumps_geojson(doc))
    console.print(f"sections.csv and network.geojson written to {folder} (scale {doc['properties']['scale']})",
                  highlight=False)


@app.command()
@friendly
def report(
    result_dir: Path = typer.Argument(..., help="Result folder (of pipemap run or pipemap demo)."),
    out: Optional[Path] = typer.Option(None, "--out", help="The page to write (default RESULT/viewer.html)."),
    observations: Optional[Path] = typer.Option(None, "--observations", help="A located observations CSV "
                                                "(default RESULT/observations.csv when there is one)."),
    config: Optional[Path] = CONFIG_OPTION,
    set_: List[str] = SET_OPTION,
    force: bool = typer.Option(False, "--force", help="Replace an existing page (once the new one is complete)."),
) -> None:
    """Write a self-contained HTML viewer of a result: the network in 3D with a sample of the appearance map,
    every unrolled wall with a chainage x clock grid (click for chainage and clock position), the deformation
    plot and the observations. It opens from the file with no server and no network."""
    from pipemap.viewer import write_viewer

    summary = write_viewer(result_dir, out, observations, _load_settings(config, set_), force=force)
    extra = "" if summary.observations is None else f", {summary.observations} observations ({summary.placed} on walls)"
    console.print(f"viewer: {summary.path} ({summary.bytes / 1e6:.1f} MB, {summary.walls} walls, "
                  f"{summary.cloud_points} map points{extra})", markup=False, highlight=False, soft_wrap=True)
    for note in summary.missing:
        console.print(f"note: {note}", markup=False, highlight=False, soft_wrap=True)


@app.command()
@friendly
def demo(
    out: Path = typer.Option(Path("pipemap-demo"), "--out", help="Folder for dataset/ and result/ (must be empty)."),
    force: bool = typer.Option(False, "--force", help="Replace the dataset/ and result/ of an earlier demo."),
) -> None:
    """Simulate the demo-loop network, map it, evaluate against ground truth and write report.html and
    viewer.html."""
    from pipemap.demo import run_demo

    with frame_progress("demo: rendering, then mapping") as bar:
        summary = run_demo(out, progress=lambda stage, done, total: bar(done, total), force=force)
    table = Table(title=f"pipemap demo ({summary.seconds['total']:.0f} s)", show_header=False)
    table.add_row("frames / keyframes", f"{summary.frames} / {summary.keyframes}")
    table.add_row("time", ", ".join(f"{k} {v:.1f} s" for k, v in summary.seconds.items() if k != "total"))
    table.add_row("path length error", "–" if summary.path_length_error_pct is None
                  else f"{summary.path_length_error_pct:+.2f} %")
    table.add_row("ATE RMSE (rigid)", "–" if summary.ate_rmse_m is None else f"{1000 * summary.ate_rmse_m:.1f} mm")
    for row in summary.tee_errors:
        table.add_row(f"tee distance {row['pair']}", f"{row['estimate_m']:.3f} m vs {row['truth_m']:.3f} m "
                      f"({row['error_pct']:+.2f} %)")
    if summary.appearance_points is not None:
        table.add_row("appearance map", f"{summary.appearance_points} points")
    wall = summary.appearance_wall or {}
    for name in ("global", "local"):
        stats = wall.get(name)
        if stats:
            table.add_row(f"map vs true wall ({name})", f"median {stats['median_mm']:.2f} mm, "
                          f"{stats['within_2mm_pct']:.1f} % within 2 mm")
    console.print(table)
    for note in summary.notes:
        console.print(f"note: {note}", markup=False)
    console.print(f"report: {summary.report}", markup=False)
    console.print(f"viewer: {summary.viewer}", markup=False)


def run() -> None:  # pragma: no cover - console entry for `python -m pipemap`
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(run())
