"""The batch on Dask: one task per run on a local cluster or on the cluster at a scheduler's address.
Complete runs are skipped, a failed run is reported and the others go on, a run whose worker dies is
started again on another, and Ctrl-C leaves only complete result folders."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from pipemap.batch.manifest import SUMMARY_FILE, BatchRun
from pipemap.batch.summary import read_result, summary_row, write_summary
from pipemap.batch.task import FAILED, INTERRUPTED, MAPPED, PENDING, SKIPPED, map_run
from pipemap.config import BatchSettings
from pipemap.errors import PipemapError


@dataclass(frozen=True)
class BatchProgress:
    row: dict  # the summary row of the run just finished
    done: int  # runs finished in this batch
    total: int  # runs this batch had to map
    frames: int  # frames mapped in this batch so far
    seconds: float  # since the first task was submitted

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0


def local_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@contextlib.contextmanager
def dask_client(scheduler: str | None, batch: BatchSettings, workers: int | None = None) -> Iterator:
    """A Client of the scheduler at `scheduler`, or of a local cluster of single-threaded workers (one per
    core unless `workers` or batch.workers says) whose scheduler starts a run again up to batch.retries times
    when its worker dies."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise PipemapError(f"cannot reach a Dask scheduler: {first}", "--scheduler") from None
        with contextlib.closing(client):
            yield client
        return
    n = workers or batch.workers or local_cores()
    extra = {"preload": ["pipemap.batch.worker"]} if batch.processes else {}
    # Dask's workers start with MALLOC_TRIM_THRESHOLD_ set, which also turns off glibc's growing mmap threshold:
    # every frame-sized array is then mapped and faulted in anew (measured: a run's system time 0.3 s -> 6 s).
    with dask.config.set({"distributed.scheduler.allowed-failures": batch.retries,
                          "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        # A run's failure comes back with its task; the cluster's own logs are its machinery (a worker whose
        # scheduler went away at Ctrl-C logs a heartbeat traceback at ERROR), not the user's business.
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=batch.processes,
                               silence_logs=logging.CRITICAL, **extra)
    try:
        with Client(cluster) as client:
            yield client
    finally:
        cluster.close()


def prepare_out(out: Path) -> None:
    """The batch's folder: new, empty, or one a batch wrote (it holds batch.csv) and so may go on."""
    if out.exists() and not out.is_dir():
        raise PipemapError("exists and is not a folder", out)
    if out.is_dir() and any(out.iterdir()) and not (out / SUMMARY_FILE).is_file():
        raise PipemapError(f"exists, is not empty and holds no {SUMMARY_FILE} of an earlier batch; choose another "
                           "--out", out)
    out.mkdir(parents=True, exist_ok=True)


def remove_partials(out: Path, names) -> None:
    """Temporary folders of runs that did not finish (a worker that died, an interrupted batch)."""
    for name in names:
        for tmp in out.glob(f".{name}.partial-*"):
            shutil.rmtree(tmp, ignore_errors=True)


def _settings_changed(run: BatchRun, record: dict) -> bool:
    import json

    now = json.loads(json.dumps(run.settings.recorded())) if run.settings is not None else {}
    then = record.get("settings") or {}
    method = "network" if run.method == "fisheye" else run.method
    return (bool(then) and now != then) or method not in ("auto", record.get("method"))


def plan(runs: list[BatchRun], out: Path) -> tuple[dict[str, dict], list[BatchRun]]:
    """Rows of the runs that need no task (complete earlier, or unable to start) and the runs to map."""
    rows, todo = {}, []
    for run in runs:
        record = read_result(out / run.name)
        if record is not None:
            rows[run.name] = summary_row(run, out, SKIPPED)
            if _settings_changed(run, record):
                rows[run.name]["problems"] = "; ".join(filter(None, [
                    "mapped earlier with other settings or method (remove its folder to map it again)",
                    rows[run.name]["problems"]]))
        elif run.settings is None:
            rows[run.name] = summary_row(run, out, FAILED, reason=run.problem)
        else:
            todo.append(run)
    return rows, todo


def run_batch(runs: list[BatchRun], out: Path, client_factory: Callable[[], contextlib.AbstractContextManager],
              threads: int | None, on_start: Callable | None = None,
              on_progress: Callable[[BatchProgress], None] | None = None, local: bool = True) -> list[dict]:
    """Map every run not yet complete into out/<name>, one Dask task each, and write out/batch.csv.
    on_start(client, runs to map) once the cluster is up (not called when nothing is left to map);
    on_progress after every run. `local`: the cluster's workers end with the batch, so on Ctrl-C the
    interrupted runs' temporary folders can be removed (a remote worker finishes its run, atomically).
    Returns the summary rows in manifest order."""
    fresh = not out.exists()
    prepare_out(out)
    rows, todo = plan(runs, out)

    def summary(unfinished: str = PENDING) -> list[dict]:
        # a run can finish on its worker just before Ctrl-C reaches the batch: its folder is complete
        table = [rows.get(run.name) or summary_row(run, out, MAPPED if (out / run.name / "run.json").is_file()
                                                   else unfinished) for run in runs]
        write_summary(out / SUMMARY_FILE, table)
        return table

    summary()
    if not todo:
        return summary()
    remove_partials(out, [r.name for r in todo])
    try:
        with client_factory() as client:
            if on_start is not None:
                on_start(client, todo)
            _map_all(client, todo, out, threads, rows, on_progress)
    except KeyboardInterrupt:
        if local:
            remove_partials(out, [r.name for r in todo if r.name not in rows])
        summary(INTERRUPTED)
        raise
    except PipemapError:
        if fresh and all(row["status"] != MAPPED for row in rows.values()):  # no cluster: leave no trace
            shutil.rmtree(out, ignore_errors=True)
        raise
    remove_partials(out, [r.name for r in todo])  # left by workers that died mid-run
    return summary()


def _map_all(client, todo: list[BatchRun], out: Path, threads: int | None, rows: dict,
             on_progress: Callable[[BatchProgress], None] | None) -> None:
    from distributed import as_completed

    tag = uuid.uuid4().hex[:8]
    futures, run_of = [], {}
    for k, run in enumerate(todo):
        # earlier runs of the manifest first; the key names the run on the dashboard
        future = client.submit(map_run, run, str(out), threads, key=f"pipemap-run-{run.name}-{tag}", pure=False,
                               priority=len(todo) - k)
        futures.append(future)
        run_of[future.key] = run
    start, frames = time.perf_counter(), 0
    try:
        for future in as_completed(futures):
            run = run_of[future.key]
            rows[run.name] = _finished_row(future, run, out)
            if rows[run.name]["status"] == MAPPED and rows[run.name]["frames"] != "":
                frames += int(rows[run.name]["frames"])
            if on_progress is not None:
                on_progress(BatchProgress(rows[run.name], len([r for r in todo if r.name in rows]), len(todo), frames,
                                          time.perf_counter() - start))
    except BaseException:
        client.cancel(futures)
        raise


def _finished_row(future, run: BatchRun, out: Path) -> dict:
    from distributed import KilledWorker

    try:
        outcome = future.result()
    except KilledWorker:
        return summary_row(run, out, FAILED, reason="its worker died each time it was started (out of memory?)")
    except Exception as exc:  # noqa: BLE001 - the cluster's failure ends this run, not the batch
        first = str(exc).splitlines()[0] if str(exc) else ""
        return summary_row(run, out, FAILED, reason=f"task failed on the cluster: {type(exc).__name__}: {first}")
    return summary_row(run, out, outcome.status, outcome.seconds, outcome.reason)


__all__ = ["BatchProgress", "local_cores", "dask_client", "prepare_out", "remove_partials", "plan", "run_batch"]
