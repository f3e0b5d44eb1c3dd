"""Front-end result files.

`frames.csv` (formats.md): `index,keyframe,label` for every image; `keyframe` is 1 for a
keyframe and 0 otherwise; `label` is `straight` for every image until image classification
(fisheye paper III-B) labels junctions.

`tracks.csv`: one row per observation of a track in a keyframe,

    track_id,keyframe,index,u,v,guided

`track_id` is stable across keyframes, `keyframe` the keyframe number (0, 1, ...), `index` the
image index, `u,v` the pixel (origin at the centre of the top-left pixel), `guided` 1 when the
observation was found by epipolar-guided ZNCC rather than descriptor matching (always 0 with
`frontend.tracking: flow`, where Lucas-Kanade follows every feature). Rows are sorted
by keyframe. An observation whose `track_id` also occurs in the previous keyframe is an inlier
of that keyframe pair's relative pose.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.frontend.tracks import Keyframe
from pipemap.output import atomic_write_text

TRACKS_HEADER = ["track_id", "keyframe", "index", "u", "v", "guided"]


def write_frames_csv(path: Path, image_count: int, keyframe_indices, labels=None, chainage=None) -> None:
    """One row per frame of the recording. `labels`: a list (one per frame) or a mapping index -> label;
    frames it does not name were not read (damaged: `unreadable`); None: all `straight`. `chainage`: metres
    along the route per frame (NaN: none), written as a `chainage_m` column."""
    is_key = np.zeros(image_count, int)
    is_key[np.asarray(list(keyframe_indices), int)] = 1
    if labels is None:
        labels = ["straight"] * image_count
    elif isinstance(labels, dict):
        labels = [labels.get(i, "unreadable") for i in range(image_count)]
    if chainage is None:
        lines = ["index,keyframe,label"] + [f"{i},{is_key[i]},{labels[i]}" for i in range(image_count)]
    else:
        c = [f"{v:.4f}" if np.isfinite(v) else "" for v in np.asarray(chainage, float)]
        lines = ["index,keyframe,label,chainage_m"] + [f"{i},{is_key[i]},{labels[i]},{c[i]}"
                                                       for i in range(image_count)]
    atomic_write_text(Path(path), "\n".join(lines) + "\n")


def write_tracks_csv(path: Path, keyframes: list[Keyframe]) -> None:
    out = io.StringIO()
    out.write(",".join(TRACKS_HEADER) + "\n")
    for kf in keyframes:
        for tid, (u, v), g in zip(kf.track_ids, kf.keypoints, kf.guided):
            out.write(f"{tid},{kf.number},{kf.index},{u:.3f},{v:.3f},{int(g)}\n")
    atomic_write_text(Path(path), out.getvalue())


def read_tracks_csv(path: Path) -> dict[str, np.ndarray]:
    """Columns of tracks.csv as arrays: track_id, keyframe, index (int), u, v (float), guided (bool)."""
    path = Path(path)
    try:
        with path.open(newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header != TRACKS_HEADER:
                raise PipemapError(f"expected header {','.join(TRACKS_HEADER)}", path)
            rows = [r for r in reader if r]
    except FileNotFoundError:
        raise PipemapError("tracks file not found", path) from None
    try:
        data = np.array(rows, dtype=float).reshape(-1, len(TRACKS_HEADER))
    except ValueError:
        raise PipemapError("tracks file has a row that is not 6 numbers", path) from None
    return {
        "track_id": data[:, 0].astype(np.int64),
        "keyframe": data[:, 1].astype(int),
        "index": data[:, 2].astype(int),
        "u": data[:, 3],
        "v": data[:, 4],
        "guided": data[:, 5] > 0,
    }


def read_frames_csv(path: Path) -> dict[str, np.ndarray]:
    path = Path(path)
    try:
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except FileNotFoundError:
        raise PipemapError("frames file not found", path) from None
    return {
        "index": np.array([int(r["index"]) for r in rows]),
        "keyframe": np.array([int(r["keyframe"]) > 0 for r in rows]),
        "label": np.array([r["label"] for r in rows]),
    }
