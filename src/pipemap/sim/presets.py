"""Named simulation set-ups: the papers' pipes, cameras, lights and routes.

Each preset builds a `Setup` for a requested image size (the camera's intrinsics scale with the
width so that the field of view stays the same) and route variant. When fewer frames are asked
for, simulate() keeps the first N frames of the route at the same spacing.

- paper-loop: the fisheye paper's 400 mm network (Fig. 5): four tees T1..T4 placed to fit the
  six laser distances of Table I, each with a closed stub; route "A" start-T1-T2-T3-T4-end,
  route "B" start-T4-T3-T2-T1-T4-end; 1280x960 polynomial fisheye (190 deg), 7.5 fps, 1 cm.
- paper-straight-6in / paper-straight-16in: the 2010 report's pipes 1 and 2 (Table 1), camera
  looking up at the wall with image x along the pipe (report section 5.3), 4 LEDs; routes
  "forward" and "forward-reverse" with the report's frame counts.
- fisheye-straight: one straight 400 mm pipe seen by the fisheye.
- tee-pass-loop: the 3.0 m x 2.2 m, 300 mm tee loop of issue 20 at 640x480 fisheye; route "A" starts in T1's
  stub, passes T1 straight through, turns at T4, T3, T2, comes back to T1 head-on along its branch and turns
  into the stub; route "B" passes T1 and T2 straight through (from stub to stub).
- elbow-cross: issue 20's 300 mm network of a 90 deg elbow (bend radius 1.5 D), a cross, a 45 deg elbow
  (2 D) and a 30 deg sweeping bend (10 D) at 640x480 fisheye; route "A" drives through them all turning at
  the cross, "B" drives the bends backwards and passes the cross straight through, "C" the 90 deg elbow and
  the cross straight along its main pipe.
- deformed-pipe: a straight 300 mm pipe of round pieces, a 3 % and a 6 % oval piece and a piece with a
  10 mm dent (issue 22's deformation measurement), 640x480 fisheye; routes "short" and "tiny" shrink the pieces.
- demo-loop: a small 2 m x 1.5 m tee loop at 640x480, fast; route "A" drives the lap and on
  past its start along the first side, so the run revisits it (loop closure).
- cctv-loop / cctv-straight: a sewer crawler's forward-looking CCTV camera (100 deg, barrel
  distortion) in a 300 mm tee loop and a straight pipe; the robot wobbles up to 1 deg.
- cctv-recording: cctv-straight at 720x576 with the camera effects profile cctv-h264 by default.
- wall-camera-90 / -75 / -50: a wall camera off the axis of a 387.56 mm pipe, its optical axis at
  90, 75 or 50 deg to the pipe axis.
- white-card: the 2010 report's gain-mask images: a white pipe wall, LEDs on, camera still.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from pipemap.camera import CameraModel, KannalaBrandtCamera, PinholeCamera, PolynomialCamera
from pipemap.errors import PipemapError
from pipemap.network import Junction
from pipemap.sim.network_model import Pipe, PipeScene, network_scene, route_polyline, straight_scene, tee_loop_scene
from pipemap.sim.render import Appearance
from pipemap.sim.route import Drive
from pipemap.sim.wall_shape import Dent, WallShape

# Fisheye paper, Table I: laser distances between tee centres (metres).
TABLE_I = {("T1", "T2"): 8.150, ("T2", "T3"): 8.174, ("T3", "T4"): 8.159, ("T4", "T1"): 8.110,
           ("T1", "T3"): 11.468, ("T2", "T4"): 11.493}
FISHEYE_BASE = dict(width=1280, height=960, k1=290.0, k2=-8.0, k3=2.0, k4=-0.4, max_theta_deg=95.0)


@dataclass
class Setup:
    """Everything simulate() needs to render one dataset."""

    name: str
    scene: PipeScene
    camera: CameraModel
    path_vertices: np.ndarray  # the route's axis polyline
    drive: Drive
    appearance: Appearance
    fps: float
    frames: int | None = None  # the route's natural frame count when fixed (None: by distance)
    still: bool = False  # every frame at the route's first pose (white card)
    gain_mask: bool = False
    notes: dict = field(default_factory=dict)
    effects: str | None = None  # the camera effects profile (effects.PROFILES) rendered when none is asked for


@dataclass(frozen=True)
class PresetInfo:
    name: str
    description: str
    routes: tuple[str, ...]
    build: Callable[..., Setup] | None  # build(width, height, route, seed) -> Setup
    writer: Callable | None = None  # a preset that writes its own folder (e.g. calibration boards)


PRESETS: dict[str, PresetInfo] = {}


def register_preset(name: str, description: str, routes=("default",), build=None, writer=None) -> None:
    """Add a preset: `build(width, height, route, seed) -> Setup`, or `writer(folder, width=,
    height=, frames=, seed=, route=, progress=)` that fills the (temporary) dataset folder itself."""
    PRESETS[name] = PresetInfo(name, description, tuple(routes), build, writer)


def list_presets() -> dict[str, str]:
    """Preset name -> one-line description (with its routes), in registration order."""
    return {p.name: f"{p.description} (routes: {', '.join(p.routes)})" for p in PRESETS.values()}


def get_setup(name: str, width: int | None = None, height: int | None = None, route: str | None = None,
              seed: int = 0) -> Setup:
    info = _info(name)
    if info.build is None:
        raise PipemapError(f"preset {name!r} writes its own dataset folder", key="preset")
    route = route or info.routes[0]
    if route not in info.routes:
        raise PipemapError(f"preset {name} has no route {route!r} (expected one of {', '.join(info.routes)})",
                           key="route")
    return info.build(width, height, route, seed)


def _info(name: str) -> PresetInfo:
    if name not in PRESETS:
        raise PipemapError(f"unknown preset {name!r} (expected one of {', '.join(PRESETS)})", key="preset")
    return PRESETS[name]


# -- cameras ----------------------------------------------------------------------------------------


def _size(width, height, base_w: int, base_h: int) -> tuple[int, int, float]:
    if width is None and height is None:
        return base_w, base_h, 1.0
    if width is None:
        width = int(round(height * base_w / base_h))
    if height is None:
        height = int(round(width * base_h / base_w))
    for v, key in ((width, "width"), (height, "height")):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 16:
            raise PipemapError(f"image {key} must be an integer of at least 16 pixels, got {v!r}", key=key)
    return int(width), int(height), min(width / base_w, height / base_h)


def fisheye_camera(width=None, height=None) -> PolynomialCamera:
    """The fisheye paper's 190 deg lens (polynomial model, eq. 1), scaled to the image size."""
    b = FISHEYE_BASE
    w, h, f = _size(width, height, b["width"], b["height"])
    params = dict(k1=b["k1"] * f, k2=b["k2"] * f, k3=b["k3"] * f, k4=b["k4"] * f, u0=(w - 1) / 2, v0=(h - 1) / 2)
    return PolynomialCamera(w, h, params, b["max_theta_deg"])


def perspective_camera(base_w: int, base_h: int, hfov_deg: float, k1: float, k2: float, width=None,
                       height=None) -> PinholeCamera:
    """A pinhole camera with mild radial distortion and the given horizontal angle of view."""
    w, h, _ = _size(width, height, base_w, base_h)
    # fx such that the distorted image edge sits at hfov / 2
    xn = np.tan(np.radians(hfov_deg) / 2)
    rad = 1 + k1 * xn**2 + k2 * xn**4
    fx = (w / 2) / (xn * rad)
    params = dict(fx=fx, fy=fx, cx=(w - 1) / 2, cy=(h - 1) / 2, k1=k1, k2=k2, p1=0.0, p2=0.0, k3=0.0)
    return PinholeCamera(w, h, params)


# -- networks ---------------------------------------------------------------------------------------


def table_i_corners() -> np.ndarray:
    """T1..T4 in the plane z = 0 fitting Table I's six distances (least squares): T1 at the
    origin, T2 on +x, the loop counter-clockwise seen from above."""
    from scipy.optimize import least_squares

    ids = ["T1", "T2", "T3", "T4"]
    pairs = [(ids.index(a), ids.index(b), d) for (a, b), d in TABLE_I.items()]

    def pts(x):
        return np.array([[0, 0], [x[0], 0], [x[1], x[2]], [x[3], x[4]]])

    def res(x):
        p = pts(x)
        return [np.linalg.norm(p[i] - p[k]) - d for i, k, d in pairs]

    x = least_squares(res, [8.15, 8.15, 8.15, 0.0, 8.15], xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    return np.concatenate([pts(x), np.zeros((4, 1))], axis=1)


# -- presets ----------------------------------------------------------------------------------------


def _loop_setup(name, corners, width, height, route, seed, *, fisheye_scale_w=None, stub=0.6, piece=2.75,
                sag=0.004, misalign=0.002, start_back=1.5, end_before=1.5, radius=0.2, camera=None,
                drive_extra=None, appearance=None) -> Setup:
    """A tee loop. Route A: start on side T4-T1, turn at T1, T2, T3, T4, end on side T4-T1
    `end_before` metres short of the start (past it when negative). Route B: start on side T1-T4
    heading to T4, turn at T4, T3, T2, T1, T4, end on side T4-T3."""
    scene = tee_loop_scene(corners, radius, stub_length=stub, piece_length=piece, sag_m=sag, misalign_m=misalign,
                           seed=seed)
    n = len(corners)
    if route == "A":
        legs = [(f"S{n}", False)] + [(f"S{k}", False) for k in range(1, n + 1)]
        side = np.linalg.norm(corners[0] - corners[-1])
        start, end = side - start_back, -(start_back + end_before)
    else:
        legs = ([(f"S{n}", True)] + [(f"S{k}", True) for k in range(n - 1, 0, -1)]
                + [(f"S{n}", True), (f"S{n - 1}", True)])
        side = np.linalg.norm(corners[0] - corners[-1])
        start, end = side - start_back, -(np.linalg.norm(corners[-1] - corners[-2]) - end_before)
    poly = route_polyline(scene, legs)
    if camera is not None:
        cam = camera
    else:
        cam = fisheye_camera(width, height) if fisheye_scale_w is None else fisheye_camera(
            width or fisheye_scale_w[0], height or fisheye_scale_w[1])
    drive = Drive(spacing_m=0.01, offset_down_m=0.04, look="forward", turn_radius_m=0.2, start_m=float(start),
                  end_m=float(end), **(drive_extra or {}))
    return Setup(name, scene, cam, poly, drive, appearance or Appearance(mm_per_px=1.0), 7.5)


def _paper_loop(width, height, route, seed):
    return _loop_setup("paper-loop", table_i_corners(), width, height, route, seed)


def _long_loop(width, height, route, seed):
    # paper-loop's pipe, lights and camera at 640x480 around a 64 m square: route A drives about 256 m, 25,900
    # frames at 1 cm, so that time per frame and memory can be measured over a run as long as the paper's dataset A
    corners = np.array([[0, 0, 0], [64.0, 0, 0], [64.0, 64.0, 0], [0, 64.0, 0]], float)
    return _loop_setup("long-loop", corners, width or 640, height or 480, route, seed)


# Route A starts 0.75 m short of T1 and ends 0.45 m short of it, a lap later: 0.3 m of the first side
# is driven twice (loop closure needs 0.2 m), and neither end is within 2 radii of a tee.
_DEMO_ENDS = {"A": dict(start_back=0.75, end_before=-0.3), "B": dict(start_back=0.6, end_before=0.4)}


def _demo_loop(width, height, route, seed):
    corners = np.array([[0, 0, 0], [2.0, 0, 0], [2.0, 1.5, 0], [0, 1.5, 0]], float)
    s = _loop_setup("demo-loop", corners, width, height, route, seed, fisheye_scale_w=(640, 480), stub=0.4,
                    piece=1.0, sag=0.002, misalign=0.001, **_DEMO_ENDS[route])
    return s


# The reviewer's tee-pass scene (issue 20): a 3.0 m x 2.2 m loop of 300 mm pipe, a tee at each corner, 1 m stubs.
# T1's main pipe is side T4-T1 with its stub B1 beyond T1 (-y); T2's main pipe is side T2-T3 with its stub B2
# beyond T2 (-y too), so that a route can leave T1's stub straight through T1 and end straight through T2.
TEE_PASS_CORNERS = np.array([[0, 0, 0], [3.0, 0, 0], [3.0, 2.2, 0], [0, 2.2, 0]], float)
_TEE_PASS_LEGS = {
    # start in B1, T1 straight through, turn at T4, T3, T2, back to T1 head-on along its branch, turn into B1
    "A": [("B1", True), ("S4", True), ("S3", True), ("S2", True), ("S1", True), ("B1", False)],
    # start in B1, T1 straight through, turn at T4 and T3, T2 straight through into its stub B2
    "B": [("B1", True), ("S4", True), ("S3", True), ("S2", True), ("B2", False)],
}


def _tee_pass_loop(width, height, route, seed, *, stub=1.0, start_back=0.75, end_in=0.5):
    """Routes that pass tees straight through and approach one along its stem; the drive starts
    `start_back` before T1 in its stub and ends `end_in` into the last stub."""
    scene = tee_loop_scene(TEE_PASS_CORNERS, 0.15, stub_length=stub, piece_length=1.0, sag_m=0.002, misalign_m=0.001,
                           seed=seed, main_out=(2,))
    poly = route_polyline(scene, _TEE_PASS_LEGS[route])
    drive = Drive(spacing_m=0.01, offset_down_m=0.04, look="forward", turn_radius_m=0.15, start_m=stub - start_back,
                  end_m=-(stub - end_in))
    return Setup("tee-pass-loop", scene, fisheye_camera(width or 640, height or 480), poly, drive,
                 Appearance(mm_per_px=1.0), 7.5, notes={"straight_through": ["T1"] if route == "A" else ["T1", "T2"]})


def elbow_cross_scene(radius: float = 0.15) -> PipeScene:
    """Issue 20's network of elbows and a cross, 300 mm pipe, all in the plane z = 0.

    Run M1 from a closed end at the origin along +x turns left at E1 (90 deg, bend radius 0.45 m =
    1.5 D, vertex (2, 0)) and meets the cross X1 at (2, 2.2); M2 goes on straight through it along +y to a
    closed end 1 m on. The cross's branches: W leaves X1 along -x, turns right at E2 (45 deg, bend radius
    0.6 m = 2 D, vertex 1.2 m from X1) and again at E3, a long sweeping bend (30 deg, bend radius 3 m =
    10 D, vertex 2 m on), to a closed end 2 m further; X is a closed 1 m stub along +x."""
    x1 = np.array([2.0, 2.2, 0.0])
    e2 = np.array([0.8, 2.2, 0.0])
    e3 = e2 + 2.0 * np.array([-np.sqrt(0.5), np.sqrt(0.5), 0.0])
    w_end = e3 + 2.0 * np.array([np.cos(np.radians(105)), np.sin(np.radians(105)), 0.0])
    runs = [
        ("M1", np.array([[0.0, 0, 0], [2.0, 0, 0], x1]), {1: ("E1", 0.45)}, True, False),
        ("M2", np.array([x1, [2.0, 3.2, 0]]), {}, False, True),
        ("W", np.array([x1, e2, e3, w_end]), {1: ("E2", 0.6), 2: ("E3", 3.0)}, False, True),
        ("X", np.array([x1, [3.0, 2.2, 0]]), {}, False, True),
    ]
    return network_scene(radius, runs, [Junction("X1", "cross", x1)])


# route -> (legs, metres from the first run's start where the drive begins, metres short of the end where it stops)
_ELBOW_ROUTES = {
    "A": ([("M1", False), ("W", False)], 0.5, 0.5),  # E1, turn at X1, E2, E3
    "B": ([("W", True), ("X", False)], 0.5, 0.4),  # E3, E2 backwards, X1 straight through into the stub
    "C": ([("M1", False), ("M2", False)], 0.5, 0.4),  # E1, X1 straight through along the main pipe
}


def _elbow_cross(width, height, route, seed):
    scene = elbow_cross_scene()
    legs, start, end = _ELBOW_ROUTES[route]
    drive = Drive(spacing_m=0.01, offset_down_m=0.04, look="forward", turn_radius_m=0.15, start_m=start, end_m=-end)
    return Setup("elbow-cross", scene, fisheye_camera(width or 640, height or 480), route_polyline(scene, legs), drive,
                 Appearance(mm_per_px=1.0), 7.5)


def _fisheye_straight(width, height, route, seed):
    scene = straight_scene(6.0, 0.2, piece_length=2.0, sag_m=0.003, misalign_m=0.0015, seed=seed)
    # recheck: in to 3 m, back to 2 m to look again, on to the end and back out
    drive = Drive(spacing_m=0.01, offset_down_m=0.04, look="forward", start_m=0.5, end_m=5.0,
                  reverse=route != "forward", turns_m=(3.0, 2.0) if route == "recheck" else ())
    return Setup("fisheye-straight", scene, fisheye_camera(width, height), scene.runs["S1"], drive,
                 Appearance(mm_per_px=1.0), 7.5)


# issue 22's deformed pipe: round pieces between a 3 % oval one (major axis horizontal), a 6 % oval one (major
# axis at 2 o'clock) and one with a 10 mm dent at 11 o'clock; (piece length, shape) in order, metres.
DEFORMED_PIECES = (
    (1.0, None),
    (1.0, WallShape(3.0, 90.0)),
    (0.8, None),
    (1.0, WallShape(6.0, 60.0)),
    (0.8, None),
    (1.0, WallShape(0.0, 0.0, (Dent(0.5, 330.0, 0.010, 0.3, 60.0),))),
    (1.0, None),
)


def deformed_scene(radius: float = 0.15, scale: float = 1.0) -> PipeScene:
    """A straight pipe along +x of DEFORMED_PIECES, each piece's length times `scale` (a dent keeps its size
    and sits in its piece's middle), both ends closed."""
    pipes, h = [], 0.0
    for k, (length, shape) in enumerate(DEFORMED_PIECES):
        n = length * scale
        if shape is not None and shape.dents:
            shape = replace(shape, dents=tuple(replace(d, h_m=n / 2) for d in shape.dents))
        pipes.append(Pipe(f"S1.{k + 1}", np.array([h, 0.0, 0.0]), np.array([h + n, 0.0, 0.0]), closed_start=k == 0,
                          closed_end=k == len(DEFORMED_PIECES) - 1, shape=shape))
        h += n
    return PipeScene(float(radius), tuple(pipes), (), {"S1": np.array([[0.0, 0, 0], [h, 0, 0]])})


def _deformed(width, height, route, seed):
    scale = {"short": 0.6, "tiny": 0.4}.get(route, 1.0)
    scene = deformed_scene(scale=scale)
    length = float(scene.runs["S1"][-1, 0])
    drive = Drive(spacing_m=0.01, offset_down_m=0.04, look="forward", start_m=0.3, end_m=length - 0.5 * scale)
    return Setup("deformed-pipe", scene, fisheye_camera(width or 640, height or 480), scene.runs["S1"], drive,
                 Appearance(mm_per_px=1.0), 7.5)


def _straight_2010(name, *, length, diameter, gt_mm, base, hfov, k1, k2, fps, frames, offset_down, ring, mm_px,
                   width, height, route, seed, vignetting):
    radius = diameter / 2
    scene = straight_scene(length, radius, seed=seed)
    cam = perspective_camera(base[0], base[1], hfov, k1, k2, width, height)
    n = frames[route]
    travel = gt_mm / 1000.0
    start = (length - travel) / 2
    legs = 2 if route == "forward-reverse" else 1
    pause = 8
    spacing = travel * legs / (n - 1 - (pause if legs == 2 else 0))
    drive = Drive(spacing_m=spacing, speed_variation=0.15, pause_frames=pause, offset_down_m=offset_down,
                  look="up", wobble_deg=0.3, wobble_m=0.001, start_m=start, end_m=start + travel,
                  reverse=route == "forward-reverse")
    ap = Appearance(texture_style="procedural", mm_per_px=mm_px, n_leds=4, led_phase_deg=45.0, led_ring_radius_m=ring,
                    led_beam_half_angle_deg=40.0, specular_strength=0.1, vignetting=vignetting)
    return Setup(name, scene, cam, scene.runs["S1"], drive, ap, fps,
                 notes={"report_frames": n, "distance_m": travel})


def _six_inch(width, height, route, seed):
    # 2010 report Table 1, pipe 1: 6 m, 153.32 mm inside, dragonfly 1024x768 at 7.5 fps, 70 deg;
    # datasets 1/2 forward (4256, 4176 images), dataset 3 forward & reverse (3369 images).
    return _straight_2010("paper-straight-6in", length=6.0, diameter=0.15332, gt_mm=5844.4, base=(1024, 768), hfov=70.0,
                          k1=-0.12, k2=0.02, fps=7.5, frames={"forward": 4256, "forward-reverse": 3369},
                          offset_down=0.025, ring=0.025, mm_px=0.4, width=width, height=height, route=route, seed=seed,
                          vignetting=0.35)


def _sixteen_inch(width, height, route, seed):
    # pipe 2: 4 m, 387.56 mm inside, firefly 640x480 at 30 fps, 25 deg; forward & reverse, 2392 images.
    return _straight_2010("paper-straight-16in", length=4.0, diameter=0.38756, gt_mm=3391.0, base=(640, 480), hfov=25.0,
                          k1=-0.05, k2=0.0, fps=30.0, frames={"forward-reverse": 2392, "forward": 1196},
                          offset_down=0.07, ring=0.04, mm_px=0.5, width=width, height=height, route=route, seed=seed,
                          vignetting=0.15)


# A sewer crawler's forward-looking CCTV camera: 100 deg across the image, barrel distortion, a ring of
# LEDs round the lens; the robot rolls and pitches up to 1 deg and moves a few mm sideways.
CCTV_BASE = dict(width=640, height=480, hfov_deg=100.0, k1=-0.25, k2=0.05)
CCTV_WOBBLE = dict(wobble_deg=1.0, wobble_m=0.003)


def cctv_camera(width=None, height=None) -> PinholeCamera:
    """The forward-looking CCTV camera; 720x576 (PAL) keeps the horizontal field of view."""
    b = CCTV_BASE
    return perspective_camera(b["width"], b["height"], b["hfov_deg"], b["k1"], b["k2"], width, height)


def _cctv_appearance() -> Appearance:
    # A video camera's gamma and an exposure that keeps the near wall from burning out; the wall's texture
    # at 0.5 mm, as a narrow lens magnifies it.
    return Appearance(mm_per_px=0.5, n_leds=8, led_ring_radius_m=0.03, led_beam_half_angle_deg=50.0, vignetting=0.4,
                      gamma=2.2, exposure_percentile=99.0, exposure_target=0.9)


_CCTV_ENDS = {"A": dict(start_back=0.8, end_before=-0.4), "B": dict(start_back=0.8, end_before=0.5)}


def _cctv_loop(width, height, route, seed):
    # 300 mm sewer pipe, a 3.0 m x 2.2 m loop of 1 m pieces with a tee at each corner.
    corners = np.array([[0, 0, 0], [3.0, 0, 0], [3.0, 2.2, 0], [0, 2.2, 0]], float)
    return _loop_setup("cctv-loop", corners, width, height, route, seed, stub=0.4, piece=1.0, sag=0.002,
                       misalign=0.001, radius=0.15, camera=cctv_camera(width, height), drive_extra=CCTV_WOBBLE,
                       appearance=_cctv_appearance(), **_CCTV_ENDS[route])


def _cctv_straight(width, height, route, seed):
    scene = straight_scene(6.0, 0.15, piece_length=1.0, sag_m=0.002, misalign_m=0.001, seed=seed)
    drive = Drive(spacing_m=0.01, offset_down_m=0.04, look="forward", start_m=0.5, end_m=5.0,
                  reverse=route == "forward-reverse", **CCTV_WOBBLE)
    return Setup("cctv-straight", scene, cctv_camera(width, height), scene.runs["S1"], drive, _cctv_appearance(), 7.5)


def _cctv_recording(width, height, route, seed):
    # The straight CCTV run as a crawler's recorder delivers it: PAL size, H.264 at CRF 28, text burned in,
    # the gain drifting and stepping, a flaky link (effects profile cctv-h264; effects="clean" for the clean frames).
    if width is None and height is None:
        width, height = 720, 576
    return replace(_cctv_straight(width, height, route, seed), name="cctv-recording", effects="cctv-h264")


def _wall_camera(mount_deg: float):
    """A 640x480, 70 deg camera looking at the wall of a 387.56 mm pipe from 3 cm beside and 4 cm below
    the axis, its optical axis at `mount_deg` to the pipe axis (turned towards the direction of travel)."""

    def build(width, height, route, seed):
        radius = 0.38756 / 2
        scene = straight_scene(4.0, radius, seed=seed)
        cam = perspective_camera(640, 480, 70.0, -0.12, 0.02, width, height)
        travel = 3.0
        start = (4.0 - travel) / 2
        drive = Drive(spacing_m=0.005, speed_variation=0.15, pause_frames=8, offset_down_m=0.04, offset_side_m=0.03,
                      look="up", mount_deg=float(mount_deg), start_m=start, end_m=start + travel,
                      reverse=route == "forward-reverse", **CCTV_WOBBLE)
        ap = Appearance(texture_style="procedural", mm_per_px=0.5, n_leds=4, led_phase_deg=45.0, led_ring_radius_m=0.04,
                        led_beam_half_angle_deg=40.0, specular_strength=0.1, vignetting=0.15)
        return Setup(f"wall-camera-{mount_deg:g}", scene, cam, scene.runs["S1"], drive, ap, 30.0,
                     notes={"distance_m": travel, "mount_deg": float(mount_deg), "offset_m": [0.03, -0.04]})

    return build


def _white_card(width, height, route, seed):
    """White-card frames of the 6-inch robot (route '6in') or the 16-inch one (route '16in')."""
    s = (_sixteen_inch if route == "16in" else _six_inch)(width, height, "forward", seed)
    ap = replace(s.appearance, texture_style="white", mm_per_px=1.0)
    drive = replace(s.drive, wobble_deg=0.0, wobble_m=0.0, speed_variation=0.0)
    return Setup("white-card", s.scene, s.camera, s.path_vertices, drive, ap, s.fps, frames=10, still=True,
                 gain_mask=True)


register_preset("paper-loop", "fisheye paper network: 400 mm tee loop after Table I, 190 deg fisheye 1280x960, 7.5 fps",
                ("A", "B"), _paper_loop)
register_preset("long-loop", "paper-loop's 400 mm pipe and fisheye at 640x480 around a 64 m x 64 m tee loop: "
                "route A about 25,900 frames (memory and speed over a long run)", ("A", "B"), _long_loop)
register_preset("paper-straight-6in", "2010 report pipe 1: 6 m x 153.32 mm, perspective 1024x768 70 deg, 4 LEDs",
                ("forward", "forward-reverse"), _six_inch)
register_preset("paper-straight-16in", "2010 report pipe 2: 4 m x 387.56 mm, perspective 640x480 25 deg, 4 LEDs",
                ("forward-reverse", "forward"), _sixteen_inch)
register_preset("fisheye-straight", "one straight 6 m x 400 mm pipe, 190 deg fisheye 1280x960 (recheck: in to 3 m, "
                "back to 2 m, on to 5 m and back out)", ("forward", "forward-reverse", "recheck"), _fisheye_straight)
register_preset("deformed-pipe", "straight 300 mm pipe, fisheye 640x480: round pieces between a 3 % and a 6 % "
                "oval piece and one with a 10 mm dent; routes short, tiny: pieces at 0.6, 0.4 of their length",
                ("full", "short", "tiny"), _deformed)
register_preset("demo-loop", "small 2 m x 1.5 m tee loop, fisheye 640x480 (fast)", ("A", "B"), _demo_loop)
register_preset("tee-pass-loop", "3.0 m x 2.2 m loop of 300 mm pipe, a tee at each corner, fisheye 640x480: "
                "A leaves T1's stub straight through T1, turns at T4, T3, T2, meets T1 head-on along its branch and "
                "turns into the stub; B passes T1 and T2 straight through", ("A", "B"), _tee_pass_loop)
register_preset("elbow-cross", "300 mm network of elbows and a cross, fisheye 640x480: A drives through a 90 deg elbow "
                "(bend radius 1.5 D), turns at the cross, then a 45 deg elbow (2 D) and a 30 deg sweeping bend (10 D); "
                "B drives the bends backwards and through the cross straight; C the 90 deg elbow and the cross "
                "straight along its main pipe", ("A", "B", "C"), _elbow_cross)
register_preset("cctv-loop", "sewer crawler's forward-looking CCTV (100 deg, barrel distortion, 640x480; 720x576 "
                "keeps the view) in a 3.0 m x 2.2 m loop of 300 mm pipe with a tee at each corner", ("A", "B"),
                _cctv_loop)
register_preset("cctv-straight", "forward-looking CCTV (100 deg, 640x480) in a straight 6 m x 300 mm pipe",
                ("forward", "forward-reverse"), _cctv_straight)
register_preset("cctv-recording", "cctv-straight as recorded footage: 720x576, camera effects profile cctv-h264 "
                "by default (H.264 CRF 28, counter and clock, gain drift and steps, 5 % repeated, 1 % dropped frames)",
                ("forward", "forward-reverse"), _cctv_recording)
for _mount in (90, 75, 50):
    register_preset(f"wall-camera-{_mount}", f"640x480 70 deg camera 3 cm beside and 4 cm below the axis of a "
                    f"387.56 mm pipe, its optical axis at {_mount} deg to the pipe axis",
                    ("forward-reverse", "forward"), _wall_camera(_mount))
register_preset("white-card", "2010 report gain-mask images: white wall, LEDs on, still camera; writes gain_mask.png; "
                "route = the robot", ("6in", "16in"), _white_card)


def _calibration(folder: Path, *, width=None, height=None, frames=None, seed=0, route=None, progress=None) -> None:
    """Checkerboard views through the chosen model: images/ and camera.yaml (the true camera and poses)."""
    from pipemap.sim.board import save_board_views

    model = route or "polynomial"
    if model not in CALIBRATION_MODELS:
        raise PipemapError(f"preset calibration has no route {model!r} "
                           f"(expected one of {', '.join(CALIBRATION_MODELS)})",
                           key="route")
    if model == "pinhole":
        camera = perspective_camera(1024, 768, 70.0, -0.12, 0.02, width, height)
    else:
        camera = fisheye_camera(width, height)
        if model == "kannala_brandt":
            f = camera.params[0]
            camera = KannalaBrandtCamera(camera.width, camera.height,
                                         dict(fx=f, fy=f, cx=camera.params[4], cy=camera.params[5],
                                              k1=-0.02, k2=0.003, k3=0.0, k4=0.0), camera.max_theta_deg)
    n = 20 if frames is None else int(frames)
    if n < 3:
        raise PipemapError(f"calibration needs at least 3 views, got {n}", key="frames")
    save_board_views(folder, camera, n_views=n, seed=seed)
    if progress is not None:
        progress(n, n)


CALIBRATION_MODELS = ("polynomial", "kannala_brandt", "pinhole")
register_preset("calibration", "9x6 checkerboard views (25 mm squares) for pipemap calibrate; route = camera model",
                CALIBRATION_MODELS, writer=_calibration)
