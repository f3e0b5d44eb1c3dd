"""A preset rendered as inspection footage: camera effects on every frame, ground truth kept exact.

The plan's frames are the camera's frame slots: slot j is captured at j / fps. The link schedule
(effects.link_schedule) makes each slot written, repeated (the previous written frame again,
byte for byte, overlay included: the recorder got nothing new) or dropped (nothing written; its
frame is never rendered, as nothing could show it). Written frame k is images/{k:06d}.png or the
video's k-th frame (presented at its slot's time, so drops leave gaps in the video's timestamps).

Ground truth of what was written:
- poses.tum: one line per written frame, the pose its picture shows (for a repeat, the repeated
  frame's pose), timestamped with the frame's time on the recording's clock, slot / fps: the
  video's presentation time, or the line of timestamps.txt (written beside numbered PNGs and named
  by dataset.yaml's `timestamps:` key). Without dropped frames that is index / fps, as before;
- recording.csv (added): index, slot, time_s (= slot / fps, the recorder's clock: a drop leaves a
  gap), capture_slot (the slot whose picture it is), repeat (1: identical to the previous frame),
  dropped_before (slots lost just before it), gain, distance_m (the counter shown);
- overlay_mask.png (added, with an overlay): 255 wherever burned-in text was drawn in any frame;
- simulation.yaml: the effects and the counts of written, repeated and dropped frames.
"""

from __future__ import annotations

import contextlib
import multiprocessing
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from pipemap.errors import PipemapError
from pipemap.sim.capture import Capture
from pipemap.sim.effects import DROP, REPEAT, WRITTEN, CameraEffects, gain_curve, link_schedule
from pipemap.sim.overlay import OverlayPainter
from pipemap.sim.recorder import PngFrames, VideoFrames
from pipemap.sim.render import Renderer, frame_rng
from pipemap.trajectory import Trajectory

RECORDING_HEADER = "index,slot,time_s,capture_slot,repeat,dropped_before,gain,distance_m"


def write_footage(folder: Path, preset: str, route: str | None, p, renderer: Renderer, fx: CameraEffects, seed: int,
                  workers: int, progress: Callable[[int, int], None] | None = None) -> None:
    """Fill the (temporary) dataset folder with `p`'s frames as `fx` makes them."""
    from pipemap.sim.simulate import _write_metadata

    setup = p.setup
    cam, fps, n = setup.camera, float(setup.fps), len(p)
    fx_seed = seed if fx.seed is None else int(fx.seed)
    kinds = link_schedule(fx.link, n, fx_seed)
    gains = gain_curve(fx.gain, n, fx_seed)
    traj = p.trajectory
    if renderer.exposure is None:  # the camera's nominal exposure, on the first frame before any gain
        renderer.fix_exposure(renderer.radiance(traj.rotations[0], traj.positions[0]))
    capture = Capture(renderer, traj.rotations, traj.positions, fx, gains)
    painter = OverlayPainter(fx.overlay, cam.width, cam.height) if fx.overlay is not None else None
    counter = p.s - p.s[0]  # the cable counter: metres along the route from the first frame
    (folder / "ground_truth").mkdir()
    sink = (VideoFrames(folder, fx.video, cam.width, cam.height, fps, fx.interlace) if fx.video is not None
            else PngFrames(folder))
    text_mask = np.zeros((cam.height, cam.width), bool)
    mean = np.zeros((cam.height, cam.width), np.float64) if setup.gain_mask else None
    rows: list[str] = []
    shown: list[int] = []
    last = last_slot = None
    dropped = 0
    images = _captures(capture, np.flatnonzero(kinds == WRITTEN), seed, workers)
    with contextlib.closing(images), sink:
        for j in range(n):
            if kinds[j] == DROP:
                dropped += 1
            else:
                if kinds[j] == WRITTEN:
                    last, last_slot = next(images), j
                    if mean is not None:  # the flat field of what the sensor saw, without the burned-in text
                        mean += last
                    if painter is not None:
                        text_mask |= painter.draw(last, counter[j], j / fps)
                k = len(shown)
                sink.put(k, j, last)
                shown.append(last_slot)
                rows.append(f"{k},{j},{j / fps:.6f},{last_slot},{int(kinds[j] == REPEAT)},{dropped},"
                            f"{gains[last_slot]:.6f},{counter[last_slot]:.6f}")
                dropped = 0
            if progress is not None:
                progress(j + 1, n)
    shown_idx = np.array(shown)
    times = np.flatnonzero(kinds != DROP) / fps
    written = Trajectory(times, traj.positions[shown_idx], traj.rotations[shown_idx])
    counts = {"frames": n, "written_frames": len(shown), "repeated_frames": int(np.sum(kinds == REPEAT)),
              "dropped_frames": int(np.sum(kinds == DROP))}
    extra_keys = {}
    if fx.video is None:  # a video carries its frames' times; numbered PNGs get a timestamps file
        (folder / "timestamps.txt").write_text(
            "# seconds since the first frame, one line per image (a dropped frame leaves a gap)\n"
            + "".join(f"{t:.6f}\n" for t in times))
        extra_keys["timestamps"] = "timestamps.txt"
    _write_metadata(folder, preset, route, seed, p, renderer, sink.glob, written,
                    None if mean is None else mean / np.sum(kinds == WRITTEN), counts,
                    {"camera_effects": fx.to_dict()}, extra_keys)
    gt = folder / "ground_truth"
    (gt / "recording.csv").write_text("\n".join([RECORDING_HEADER, *rows]) + "\n")
    if painter is not None and not cv2.imwrite(str(gt / "overlay_mask.png"), text_mask.astype(np.uint8) * 255):
        raise PipemapError("cannot write image", gt / "overlay_mask.png")


_JOB: tuple | None = None  # what forked workers share with the parent (copy-on-write)


def _captures(capture: Capture, slots: np.ndarray, seed: int, workers: int):
    """The captured frames of `slots`, in order; several workers render them in forked processes.
    Every frame's noise is seeded by its slot, so the images do not depend on the number of workers."""
    global _JOB
    if workers == 1 or len(slots) < 2:
        for j in slots:
            yield capture.image(int(j), frame_rng(seed, int(j)))
        return
    _JOB = (capture, seed)
    try:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            yield from pool.imap(_capture_one, [int(j) for j in slots], chunksize=2)
    finally:
        _JOB = None


def _capture_one(j: int) -> np.ndarray:
    capture, seed = _JOB
    return capture.image(j, frame_rng(seed, j))
