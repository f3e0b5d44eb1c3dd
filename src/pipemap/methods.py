"""One dataset mapped by the method named (or the one `auto` measures): the code path of `pipemap run`,
shared by `pipemap batch` so that a batch's result folders are the ones `pipemap run` writes."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from pipemap.config import Settings
from pipemap.errors import PipemapError

NETWORK_METHODS = ("network", "fisheye")  # fisheye: the network pipeline's older name


def method_names() -> tuple[str, ...]:
    from pipemap.straight import DENSE_METHODS
    from pipemap.straight.sparse.run import SPARSE_METHOD

    return ("auto", *NETWORK_METHODS, *DENSE_METHODS, SPARSE_METHOD)


def check_method(method: str, where: str | Path | None = None, key: str | None = None) -> None:
    """PipemapError unless `method` is one that `pipemap run --method` takes."""
    names = method_names()
    if method not in names:
        raise PipemapError(f"unknown method {method!r} (expected {', '.join(n for n in names if n != 'fisheye')})",
                           where, key)


def choose_method(dataset: Path, settings: Settings):
    """`auto`: the method for the way the camera looks, and the ViewReport that says why."""
    from pipemap.dataset import load_dataset
    from pipemap.view import camera_view

    view = camera_view(load_dataset(dataset), settings)
    return view.method, view


def map_dataset(dataset: Path, out: Path, method: str, settings: Settings,
                progress: Callable | None = None, on_stage: Callable[[str], None] | None = None):
    """Map `dataset` into the result folder `out` (written atomically) with a resolved method (not auto).
    Returns the method's result: PipelineResult (network), DenseResult or SparseResult.
    progress(done, total[, keyframes]) after every frame; on_stage(name) as the network pipeline's stages start."""
    from pipemap.straight import DENSE_METHODS, run_dense
    from pipemap.straight.sparse.run import SPARSE_METHOD, run_sparse

    check_method(method, key="--method")
    if method in DENSE_METHODS:
        return run_dense(dataset, out, settings, method, progress=progress)
    if method == SPARSE_METHOD:
        return run_sparse(dataset, out, settings, progress=progress)
    if method == "auto":
        raise ValueError("resolve auto with choose_method first")
    from pipemap.pipeline import run_pipeline

    return run_pipeline(dataset, out, settings, progress=progress, on_stage=on_stage)


__all__ = ["NETWORK_METHODS", "method_names", "check_method", "choose_method", "map_dataset"]
