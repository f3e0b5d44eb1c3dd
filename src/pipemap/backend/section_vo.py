"""Straight-section metric visual odometry (fisheye paper III-C): keyframes in, metric poses and points out.

For each new keyframe:
  1. its pose is the previous keyframe's composed with the front end's five-point (R, unit t);
  2. the length of t (the relative scale) is the weighted median, over tracks that already have a
     3D point, of |point depth in the previous keyframe| / (depth triangulated in the unit-baseline
     pair); weights are the squared parallax of the pair, so far points near the optical axis count little;
  3. tracks without a point are triangulated from all their observations (midpoint + angular
     Gauss-Newton on bearings, `triangulate`), kept when in front of every ray, with enough parallax
     and consistent with every bearing.
Windows: once a section has `first_window` keyframes, and then every `bundle.step` keyframes, a
sliding-window SBA (`BundleProblem`) runs over its last `bundle.window` keyframes with a cylinder
of the a-priori radius fitted to the window's points (eq. 2-6), its axis allowed the small bend of
a sagging run (`bundle.bend_knot_m`, `pipemap.geometry.bend`). Gauge: every pose older
than the window and every pose of the window already solved by a previous window is held
(`fixed_share` limits that to the oldest share, `fixed_overlap` to the oldest few), so consecutive
windows chain; the first window holds its first pose. A section's last keyframes get a final (partial) window
when it ends.

Metric scale comes from the radius alone. The section starts at unit scale (one unit per first
keyframe step); before its first window solve, the whole section is scaled by r / free_radius of
a cylinder fitted to the window's points with the radius free, and the SBA with the cylinder term
(tau > 0) then refines the scale. With tau = 0 the first window keeps the distance between its
first and last poses (so the free-radius rescale is all the metric information there is) and
later windows inherit the scale through their held poses.

Sections: a keyframe with pose_valid False (tracking lost) starts a new section with no link to the
previous one. Its first pose is put at the previous keyframe's pose (the camera cannot be far: the
front end gives up after `frontend.max_lost_frames` untracked frames), so the trajectory stays
continuous but the motion during the gap is lost; the new section gets its own metric scale from its
own first window. A section too short for a cylinder fit takes the previous section's mean keyframe
step as its step length ("scale": "assumed") or stays at unit scale if there is none ("unit").
Everything is deterministic: no random choices are made here.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from pipemap.backend.bundle import BundleProblem, Observations
from pipemap.backend.resection import resect
from pipemap.backend.triangulate import triangulate_rays
from pipemap.backend.wall_reach import straight_reach
from pipemap.camera.base import CameraModel
from pipemap.config import Settings
from pipemap.frontend.angular import pixel_angle
from pipemap.frontend.tracks import Keyframe
from pipemap.geometry.cylinder import fit_cylinder, foremost, path_chord
from pipemap.geometry.rotations import exp_so3, log_so3
from pipemap.geometry.se3 import world_to_camera
from pipemap.frontend.image_steps import image_step


@dataclass
class WindowReport:
    section: int
    first: int  # keyframe numbers (inclusive)
    last: int
    fixed: int
    points: int
    observations: int
    time_s: float
    iterations: int
    rms_px: float
    cylinder_rms_m: float
    rescale: float  # the rescale applied before this solve: the section's by its free radius (first window), or
    # the not yet solved keyframes' so that their points meet the wall of the solved ones
    step_scale: float  # mean keyframe step length in the window after the solve over before it
    tail_turn_deg: float = 0.0  # how far the not yet solved keyframes were turned onto the solved wall first

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}


@dataclass
class SectionReport:
    number: int
    first: int  # keyframe numbers (inclusive)
    last: int
    scale: str  # "cylinder" (metric from r), "assumed" (previous section's step length) or "unit"
    windows: int = 0
    kind: str = "straight"  # "straight" or "junction" (image classification, fisheye paper III-B)
    linked: bool = False  # continues the previous section's chain (tracks, pose and scale carry over)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class StraightResult:
    timestamps: np.ndarray  # (N,) of the keyframes
    indices: np.ndarray  # (N,) image indices
    poses: np.ndarray  # (N, 4, 4) T_wc, metres
    points: np.ndarray  # (M, 3) live scene points
    point_tracks: np.ndarray  # (M,) their track ids
    sections: list[SectionReport]
    windows: list[WindowReport]
    seconds: dict = field(default_factory=dict)  # "relative" (scale + triangulation), "windows"
    active: list[np.ndarray] = field(default_factory=list)  # per keyframe: observations not rejected as outliers


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values, kind="stable")
    cw = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cw, 0.5 * cw[-1])])


@dataclass(frozen=True)
class SpentKeyframe:
    """What StraightVO keeps of a keyframe that no window can reach any more (`forget_spent`)."""

    number: int
    index: int
    timestamp: float


# A tail turned onto the solved wall must cut its points' misfit to this share of the best scale alone's.
TAIL_TURN_GAIN = 0.5

# Keyframes beyond the window kept whole, besides the window itself (a window reaches `bundle.window` back).
SPENT_MARGIN = 5


class StraightVO:
    """Feed keyframes in order with `add`; `finish` closes the last section and returns the result.
    `forget_spent`: keep only the number, image index and time of keyframes more than a window behind the newest
    (where the VO runs in a process of its own, whose keyframes the run holds anyway), so that its memory does
    not grow with their features."""

    def __init__(self, camera: CameraModel, radius: float, settings: Settings | None = None,
                 forget_spent: bool = False):
        self.camera = camera
        self.forget_spent = forget_spent
        self.radius = float(radius)
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"the pipe radius must be positive, got {radius!r}")
        settings = settings or Settings()
        self.b = settings.bundle
        self.s = settings.straight_vo
        self.keyframes: list[Keyframe] = []
        self.R: list[np.ndarray] = []  # R_wc per keyframe
        self.c: list[np.ndarray] = []  # camera centre per keyframe
        self.active: list[np.ndarray] = []  # per keyframe: observation not rejected as an outlier
        self.sections: list[SectionReport] = []
        self.windows: list[WindowReport] = []
        self._X = np.zeros((0, 3))
        self._has = np.zeros(0, bool)
        self._dead = np.zeros(0, bool)
        self._first_kf = np.zeros(0, np.int64)
        self._solved_until = -1  # keyframes up to this number were solved by a window of the current section
        self._metric = False
        self._first_tid = 0
        self._chain_first = 0  # first keyframe of the current unbroken chain of linked sections
        m = self.s.max_colatitude_deg
        self._min_cos = -1.0 if m is None else float(np.cos(np.radians(m)))
        self._t_rel = 0.0
        self._t_win = 0.0
        # A camera that cannot see the wall beside it (a forward perspective camera) has five-point poses that
        # trade rotation for sideways steps and a chained scale that slips: its keyframes are resected and its
        # scale watched. A fisheye needs neither, and both cost it (paper-loop route A: Table I 0.15 -> 0.30 %
        # with resection; compressed footage set the drift check off every few keyframes).
        narrow = not camera.sees_beside()
        self._drift_check = self.s.scale_drift is not None and narrow
        self._resection = self.s.resection_min_points is not None and narrow
        # The wall ahead is all a forward camera sees of a window's pipe: cut at a bend's first sign it left the
        # cylinder too little (cctv-loop route B seeds 1 / 2, the same tracks: Table I 0.156 / 0.193 -> 0.229 /
        # 0.198 %). A fisheye sees the wall beside it.
        self._bend_check = self.s.wall_inward_m is not None and not narrow
        self._resected = False  # the newest keyframe's pose was refined against its scene points (or resection is off)
        self._wall = None  # the current section's wall as its last window solve left it
        self._ending: SectionReport | None = None  # a straight section whose final window waits (`end_lookahead`)
        self._fresh: list[np.ndarray] = []  # points triangulated since then
        self._huber_rad = self.b.huber_px * pixel_angle(camera)

    # -- storage --------------------------------------------------------------------------

    def _grow(self, max_tid: int) -> None:
        n = len(self._has)
        if max_tid < n:
            return
        m = max(max_tid + 1, 2 * n, 1024)
        X = np.full((m, 3), np.nan)
        X[:n] = self._X
        has, dead, first = np.zeros(m, bool), np.zeros(m, bool), np.full(m, -1, np.int64)
        has[:n], dead[:n], first[:n] = self._has, self._dead, self._first_kf
        self._X, self._has, self._dead, self._first_kf = X, has, dead, first

    @property
    def section(self) -> SectionReport:
        return self.sections[-1]

    # -- per keyframe ---------------------------------------------------------------------

    def add(self, kf: Keyframe, junction: bool = False) -> None:
        """Add the next keyframe; `junction` is its image class (fisheye paper III-B). A change of
        class starts a new section linked to the previous one: no window spans a junction and a
        junction section has no straight-cylinder window of its own (the tee model joins it)."""
        t0 = time.perf_counter()
        if kf.number != len(self.keyframes):
            raise ValueError(f"keyframes must come in order: expected number {len(self.keyframes)}, got {kf.number}")
        tids = np.asarray(kf.track_ids, np.int64)
        if len(tids):
            self._grow(int(tids.max()))
        k = len(self.keyframes)
        kind = "junction" if junction else "straight"
        broken = k == 0 or not kf.pose_valid
        if broken:
            if k > 0:
                self._close_section()
            R, c = (np.eye(3), np.zeros(3)) if k == 0 else (self.R[-1].copy(), self.c[-1].copy())
            self.sections.append(SectionReport(len(self.sections), k, k, "unit", kind=kind))
            self._solved_until, self._metric = -1, False
            self._wall, self._fresh = None, []
            self._first_tid = int(tids.min()) if len(tids) else len(self._has)
            self._chain_first = k
        else:
            if kind != self.section.kind:
                self._close_section(wait=True)
                self.sections.append(SectionReport(len(self.sections), k, k, self.section.scale, kind=kind,
                                                   linked=True))
                self._wall, self._fresh = None, []
            s = self._relative_scale(kf)
            Rp, cp = self.R[-1], self.c[-1]
            R = Rp @ kf.R.T
            c = cp - R @ (kf.t * s)
            R, c = self._resect(kf, R, c)
        self.keyframes.append(kf)
        spent = k - self.b.window - SPENT_MARGIN
        if self.forget_spent and spent >= 0:
            old = self.keyframes[spent]
            self.keyframes[spent] = SpentKeyframe(old.number, old.index, old.timestamp)
        self.R.append(R)
        self.c.append(c)
        self.active.append(np.ones(len(tids), bool))
        fresh = self._first_kf[tids] < 0
        self._first_kf[tids[fresh]] = k
        self.section.last = k
        if not broken:
            self._triangulate(kf)
        self._t_rel += time.perf_counter() - t0
        if self._ending is not None and k - self._ending.last >= self.s.end_lookahead:
            self._window(self._ending)
        n = k - self.section.first + 1
        if n == self.s.first_window or (n > self.s.first_window and n % self.b.step == 0) or self._drifted():
            self._window()

    def _relative_scale(self, kf: Keyframe) -> float:
        """Length of the new step, from tracks that already have 3D points (see the module docstring)."""
        prev = self.keyframes[-1]
        last_step = self._speed_step(kf)
        cur = np.flatnonzero(kf.inliers)
        _, ip, ic = np.intersect1d(prev.track_ids, kf.track_ids[cur], assume_unique=True, return_indices=True)
        ic = cur[ic]
        tid = kf.track_ids[ic]
        ok = self._has[tid] & self.active[-1][ip] & (tid >= self._first_tid)
        ip, ic, tid = ip[ok], ic[ok], tid[ok]
        if len(tid) < self.s.min_scale_points:
            return float(last_step)
        Xp = world_to_camera(self.R[-1], self.c[-1], self._X[tid])
        a = prev.bearings[ip] @ kf.R.T  # previous bearings in the new camera's axes
        b = kf.bearings[ic]
        # Depth along the previous bearing of the unit-baseline two-view midpoint.
        ab = np.sum(a * b, 1)
        at, bt = a @ kf.t, b @ kf.t
        den = 1.0 - ab * ab
        lam_i = (ab * bt - at) / np.where(den > 1e-12, den, 1e-12)
        lam_j = (bt - ab * at) / np.where(den > 1e-12, den, 1e-12)
        parallax = np.arccos(np.clip(ab, -1.0, 1.0))
        depth = np.einsum("ki,ki->k", Xp, prev.bearings[ip])
        use = (lam_i > 0) & (lam_j > 0) & (depth > 0) & (parallax > np.radians(self.s.scale_min_parallax_deg))
        if use.sum() < self.s.min_scale_points:
            return float(last_step)
        return _weighted_median(depth[use] / lam_i[use], parallax[use] ** 2)

    def _resect(self, kf: Keyframe, R: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The chained pose refined against the scene points the keyframe sees (`resection`), when
        there are enough of them."""
        self._resected = not self._resection  # without resection no keyframe is better held
        if self._resected:
            return R, c
        rows = np.flatnonzero(kf.inliers)
        tid = kf.track_ids[rows]
        ok = self._has[tid] & (tid >= self._first_tid)
        if ok.sum() < self.s.resection_min_points:
            return R, c
        res = resect(R, c, self._X[tid[ok]], kf.bearings[rows[ok]], self._huber_rad)
        if res.inliers.sum() < self.s.resection_min_points:
            return R, c
        self._resected = True
        return res.R, res.c

    def _speed_step(self, kf: Keyframe, steps: int = 5) -> float:
        """The new step's length if the robot kept its recent speed: the median speed of the chain's last
        few steps times the time this one took. Keyframes come at uneven intervals (a forward view loses
        its near tracks in bursts), and one step can be off (a window solved at a keyframe that saw few
        points), so neither the last step's length nor its speed alone serves."""
        k = len(self.c) - 1
        lo = max(self._chain_first, k - steps)
        if k <= lo:
            return 1.0
        c = np.stack(self.c[lo:k + 1])
        t = np.array([f.timestamp for f in self.keyframes[lo:k + 1]])
        length = np.linalg.norm(np.diff(c, axis=0), axis=1)
        dt = np.diff(t)
        dt_now = kf.timestamp - t[-1]
        if not (dt > 0).all() or not dt_now > 0:
            return float(length[-1])
        return float(np.median(length / dt) * dt_now)

    def _observations(self, tids: np.ndarray, lo: int, hi: int):
        """Active observations of the sorted tracks `tids` in keyframes lo..hi:
        (keyframe, position in tids, world ray direction)."""
        kfs, which, dirs = [], [], []
        for k in range(lo, hi + 1):
            kf = self.keyframes[k]
            _, it, ik = np.intersect1d(tids, kf.track_ids, assume_unique=True, return_indices=True)
            ok = self.active[k][ik]
            kfs.append(np.full(int(ok.sum()), k))
            which.append(it[ok])
            dirs.append(kf.bearings[ik[ok]] @ self.R[k].T)
        return np.concatenate(kfs), np.concatenate(which), np.concatenate(dirs)

    def _triangulate(self, kf: Keyframe) -> None:
        tids = kf.track_ids[kf.inliers]
        tids = np.sort(tids[~self._has[tids] & ~self._dead[tids] & (tids >= self._first_tid)])
        if not len(tids):
            return
        lo = max(int(self._first_kf[tids].min()), self._chain_first, kf.number - self.b.window + 1)
        ks, which, d = self._observations(tids, lo, kf.number)
        c = np.stack(self.c)[ks] if len(ks) else np.zeros((0, 3))
        tri = triangulate_rays(c, d, which, len(tids), min_parallax_deg=self.s.min_parallax_deg)
        good = tri.valid & (tri.max_error_deg <= self.s.max_ray_error_deg)
        self._X[tids[good]] = tri.points[good]
        self._has[tids[good]] = True
        self._fresh.append(tids[good])

    def _drifted(self) -> bool:
        """Whether the points triangulated since the last window solve have left its wall by more than
        `scale_drift` in radius: the chained scale has slipped, and a window should solve now, while the
        slip is small enough for its cylinder fit to keep those points."""
        # A keyframe that sees few scene points (its pose chained, not resected) would end the window
        # loosely held: wait for one that the scene fixes.
        if (self._wall is None or not self._drift_check or self.section.kind != "straight"
                or len(self._fresh) < self.s.min_window_keyframes or not self._resected):
            return False
        # the newest keyframes' points, enough of them for a median: the slip shows there first
        recent, count = [], 0
        for tids in reversed(self._fresh):
            tids = tids[self._has[tids]]
            recent.append(tids)
            count += len(tids)
            if count >= self.s.min_window_points:
                break
        if count < self.s.min_window_points:
            return False
        ratio = 1.0 + float(np.median(self._wall.distance(self._X[np.concatenate(recent)]))) / self.radius
        return abs(ratio - 1.0) > self.s.scale_drift

    # -- windows ------------------------------------------------------------------------

    def _window(self, ending: SectionReport | None = None) -> None:
        """The current section's window, or the waiting final window of the section `ending` through the
        keyframes since it ended."""
        t0 = time.perf_counter()
        try:
            if ending is None:
                self._solve_window(self.section, self.section.last)
            else:
                self._ending = None
                self._solve_window(ending, len(self.keyframes) - 1)
        finally:
            self._t_win += time.perf_counter() - t0

    def _section_points(self) -> np.ndarray:
        tids = np.flatnonzero(self._has)
        return tids[tids >= self._first_tid]

    def _rescale_section(self, f: float) -> None:
        """Scale the current chain (its linked sections so far) about its first camera centre."""
        sec = self.section
        o = self.c[self._chain_first].copy()
        for k in range(self._chain_first, sec.last + 1):
            self.c[k] = o + f * (self.c[k] - o)
        tids = self._section_points()
        self._X[tids] = o + f * (self._X[tids] - o)

    def _rescale_tail(self, uniq: np.ndarray, first: int, last: int, R0: np.ndarray,
                      c0: np.ndarray) -> tuple[float, float]:
        """Scale the keyframes no window has solved yet, and the points they triangulated, about the last
        solved camera so that those points meet the wall of the solved part; returns the factor and the
        angle (deg) they were turned by (below).

        Between windows the relative scale is chained from step to step; a camera looking along the pipe
        can let it slip by tenths over a window's 50 keyframes (cctv-loop: 0.6). Its points then lie well
        inside the wall, the window's cylinder fit takes them for outliers, and the solve keeps the slip.
        The first window rescales a whole section by its free radius for the same reason.

        The chain can turn as well as slip: where its relative rotations are poor (320x240 H.264 CCTV
        footage: 0.5-1.7 deg a keyframe) the unsolved keyframes' own wall ran 6 deg off the solved one, so
        that no scale put their points on it and the best one halved the steps (the straight pipe 21 %
        short; the solve kept it). So the tail is also turned about the last solved camera until its own
        wall's axis runs along the solved one, and scaled again: kept where its points miss the wall by more
        than the Huber threshold and the turn at least halves that (TAIL_TURN_GAIN), which a tail that only
        slipped does not."""
        held_until = self._solved_until
        if not first <= held_until < last:
            return 1.0, 0.0
        tail = self._first_kf[uniq] > held_until
        if tail.sum() < self.s.min_window_points or (~tail).sum() < self.s.min_window_points:
            return 1.0, 0.0
        try:
            fit = fit_cylinder(self._X[uniq[~tail]], self.radius, reference=(R0, c0),
                               direction=path_chord(self.c[first:held_until + 1]), huber=self.b.huber_m)
        except (ValueError, np.linalg.LinAlgError):
            return 1.0, 0.0
        o = self.c[held_until].copy()
        X = self._X[uniq[tail]] - o

        def misfit(turn: np.ndarray, f: float) -> float:
            return float(np.median(np.abs(fit.cylinder.distance(o + f * X @ turn.T))))

        def best_scale(turn: np.ndarray) -> float:
            return float(minimize_scalar(lambda f: misfit(turn, f), bounds=(0.25, 4.0), method="bounded",
                                         options={"xatol": 1e-4}).x)

        turn, f = np.eye(3), best_scale(np.eye(3))
        if not misfit(turn, f) < misfit(turn, 1.0):
            f = 1.0
        # a tail whose points already meet the wall within the Huber threshold has nothing to turn
        own = None if misfit(turn, f) <= self.b.huber_m else self._tail_turn(uniq[tail], fit.cylinder.direction,
                                                                              held_until, last)
        if own is not None:
            g = best_scale(own)
            if misfit(own, g) < TAIL_TURN_GAIN * misfit(turn, f):
                turn, f = own, g
        if f == 1.0 and turn is not own:
            return 1.0, 0.0
        if not self._steps_agree(held_until, last, f):
            return 1.0, 0.0
        for k in range(held_until + 1, last + 1):
            self.c[k] = o + f * turn @ (self.c[k] - o)
            self.R[k] = turn @ self.R[k]
        tids = self._section_points()
        later = tids[self._first_kf[tids] > held_until]
        self._X[later] = o + f * (self._X[later] - o) @ turn.T
        return f, float(np.degrees(np.linalg.norm(log_so3(turn))))

    def _steps_agree(self, held_until: int, last: int, f: float) -> bool:
        """Whether scaling keyframes held_until+1..last by `f` leaves their steps near those their features' image
        motion shows (frontend/image_steps.py): within `straight_vo.tail_image_step` either way, or nearer than
        before. The tail's points can lie anywhere when its relative poses are poor, and the scale that put them
        on the wall had shrunk a CCTV run at 320x240 as H.264 to 0.25 of its steps, window after window."""
        limit = self.s.tail_image_step
        if limit is None:
            return True
        ratios = []
        for k in range(held_until + 1, last + 1):
            seen = image_step(self.keyframes[k - 1], self.keyframes[k], self.radius)
            made = float(np.linalg.norm(self.c[k] - self.c[k - 1]))
            if np.isfinite(seen) and seen > 0 and made > 0:
                ratios.append(made / seen)
        if len(ratios) < self.s.min_window_keyframes:
            return True
        before = abs(np.log(np.median(ratios)))
        return abs(np.log(np.median(ratios) * f)) <= max(before, np.log(limit))

    def _tail_turn(self, tids: np.ndarray, axis: np.ndarray, held_until: int, last: int) -> np.ndarray | None:
        """The rotation that turns the axis of the wall the points `tids` lie on (a cylinder of free radius
        fitted to them) onto `axis`, or None when none fits."""
        try:
            own = fit_cylinder(self._X[tids], self.radius, direction=path_chord(self.c[held_until:last + 1]),
                               huber=self.b.huber_m)
        except (ValueError, np.linalg.LinAlgError):
            return None
        a = np.asarray(axis, float) / np.linalg.norm(axis)
        b = np.asarray(own.cylinder.direction, float) / np.linalg.norm(own.cylinder.direction)
        b = b if a @ b >= 0 else -b
        v = np.cross(b, a)
        return exp_so3(v / max(np.linalg.norm(v), 1e-12) * np.arctan2(np.linalg.norm(v), float(a @ b)))

    def _solve_window(self, sec: SectionReport, last: int, whole: bool = False) -> None:
        """Solve the window of straight section `sec` that ends at keyframe `last` (after the section's own last
        keyframe when its final window waited for the keyframes beyond it); `whole`: every keyframe of the section,
        only its first pose held (solve_turning_sections)."""
        if sec.kind != "straight":
            return
        first = sec.first if whole else max(sec.first, sec.last - self.b.window + 1)
        n = last - first + 1
        if n < self.s.min_window_keyframes or (last <= self._solved_until and not whole):
            return
        ks, rows, pixels, uniq, inv = self._window_observations(first, last)
        wall = self._straight_wall(uniq, first, last, sec.last)
        if wall.sum() < self.s.min_window_points:
            return
        R = np.stack(self.R[first:last + 1])
        scaled = self._window_cylinder(uniq, first, last, R, wall, sec.last)
        if scaled is None:
            return
        fit, c, rescale, turned = scaled
        R = np.stack(self.R[first:last + 1])  # the tail's, turned onto the solved wall
        on_wall = np.zeros(len(uniq), bool)
        on_wall[np.flatnonzero(wall)[fit.inliers]] = True
        fixed = [0] if whole else self._held_poses(first, last)
        kwargs = dict(fixed_poses=fixed, cylinder=fit, cylinder_reference=0, cylinder_points=on_wall)
        if self.b.tau <= 0 and len(fixed) < 2:
            kwargs["fixed_distance"] = (0, n - 1)
        obs = Observations(ks - first, inv, pixels)
        if self.b.track_age_keyframes is not None:
            kwargs["observation_sigma"] = 1.0 + (ks - self._first_kf[uniq[inv]]) / self.b.track_age_keyframes
        before = np.mean(np.linalg.norm(np.diff(c, axis=0), axis=1))
        res = BundleProblem.from_settings(self.camera, (R, c), self._X[uniq], obs, self.b, **kwargs).solve()
        after = self._take_window(res, uniq, first, last, ks, rows, R[0])
        sec.scale = "cylinder"
        sec.windows += 1
        self.windows.append(WindowReport(sec.number, int(first), int(last), len(fixed), len(uniq), len(obs),
                                         float(res.time_s), int(res.iterations), float(res.rms_px),
                                         float(res.cylinder_rms_m), float(rescale), float(after / before),
                                         turned))

    def _window_observations(self, first: int, last: int):
        """Observations of live points in keyframes first..last, a point needing two of them: (keyframe, row in
        it, pixel) of each, the points' track ids (sorted) and each observation's position among them."""
        ks, rows, tids, pixels = [], [], [], []
        for k in range(first, last + 1):
            kf = self.keyframes[k]
            r = np.flatnonzero(self.active[k] & self._has[kf.track_ids] & (kf.track_ids >= self._first_tid)
                               & (kf.bearings[:, 2] >= self._min_cos))
            ks.append(np.full(len(r), k))
            rows.append(r)
            tids.append(kf.track_ids[r])
            pixels.append(kf.keypoints[r])
        ks, rows, tids, pixels = (np.concatenate(a) for a in (ks, rows, tids, pixels))
        uniq, inv, counts = np.unique(tids, return_inverse=True, return_counts=True)
        keep = counts[inv] >= 2
        ks, rows, tids, pixels = ks[keep], rows[keep], tids[keep], pixels[keep]
        uniq, inv = np.unique(tids, return_inverse=True)
        return ks, rows, pixels, uniq, inv

    def _straight_wall(self, uniq: np.ndarray, first: int, last: int, end: int) -> np.ndarray:
        """(len(uniq),) bool: the points the window's cylinder term holds: those no further than `wall_ahead_m`
        ahead of its last keyframe `last`, nor than `end_wall_ahead_m` ahead of the section's last keyframe `end`
        when the window runs on past it, nor beyond where the wall ahead of `last` comes in as a bend's does
        (`wall_inward_m`, backend/wall_reach.py); every point before the section has a metric scale."""
        wall = np.ones(len(uniq), bool)
        if not self._metric:
            return wall
        # Ahead of the foremost camera along the way there, and ahead of the section's end along the way to it:
        # a crawler that turned back within the window or section ends about where it began.
        fore = first + foremost(self.c[first:last + 1])
        limits = [] if self.s.wall_ahead_m is None else [(fore, first, self.s.wall_ahead_m)]
        if end + 1 < len(self.c):
            limits.append((end, end - foremost(self.c[first:end + 1][::-1]), self.s.end_wall_ahead_m))
        travel = self.c[fore] - self.c[first]
        if self._bend_check and np.linalg.norm(travel) > 0:
            limits.append((fore, first, straight_reach(self._X[uniq], self.c[fore], travel, self.radius,
                                                       inward_m=self.s.wall_inward_m, slice_m=self.s.wall_slice_m,
                                                       huber=self.b.huber_m)))
        for k, start, ahead in limits:
            u = self.c[k] - self.c[start]
            if np.linalg.norm(u) > 0:
                wall &= (self._X[uniq] - self.c[k]) @ (u / np.linalg.norm(u)) <= ahead
        return wall

    def _window_cylinder(self, uniq: np.ndarray, first: int, last: int, R: np.ndarray, wall: np.ndarray,
                         end: int):
        """The cylinder of the window's points on the straight wall (`wall`), after the rescale that puts them
        on it (the section's by its free radius before its first window, the tail's after): (fit, window camera
        centres, rescale, the tail's turn in deg), or None when no cylinder fits. `end`: the section's last keyframe."""
        uniq = uniq[wall]
        c = np.stack(self.c[first:last + 1])
        direction = path_chord(c[:end - first + 1])
        if np.linalg.norm(direction) <= 0:
            direction = R[0][:, 2]
        rescale, turned = 1.0, 0.0
        huber = self.b.huber_m
        if self._metric:
            rescale, turned = self._rescale_tail(uniq, first, last, R[0], c[0])
            c = np.stack(self.c[first:last + 1])
        else:
            # Unknown units: put the Huber threshold at the same fraction of the (rough) radius.
            u = direction / np.linalg.norm(direction)
            v = self._X[uniq] - c[0]
            rough = float(np.median(np.linalg.norm(v - (v @ u)[:, None] * u, axis=1)))
            huber *= rough / self.radius
        try:
            fit = fit_cylinder(self._X[uniq], self.radius, reference=(R[0], c[0]), direction=direction, huber=huber)
            if not self._metric:
                rescale = self.radius / fit.free_radius
                self._rescale_section(rescale)
                c = np.stack(self.c[first:last + 1])
                fit = fit_cylinder(self._X[uniq], self.radius, reference=(R[0], c[0]),
                                   direction=path_chord(c[:end - first + 1]), huber=self.b.huber_m)
        except (ValueError, np.linalg.LinAlgError):
            return None
        return fit, c, rescale, turned

    def _held_poses(self, first: int, last: int) -> list[int]:
        """The window's poses (0 = keyframe `first`) the solve holds: the first pose of a section's first window,
        else the oldest of those a previous window solved (`fixed_share`, `fixed_overlap`)."""
        numbers = np.arange(first, last + 1)
        if self._solved_until < first:
            return [0]
        fixed = np.flatnonzero(numbers <= self._solved_until)
        if self.s.fixed_share is not None:
            fixed = fixed[: max(int(round(self.s.fixed_share * len(fixed))), 1)]
        if self.s.fixed_overlap is not None:
            fixed = fixed[: max(self.s.fixed_overlap, 1)]
        return fixed.tolist()

    def _take_window(self, res, uniq: np.ndarray, first: int, last: int, ks: np.ndarray, rows: np.ndarray,
                     R0: np.ndarray) -> float:
        """Keep a window's solve: its poses and points, its outliers dropped, the wall it leaves; returns the mean
        keyframe step length after it."""
        numbers = np.arange(first, last + 1)
        for i, k in enumerate(numbers):
            self.R[k] = res.poses[i, :3, :3].copy()
            self.c[k] = res.poses[i, :3, 3].copy()
        good = res.point_inliers & np.all(np.isfinite(res.points), axis=1)
        self._X[uniq[good]] = res.points[good]
        self._has[uniq[~good]] = False
        self._dead[uniq[~good]] = True
        out = ~res.inliers
        for k, r in zip(ks[out], rows[out]):
            self.active[k][r] = False
        after = np.mean(np.linalg.norm(np.diff(res.poses[:, :3, 3], axis=0), axis=1))
        try:
            self._wall = fit_cylinder(res.points[good], self.radius, reference=(R0, res.poses[0, :3, 3]),
                                      direction=path_chord(res.poses[:, :3, 3]),
                                      huber=self.b.huber_m).cylinder
        except (ValueError, np.linalg.LinAlgError):
            self._wall = None
        self._fresh = []
        self._solved_until = last
        self._metric = True
        return after

    def _close_section(self, wait: bool = False) -> None:
        """The final (partial) window; a fallback scale for a section with no window at all. `wait`: a junction
        section follows, and a metric straight section's final window waits for its keyframes (`end_lookahead`)."""
        if self._ending is not None:
            self._window(self._ending)
        sec = self.section
        if wait and self.s.end_lookahead is not None and self._metric and sec.kind == "straight":
            self._ending = sec
            return
        self._window()
        if self._metric or sec.last == sec.first:
            if sec.last == sec.first and not self._metric:
                sec.scale = "none needed"
            return
        metric = [s for s in self.sections[:-1] if s.scale == "cylinder" and s.last > s.first]
        if metric:
            p = metric[-1]
            ref = np.mean(np.linalg.norm(np.diff(np.stack(self.c[p.first:p.last + 1]), axis=0), axis=1))
            own = np.mean(np.linalg.norm(np.diff(np.stack(self.c[sec.first:sec.last + 1]), axis=0), axis=1))
            if own > 0:
                self._rescale_section(ref / own)
                sec.scale = "assumed"

    def solve_turning_sections(self) -> bool:
        """Solve whole each straight section in which the crawler turned back by more than
        `straight_vo.whole_turn_back_m` along its pipe (a camera that sees the wall beside it; at most
        `whole_max_keyframes`), only its first pose held, and move the keyframes and points after it by the change
        of its last pose. Each window held the oldest poses it shared with the one before, with the scale the chain
        had slipped by since; through a turning point, seen by both legs, that left the last 0.3 m before it 0.5 %
        short on compressed footage. Needs every keyframe whole (after finish, as StraightVOBeside returns it).
        True when a section was solved."""
        if self.s.whole_turn_back_m is None or not self.camera.sees_beside() or not self._metric:
            return False
        solved, first_tid = False, self._first_tid
        self._first_tid = 0  # an earlier section's points as well as the newest chain's
        for sec in self.sections:
            size = sec.last - sec.first + 1
            if (sec.kind != "straight" or sec.scale != "cylinder" or size > self.s.whole_max_keyframes
                    or _turn_back_m(np.stack(self.c[sec.first:sec.last + 1])) <= self.s.whole_turn_back_m):
                continue
            R_old, c_old = self.R[sec.last].copy(), self.c[sec.last].copy()
            t0 = time.perf_counter()
            self._solved_until = len(self.keyframes) - 1  # no unsolved tail to rescale
            self._solve_window(sec, sec.last, whole=True)
            self._t_win += time.perf_counter() - t0
            turn = self.R[sec.last] @ R_old.T
            for k in range(sec.last + 1, len(self.keyframes)):
                self.R[k] = turn @ self.R[k]
                self.c[k] = turn @ (self.c[k] - c_old) + self.c[sec.last]
            later = self._has & (self._first_kf > sec.last)
            self._X[later] = (self._X[later] - c_old) @ turn.T + self.c[sec.last]
            solved = True
        self._solved_until, self._first_tid = len(self.keyframes) - 1, first_tid
        return solved

    def finish(self) -> StraightResult:
        if self.keyframes:
            self._close_section()
        return self.result()

    def result(self) -> StraightResult:
        """The poses, points, sections and windows as they stand."""
        poses = np.tile(np.eye(4), (len(self.keyframes), 1, 1))
        if self.keyframes:
            poses[:, :3, :3] = np.stack(self.R)
            poses[:, :3, 3] = np.stack(self.c)
        tids = np.flatnonzero(self._has)
        return StraightResult(
            np.array([k.timestamp for k in self.keyframes], float),
            np.array([k.index for k in self.keyframes], np.int64),
            poses, self._X[tids].copy(), tids, list(self.sections), list(self.windows),
            {"relative": self._t_rel, "windows": self._t_win}, [a.copy() for a in self.active])


def _turn_back_m(c: np.ndarray) -> float:
    """How far (m) camera centres `c` (N, 3) came back along their main direction from a point where they turned
    back: at either end of their reach, the lesser of the way there and the way back."""
    if len(c) < 3:
        return 0.0
    d = c - c.mean(axis=0)
    along = d @ np.linalg.svd(d, full_matrices=False)[2][0]
    return float(max(min(abs(along[k] - along[0]), abs(along[k] - along[-1]))
                     for k in (int(np.argmax(along)), int(np.argmin(along)))))


def run_straight(keyframes, camera: CameraModel, radius: float, settings: Settings | None = None) -> StraightResult:
    """Run the straight-section VO over a list (or stream) of keyframes."""
    vo = StraightVO(camera, radius, settings)
    for kf in keyframes:
        vo.add(kf)
    return vo.finish()


__all__ = ["StraightVO", "StraightResult", "SectionReport", "WindowReport", "run_straight"]
