"""Shared scenes for the front-end tests, built once per session.

`pipe_scene` is a tiny ray-cast render of a straight textured pipe (independent of the
simulator, so that the front end can be tested with exact geometry). `sim_scene` renders with
the project's simulator when it is available.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipemap.camera import PolynomialCamera
from pipemap.dataset import Frame
from pipemap.geometry.rotations import exp_so3


@dataclass
class PipeScene:
    camera: PolynomialCamera
    radius: float
    rotations: np.ndarray  # (N, 3, 3) R_wc
    centres: np.ndarray  # (N, 3)
    images: list[np.ndarray]

    def frames(self):
        return [Frame(i, i / 10.0, img) for i, img in enumerate(self.images)]


def wall_texture(length_m: float, radius: float, res_m: float, seed: int) -> np.ndarray:
    """Blobby grey texture of the unrolled wall: (length / res, 2 pi r / res), float32 0..255."""
    rng = np.random.default_rng(seed)
    h, w = int(length_m / res_m), int(2 * np.pi * radius / res_m)
    tex = np.zeros((h, w), np.float32)
    for sigma, weight in ((1.5, 0.6), (4.0, 1.0), (12.0, 1.0)):
        noise = rng.normal(size=(h, w)).astype(np.float32)
        noise = cv2.GaussianBlur(noise, (0, 0), sigma, borderType=cv2.BORDER_WRAP if False else cv2.BORDER_REFLECT)
        tex += weight * noise / noise.std()
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (40 + 200 * tex).astype(np.float32)


def render_pipe(camera, radius, texture, res_m, R_wc, centre, noise, rng) -> np.ndarray:
    """Ray-cast the straight pipe (axis = world z, from z = 0) seen from one pose."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(float)
    bearings, valid = camera.unproject(np.stack([u, v], axis=-1))
    d = bearings @ R_wc.T
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (centre[0] * d[..., 0] + centre[1] * d[..., 1])
    c = centre[0] ** 2 + centre[1] ** 2 - radius**2
    s = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0))) / np.maximum(2 * a, 1e-12)
    p = centre + s[..., None] * d
    phi = np.arctan2(p[..., 1], p[..., 0])
    row = (p[..., 2] / res_m).astype(np.float32)
    col = (np.mod(phi, 2 * np.pi) * radius / res_m).astype(np.float32)
    img = cv2.remap(texture, col, row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    shade = np.clip(0.35 / np.maximum(s, 1e-3), 0.2, 1.5)
    img = img * shade + rng.normal(scale=noise, size=img.shape)
    img[~valid | (a < 1e-9) | (s > 3.0)] = 0.0
    return np.clip(img, 0, 255).astype(np.float32)


def straight_pipe_scene(width=320, height=240, frames=40, step_m=0.02, seed=0, noise=1.0) -> PipeScene:
    k1 = (height / 2 - 1) / np.radians(95.0)
    camera = PolynomialCamera(width, height, [k1, 0, 0, 0, (width - 1) / 2, (height - 1) / 2], 95.0)
    radius, res = 0.2, 0.0015
    rng = np.random.default_rng(seed)
    texture = wall_texture(frames * step_m + 4.0, radius, res, seed)
    idx = np.arange(frames)
    centres = np.stack([0.03 * np.sin(idx / 7.0), 0.02 * np.cos(idx / 5.0), 0.5 + step_m * idx], axis=-1)
    rotations = np.stack([exp_so3(np.array([0.05 * np.sin(i / 6.0), 0.04 * np.cos(i / 9.0), 0.1 * i / frames]))
                          for i in idx])
    images = [render_pipe(camera, radius, texture, res, R, c, noise, rng) for R, c in zip(rotations, centres)]
    return PipeScene(camera, radius, rotations, centres, images)


@pytest.fixture(scope="session")
def pipe_scene() -> PipeScene:
    return straight_pipe_scene()


def write_dataset(scene: PipeScene, root, saturate: tuple[int, ...] = ()) -> Path:
    """The scene as a dataset folder (formats.md) with ground truth; frames in `saturate` are pure glare."""

    import yaml

    from pipemap.network import PipeNetwork, Segment, save_network
    from pipemap.trajectory import Trajectory, write_tum

    root = Path(root)
    (root / "images").mkdir(parents=True)
    (root / "ground_truth").mkdir()
    for i, img in enumerate(scene.images):
        out = np.full_like(img, 255.0) if i in saturate else img
        cv2.imwrite(str(root / "images" / f"{i:06d}.png"), np.rint(out).astype(np.uint8))
    cam = scene.camera.to_dict()
    doc = {"format": "pipemap-dataset/1", "name": "pipe-scene", "images": "images/*.png", "fps": 10.0,
           "camera": cam, "pipe": {"radius_m": scene.radius}}
    (root / "dataset.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    n = len(scene.images)
    write_tum(root / "ground_truth" / "poses.tum", Trajectory(np.arange(n) / 10.0, scene.centres, scene.rotations))
    network = PipeNetwork(scene.radius, (Segment("S1", np.zeros(3), np.array([0.0, 0.0, 20.0])),))
    save_network(root / "ground_truth" / "network.yaml", network)
    return root


@pytest.fixture(scope="session")
def pipe_dataset(pipe_scene, tmp_path_factory):
    return write_dataset(pipe_scene, tmp_path_factory.mktemp("pipe") / "data")


@pytest.fixture(scope="session")
def glare_dataset(pipe_scene, tmp_path_factory):
    return write_dataset(pipe_scene, tmp_path_factory.mktemp("glare") / "data", saturate=(15, 16))


def _simulate(preset: str, out, **kwargs):
    from pipemap.sim.simulate import simulate

    return simulate(preset, out, **kwargs)


# 640 x 480: at 320 x 240 a pixel spans 0.8 deg and the rendered wall gives ~130 matches per
# keyframe pair, too few to hold the rotation targets; 640 x 480 renders in a few seconds.
SIM_STRAIGHT = dict(preset="fisheye-straight", width=640, height=480, frames=30, seed=0)
SIM_TEE = dict(preset="demo-loop", width=640, height=480, frames=60, seed=0, spacing_m=0.02)


@pytest.fixture(scope="session")
def sim_straight(tmp_path_factory):
    """fisheye-straight, 30 frames; with `wall`, the simulator's exact wall for judging."""
    kw = dict(SIM_STRAIGHT)
    out = _simulate(kw.pop("preset"), tmp_path_factory.mktemp("sim") / "straight", **kw)
    return out


@pytest.fixture(scope="session")
def sim_tee(tmp_path_factory):
    """demo-loop through its first tee (closest approach at frame 34), 60 frames 2 cm apart."""
    kw = dict(SIM_TEE)
    out = _simulate(kw.pop("preset"), tmp_path_factory.mktemp("sim") / "tee", **kw)
    return out


def sim_wall_for(spec: dict):
    from pipemap.sim.simulate import wall_caster

    kw = dict(spec)
    return wall_caster(kw.pop("preset"), kw["width"], kw["height"], kw["frames"], kw["seed"], kw.get("spacing_m"))
