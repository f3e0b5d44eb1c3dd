"""The straight-section VO's own process (backend/straight_beside.py) outlives no run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie has ended
        return f.read().split()[2] != "Z"


def test_the_vo_process_ends_when_the_run_is_killed():
    """A run killed outright (SIGKILL: no None is ever sent) leaves no VO process waiting for keyframes."""
    script = textwrap.dedent("""
        import time
        from pipemap.backend.straight_beside import StraightVOBeside
        from pipemap.config import Settings
        from pipemap.sim.presets import fisheye_camera
        vo = StraightVOBeside(fisheye_camera(320, 240), 0.2, Settings())
        print(vo._process.pid, flush=True)
        time.sleep(60)
    """)
    run = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    child = int(run.stdout.readline())
    assert _alive(child)
    run.send_signal(signal.SIGKILL)
    run.wait()
    deadline = time.monotonic() + 10
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(child)
