"""Render a preset into a dataset folder (spec/formats.md) with exact ground truth.

The folder is written into a temporary sibling and renamed into place at the end; an existing
non-empty `out` is refused. Frames stream to disk one by one (a writer thread encodes PNGs while
the next frame renders; at most two frames wait in the queue), so memory does not grow with
the number of frames.

Frame count: `frames=N` keeps the first N frames of the preset's route at its spacing
(`spacing_m` overrides the spacing, e.g. to cover a whole loop in fewer frames).

Camera effects (`effects=`, effects.py) turn the frames into inspection footage (footage.py: video,
burned-in text, gain changes, blur, interlacing, repeated and dropped frames); without them the
dataset is byte for byte what it was before they existed.
"""

from __future__ import annotations

import multiprocessing
import os
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import yaml

from dataclasses import replace

from pipemap.errors import PipemapError
from pipemap.gain_mask import save_gain_mask, smooth_mask
from pipemap.output import result_folder
from pipemap.sim.effects import CameraEffects, load_effects
from pipemap.sim.presets import PRESETS, Setup, _info, get_setup, list_presets
from pipemap.sim.recorder import PngWriter as _PngWriter
from pipemap.sim.render import Renderer, frame_rng
from pipemap.sim.texture import STYLES
from pipemap.sim.route import AxisPath, camera_trajectory, drive_distances, visits
from pipemap.network import save_network
from pipemap.sim.wall_shape import deformation_truth
from pipemap.trajectory import Trajectory, write_tum

__all__ = ["simulate", "list_presets", "plan", "Plan", "PRESETS"]

GAIN_MASK_SIGMA_PX = 15.0  # at 1024 px wide (the report's pipe 1 camera); scales with the width


class Plan:
    """A preset resolved to a camera, a scene, the frame poses and the visited junctions."""

    def __init__(self, setup: Setup, trajectory: Trajectory, visits: list[str], path: AxisPath, s: np.ndarray):
        self.setup = setup
        self.trajectory = trajectory
        self.visits = visits
        self.path = path
        self.s = s

    def __len__(self) -> int:
        return len(self.trajectory)


def plan(preset: str, *, width=None, height=None, frames=None, seed: int = 0, route=None, spacing_m=None,
         texture: str | None = None, specular: float | None = None) -> Plan:
    """Resolve a preset: the setup, every frame's true pose and the junction visits.
    `texture` replaces the preset's wall style (procedural, brick, gravel: real photos); `specular` the strength of
    the wall's highlight (0: a matte wall)."""
    if frames is not None and (not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or frames < 1):
        raise PipemapError(f"the number of frames must be a positive integer, got {frames!r}", key="frames")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise PipemapError(f"the seed must be an integer, got {seed!r}", key="seed")
    setup = get_setup(preset, width, height, route, int(seed))
    if texture is not None:
        if texture not in STYLES:
            raise PipemapError(f"unknown wall texture {texture!r} (expected one of {', '.join(STYLES)})", key="texture")
        setup.appearance = replace(setup.appearance, texture_style=texture)
    if specular is not None:
        if not (isinstance(specular, (int, float, np.integer, np.floating)) and 0 <= specular < float("inf")):
            raise PipemapError(f"the highlight's strength must be a number >= 0, got {specular!r}", key="specular")
        setup.appearance = replace(setup.appearance, specular_strength=float(specular))
    if spacing_m is not None:
        if not spacing_m > 0:
            raise PipemapError(f"frame spacing must be positive, got {spacing_m}", key="spacing_m")
        setup.drive = replace(setup.drive, spacing_m=float(spacing_m))
    path = AxisPath(setup.path_vertices, setup.drive.turn_radius_m,
                    radii=setup.scene.fillet_radii(setup.path_vertices))
    if setup.still:
        n = frames or setup.frames or 1
        s = np.full(n, setup.drive.start_m)
    else:
        s = drive_distances(path.length, setup.drive, int(seed), frames)
    traj = camera_trajectory(path, s, setup.drive, setup.fps, int(seed))
    return Plan(setup, traj, visits(path, s, setup.scene.junctions), path, s)


def simulate(preset: str, out: Path, *, width: int | None = None, height: int | None = None, frames: int | None = None,
             seed: int = 0, route: str | None = None, progress: Callable[[int, int], None] | None = None,
             spacing_m: float | None = None, motion_blur: int = 1, texture: str | None = None,
             workers: int | None = None, effects: str | Path | dict | CameraEffects | None = None,
             specular: float | None = None) -> Path:
    """Render `preset` into the dataset folder `out` and return it.

    width/height: image size (intrinsics scale, field of view kept); frames: the first N frames
    of the route; seed: textures, wobble, speed and sensor noise; route: the preset's variant
    (list_presets() names them); progress(i, n) after each frame; specular: the wall highlight's strength
    (None: the preset's, 0: a matte wall); motion_blur: sub-frame renders
    averaged per frame (1: none), spread over the motion since the previous frame; workers:
    rendering processes (None: one per available core for long runs). Every frame's noise is
    seeded by its index and the exposure is fixed before the workers start, so the images do not
    depend on the number of workers.

    effects: inspection footage's defects (effects.py): a profile name such as "cctv-h264", a YAML
    file, a mapping or a CameraEffects; None takes the preset's default (none for the papers'
    presets), "clean" none. Without effects the dataset is exactly what it was before effects existed.
    """
    out = Path(out)
    info = _info(preset)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise PipemapError("output already exists and is not empty; choose another --out", out)
    fx = load_effects(effects) if effects is not None else None
    if info.build is None:
        if fx is not None and not fx.clean:
            raise PipemapError(f"preset {preset} writes its own images and takes no camera effects", key="effects")
        with result_folder(out) as tmp:
            info.writer(tmp, width=width, height=height, frames=frames, seed=seed, route=route, progress=progress)
        return out
    p = plan(preset, width=width, height=height, frames=frames, seed=seed, route=route, spacing_m=spacing_m,
             texture=texture, specular=specular)
    if not isinstance(motion_blur, (int, np.integer)) or motion_blur < 1:
        raise PipemapError(f"motion blur takes a number of sub-frames >= 1, got {motion_blur!r}", key="motion_blur")
    setup = p.setup
    if fx is None:
        fx = load_effects(setup.effects)
    renderer = Renderer(setup.scene, setup.camera, setup.appearance, seed=int(seed))
    n = len(p)
    workers = _worker_count(workers, n)
    if not fx.clean:
        if motion_blur != 1:
            raise PipemapError("camera effects blur with their shutter; leave motion_blur at 1", key="motion_blur")
        from pipemap.sim.recording import write_footage

        with result_folder(out) as tmp:
            write_footage(tmp, preset, route, p, renderer, fx, int(seed), workers, progress)
        return out
    with result_folder(out) as tmp:
        (tmp / "images").mkdir()
        (tmp / "ground_truth").mkdir()
        mean = np.zeros((setup.camera.height, setup.camera.width), np.float64) if setup.gain_mask else None
        for i, img in enumerate(_render_frames(renderer, p, seed, motion_blur, tmp / "images", workers,
                                                  keep=mean is not None)):
            if mean is not None:
                mean += img
            if progress is not None:
                progress(i + 1, n)
        _write_metadata(tmp, preset, route, int(seed), p, renderer, "images/*.png", p.trajectory,
                        None if mean is None else mean / n, {"frames": n, "motion_blur": int(motion_blur)})
    return out


def _write_metadata(tmp: Path, preset: str, route: str | None, seed: int, p: Plan, renderer: Renderer, images: str,
                    trajectory: Trajectory, mean: np.ndarray | None, counts: dict, extra: dict | None = None,
                    keys: dict | None = None) -> None:
    """dataset.yaml (with the optional `keys`), gain_mask.png (from the mean image, when the preset
    makes one), and ground_truth/: poses.tum (`trajectory`: the pose each written image shows),
    network.yaml, simulation.yaml (with `extra`)."""
    setup = p.setup
    doc = {
        # /2 only where a key of /2 is used, so that datasets without one stay as they were
        "format": "pipemap-dataset/2" if keys else "pipemap-dataset/1",
        "name": f"{preset}" + (f"-{route}" if route else ""),
        "images": images,
        "fps": float(setup.fps),
        "camera": setup.camera.to_dict(),
        "pipe": {"radius_m": float(setup.scene.radius)},
        **(keys or {}),
    }
    if mean is not None:
        _write_gain_mask(tmp / "gain_mask.png", mean, setup.camera.width)
        doc["gain_mask"] = "gain_mask.png"
    (tmp / "dataset.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    gaps = len(trajectory) > 1 and np.max(np.diff(trajectory.timestamps)) > 1.5 / setup.fps
    clock = "the recording's time (gaps: dropped frames)" if gaps else "index / fps"
    write_tum(tmp / "ground_truth" / "poses.tum", trajectory,
              header=f"pipemap simulate {preset} seed {seed}: true T_wc, timestamp = {clock}")
    save_network(tmp / "ground_truth" / "network.yaml", setup.scene.network(p.visits))
    shapes = deformation_truth(setup.scene)
    if shapes is not None:
        (tmp / "ground_truth" / "deformation.yaml").write_text(yaml.safe_dump(shapes, sort_keys=False))
    record = {
        "preset": preset, "route": route, "seed": int(seed), **counts,
        "exposure": float(renderer.exposure), "drive": setup.drive.to_dict(),
        "appearance": setup.appearance.to_dict(), "path_length_m": float(p.path.length),
        "driven_m": [float(p.s[0]), float(p.s[-1])], "notes": setup.notes, **(extra or {}),
    }
    (tmp / "ground_truth" / "simulation.yaml").write_text(yaml.safe_dump(_plain(record), sort_keys=False))


def _worker_count(workers: int | None, n: int) -> int:
    if workers is not None:
        if not isinstance(workers, (int, np.integer)) or workers < 1:
            raise PipemapError(f"workers must be a positive integer, got {workers!r}", key="workers")
        return int(workers)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return 1 if n < 60 else max(1, min(cores, 8))  # a short run does not repay starting processes


_JOB: tuple | None = None  # what forked rendering workers share with the parent (copy-on-write)


def _render_frames(renderer: Renderer, p: Plan, seed: int, motion_blur: int, folder: Path, workers: int,
                   keep: bool = True):
    """Render and write every frame in order, yielding each image; with several workers, forked
    processes render and write frames while this one collects them in order (the images
    themselves only when `keep`: otherwise None, sparing the copy between processes)."""
    global _JOB
    n = len(p)
    if workers == 1 or n == 1:
        with _PngWriter() as writer:
            for i in range(n):
                img = renderer.render(_sub_poses(p, i, motion_blur), frame_rng(seed, i))
                writer.put(folder / f"{i:06d}.png", img)
                yield img
        return
    # The exposure is fixed on frame 0 exactly as a single process would, before forking.
    poses = _sub_poses(p, 0, motion_blur)
    poses = [poses] if isinstance(poses, tuple) else poses
    rad = sum(renderer.radiance(R, t) for R, t in poses) / len(poses)
    renderer.fix_exposure(rad.astype(np.float32))
    _JOB = (renderer, p, seed, motion_blur, folder, keep)
    try:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            yield from pool.imap(_render_one, range(n), chunksize=2)
    finally:
        _JOB = None


def _render_one(i: int) -> np.ndarray | None:
    renderer, p, seed, motion_blur, folder, keep = _JOB
    img = renderer.render(_sub_poses(p, i, motion_blur), frame_rng(seed, i))
    if not cv2.imwrite(str(folder / f"{i:06d}.png"), img):
        raise PipemapError("cannot write image", folder / f"{i:06d}.png")
    return img if keep else None


def _plain(x):
    """numpy scalars and arrays inside dicts/lists -> plain Python, for YAML."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def _sub_poses(p: Plan, i: int, k: int):
    R, t = p.trajectory.rotations, p.trajectory.positions
    if k == 1 or i == 0:
        return (R[i], t[i])
    # positions interpolate linearly; rotations share the small step through the nearer pose
    out = []
    for a in (np.arange(k) + 0.5) / k:
        out.append((R[i] if a > 0.5 else R[i - 1], (1 - a) * t[i - 1] + a * t[i]))
    return out


def _write_gain_mask(path: Path, mean: np.ndarray, width: int) -> None:
    save_gain_mask(path, smooth_mask(mean, GAIN_MASK_SIGMA_PX * width / 1024, path))


def wall_caster(preset: str, width: int, height: int, frames: int, seed: int, spacing_m: float | None = None):
    """The exact wall of a preset's scene (sagging, misaligned pieces) as a function
    (origin (3,), unit world directions (N, 3)) -> (points (N, 3), hit (N,)), for judging results."""
    from pipemap.sim.raycast import RayCaster

    caster = RayCaster(plan(preset, width=width, height=height, frames=frames, seed=seed,
                            spacing_m=spacing_m).setup.scene, dtype=np.float64)

    def cast(origin, directions):
        hits = caster.cast_world(origin, directions)
        t = np.where(hits.hit, hits.t, 0.0)
        return origin + t[:, None] * directions, hits.hit

    return cast
