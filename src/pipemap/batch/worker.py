"""Set-up of a local cluster's worker processes (a Dask preload: `dask_setup` runs as each one starts)."""

from __future__ import annotations

import logging
import multiprocessing
import signal
import threading


def dask_setup(worker) -> None:
    """Ctrl-C reaches every process of the terminal's group: a worker process leaves it to the batch, which
    stops the cluster and removes the unfinished runs' temporary folders, instead of dying with a traceback."""
    if multiprocessing.parent_process() is not None and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    # When the batch stops the cluster, a worker still beating its heart to the scheduler logs the broken
    # connection with a traceback; a run's own failure comes back with its task, not through these logs.
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
