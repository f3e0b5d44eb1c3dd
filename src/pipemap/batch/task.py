"""One run of a batch, as a Dask task on a worker: `pipemap run`'s code path, its failure as one line."""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from pipemap.batch.manifest import BatchRun
from pipemap.errors import PipemapError

MAPPED, SKIPPED, FAILED, PENDING, INTERRUPTED = "mapped", "skipped", "failed", "pending", "interrupted"


@dataclass(frozen=True)
class RunOutcome:
    name: str
    status: str  # MAPPED or FAILED
    seconds: float  # wall time on the worker
    reason: str | None = None  # why it failed, one line


@contextlib.contextmanager
def run_threads(threads: int | None) -> Iterator[None]:
    """OpenCV's and the BLAS/OpenMP pools' threads held to `threads` while one run maps (None: as they are);
    with one, the front end prepares frames on the run's own thread too. A worker per core then keeps each core
    on its own run instead of every run's threads waiting on the others'."""
    if threads is None:
        yield
        return
    import cv2
    from threadpoolctl import threadpool_limits

    from pipemap.pipeline import frames_prepared_in_turn

    before = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        with threadpool_limits(threads), (frames_prepared_in_turn() if threads == 1 else contextlib.nullcontext()):
            yield
    finally:
        cv2.setNumThreads(before)


def map_run(run: BatchRun, out_root: str, threads: int | None) -> RunOutcome:
    """Map one run into out_root/run.name as `pipemap run` does. Bad input and crashes come back as a FAILED
    outcome with one line, so the batch goes on; a worker that dies under the run has it started again elsewhere."""
    from pipemap.methods import choose_method, map_dataset

    start = time.perf_counter()
    try:
        if run.settings is None:
            raise PipemapError(run.problem or "no settings")
        with run_threads(threads):
            method = run.method
            if method == "auto":
                method, _ = choose_method(run.dataset, run.settings)
            map_dataset(run.dataset, Path(out_root) / run.name, method, run.settings)
    except PipemapError as exc:
        return RunOutcome(run.name, FAILED, time.perf_counter() - start, exc.line())
    except Exception as exc:  # noqa: BLE001 - one run's crash must not end the batch
        first = str(exc).splitlines()[0] if str(exc) else ""
        return RunOutcome(run.name, FAILED, time.perf_counter() - start,
                          f"internal error: {type(exc).__name__}: {first}")
    return RunOutcome(run.name, MAPPED, time.perf_counter() - start)


__all__ = ["MAPPED", "SKIPPED", "FAILED", "PENDING", "INTERRUPTED", "RunOutcome", "run_threads", "map_run"]
