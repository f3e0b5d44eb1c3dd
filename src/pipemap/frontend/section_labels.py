"""Each keyframe's section class (junction or straight), decided while the frames are still being tracked.

The straight-section VO takes its keyframes in order with their class: the images' class after the
temporal filter (classification.py), widened by the turns of bends the images missed (turning.py). Both
look ahead: the filter flips runs shorter than `min_cluster` frames, the turn test spans a window of
keyframes either side. `KeyframeClasses` hands out a keyframe's class as soon as no later frame can change
it, so that the VO can run beside the tracking, and the classes are those the whole sequence gives:
- the filter only ever relabels a short run as its neighbours, so a raw run of `min_cluster` or more frames
  keeps its label and cuts the sequence into parts that are filtered alone: every frame up to `min_cluster`
  before the end of the latest such run is final (the part after starts with that long run's last frames);
- a keyframe's turn class depends on the viewing directions of the keyframes a window either side and on
  the image classes of the keyframes up to a window further.
"""

from __future__ import annotations

import numpy as np

from pipemap.frontend.classification import temporal_filter
from pipemap.frontend.tracks import Keyframe
from pipemap.frontend.turning import turning_from_directions


def _final_cut(raw: np.ndarray, min_cluster: int) -> int:
    """How many leading frames of `raw` (which starts with a run of at least min_cluster, or at the sequence's
    start) have their final filtered class: up to min_cluster frames before the end of its last run of at least
    min_cluster equal labels. What is left starts with that many frames of the run, which keeps it whole."""
    edges = np.flatnonzero(np.diff(raw.astype(np.int8))) + 1
    ends = np.concatenate([edges, [len(raw)]])
    lengths = np.diff(np.concatenate([[0], ends]))
    long = np.flatnonzero(lengths >= min_cluster)
    return max(0, int(ends[long[-1]]) - min_cluster) if len(long) else 0


class KeyframeClasses:
    """Feed `update` the keyframes and the frames' raw image classes as they grow; it returns the keyframes
    whose class is final, in order, as (keyframe number, junction). `done=True` at the end finalises all."""

    def __init__(self, min_cluster: int, turn_deg: float | None, turn_window: int):
        self.min_cluster, self.turn_deg, self.turn_window = min_cluster, turn_deg, turn_window
        self._anchor = 0  # frames before this have their final filtered class
        self._frame_class: dict[int, bool] = {}  # frame index -> final filtered class
        self._junction: list[bool] = []  # image class of keyframes 0.. (final ones)
        self._z: list[np.ndarray] = []  # viewing directions, chained as turning.viewing_directions chains them
        self._chain: list[int] = []
        self._R = np.eye(3)
        self._bends: list[bool] = []  # of the keyframes handed out
        self._sent = 0

    @property
    def bends(self) -> np.ndarray:
        """Keyframes classed junction only for the turn of a bend the images missed (final ones)."""
        return np.array(self._bends, bool)

    def _filter(self, indices: list[int], raw: list[bool], n: int, done: bool) -> None:
        """Final filtered classes of the frames before raw[n] that have them (only the open part is read)."""
        part = np.asarray(raw[self._anchor:n], bool)
        if not len(part):
            return
        cut = len(part) if done else _final_cut(part, self.min_cluster)
        if cut == 0:
            return
        filtered = temporal_filter(part, self.min_cluster)[:cut]
        for i, j in zip(indices[self._anchor:self._anchor + cut], filtered.tolist()):
            self._frame_class[i] = j
        self._anchor += cut

    def _directions(self, keyframes: list[Keyframe]) -> None:
        for k in range(len(self._z), len(keyframes)):
            kf = keyframes[k]
            if k == 0 or not kf.pose_valid:
                self._R = np.eye(3)
                self._chain.append(self._chain[-1] + 1 if self._chain else 0)
            else:
                self._R = self._R @ np.asarray(kf.R, float).T
                self._chain.append(self._chain[-1])
            self._z.append(self._R[:, 2])

    def update(self, keyframes: list[Keyframe], indices: list[int], raw: list[bool],
               done: bool = False) -> list[tuple[int, bool]]:
        """`indices`, `raw`: the frame indices and raw image classes so far (raw may be the shorter: it is
        read first and its length counts)."""
        self._filter(indices, raw, len(raw), done)
        self._directions(keyframes)
        while len(self._junction) < len(keyframes):
            j = self._frame_class.get(keyframes[len(self._junction)].index)
            if j is None and not done:
                break
            self._junction.append(bool(j))
        known = len(self._junction)
        half = self.turn_window // 2
        reach = 2 * half + self.turn_window + 2  # keyframes a turn class depends on, either side
        ready = known if done else max(self._sent, min(known, len(keyframes)) - reach)
        if ready <= self._sent:
            return []
        # only the keyframes a new class depends on: the whole run each time would grow with its square
        lo = max(0, self._sent - reach)
        junction = np.asarray(self._junction[lo:known], bool)
        if self.turn_deg is not None:
            bends = turning_from_directions(np.asarray(self._z[lo:known]), np.asarray(self._chain[lo:known]),
                                            self.turn_window, self.turn_deg, junction) & ~junction
        else:
            bends = np.zeros(known - lo, bool)
        new = slice(self._sent - lo, ready - lo)
        self._bends += bends[new].tolist()
        out = list(zip(range(self._sent, ready), (junction[new] | bends[new]).tolist()))
        self._sent = ready
        return out


__all__ = ["KeyframeClasses"]
