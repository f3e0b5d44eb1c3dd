"""The straight-section VO in a second process, fed each keyframe once its class is final while the front end
is still tracking: data flows one way, so the tracking never waits for the window solves, and the VO gets
the same keyframes and classes in the same order as after the tracking (the same result).

On two cores the front end keeps about one and a half busy (its main thread and the thread that reads and
extracts the next frame); the window solves take the rest instead of running after it."""

from __future__ import annotations

import multiprocessing
import pickle
import queue

from pipemap.backend.section_vo import StraightResult, StraightVO
from pipemap.frontend.tracks import Keyframe

_POLL_S = 0.5


def _portable(exc: BaseException) -> BaseException:
    """The exception itself if it survives pickling, else a RuntimeError with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any exception that does not pickle
        return RuntimeError(f"{type(exc).__name__}: {exc}")


class _RunGone(Exception):
    """The run's process ended without closing the inbox (it was killed)."""


def _next(inbox):
    """The next keyframe; _RunGone once the run's process is gone (no None will come, and a process left
    waiting would outlive it)."""
    while True:
        try:
            return inbox.get(timeout=_POLL_S)
        except queue.Empty:
            parent = multiprocessing.parent_process()
            if parent is not None and not parent.is_alive():
                raise _RunGone from None


def _serve(camera, radius: float, settings, inbox, outbox) -> None:
    from threadpoolctl import threadpool_limits

    try:
        with threadpool_limits(1, user_api="blas"):  # as the run's own process: the same sums in the same order
            vo = StraightVO(camera, radius, settings, forget_spent=True)
            while (item := _next(inbox)) is not None:
                vo.add(*item)
            result = vo.finish()
        vo.keyframes = []  # the run has them: not sent back
        outbox.put(("ok", vo, result))
    except _RunGone:
        outbox.cancel_join_thread()  # nobody reads the outbox: leave at once
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the run
        outbox.put(("error", _portable(exc), None))


class StraightVOBeside:
    """StraightVO's add / finish, run in a second process. `finish(keyframes)` returns the VO (with these
    keyframes, the ones that were added) and its result; a failure there is raised here."""

    def __init__(self, camera, radius: float, settings):
        ctx = multiprocessing.get_context("spawn")  # the run's threads make fork unsafe
        self._inbox, self._outbox = ctx.Queue(), ctx.Queue()
        self._process = ctx.Process(target=_serve, args=(camera, radius, settings, self._inbox, self._outbox),
                                    name="pipemap-straight-vo", daemon=True)
        self._process.start()

    def add(self, kf: Keyframe, junction: bool = False) -> None:
        self._inbox.put((kf, bool(junction)))

    def finish(self, keyframes: list[Keyframe]) -> tuple[StraightVO, StraightResult]:
        self._inbox.put(None)
        while True:
            try:
                status, vo, result = self._outbox.get(timeout=_POLL_S)
                break
            except queue.Empty:
                if not self._process.is_alive():
                    raise RuntimeError("the straight-section VO process ended without a result "
                                       f"(exit code {self._process.exitcode})") from None
        self._process.join()
        if status != "ok":
            raise vo
        vo.keyframes = list(keyframes)
        return vo, result

    def close(self) -> None:
        """Stop the process if it is still running (the run failed or was interrupted)."""
        if self._process.is_alive():
            self._process.terminate()
        self._process.join()
        for q in (self._inbox, self._outbox):
            q.cancel_join_thread()  # keyframes a dead process never read must not hold up the run's exit
            q.close()


__all__ = ["StraightVOBeside"]
