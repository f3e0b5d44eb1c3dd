"""Ground-truth straight / junction labels of a dataset's frames, for judging image classification."""

from __future__ import annotations

import numpy as np

from pipemap.dataset import Dataset


def ground_truth_labels(dataset: Dataset, visible: bool = True) -> np.ndarray:
    """(len(dataset),) bool, True = 'junction': the camera centre is within one pipe diameter (2 r)
    of a tee or cross centroid (network.yaml), in 3D, and - with `visible`, the default - the camera has not
    passed the tee centre by more than r along its viewing direction (the tee is then behind the
    190 degree field of view and the image shows a straight pipe)."""
    traj = dataset.ground_truth_poses()
    network = dataset.network()
    if traj is None or network is None:
        raise ValueError(f"{dataset.root} has no ground truth (poses.tum and network.yaml)")
    tees = np.array([j.centroid for j in network.junctions if j.type in ("tee", "cross")], float).reshape(-1, 3)
    out = np.zeros(len(dataset), bool)
    idx = np.rint(np.asarray(traj.timestamps) * dataset.fps).astype(np.int64)
    keep = (idx >= 0) & (idx < out.size)
    if tees.size:
        rel = tees[None, :, :] - traj.positions[:, None, :]  # (N, T, 3) camera -> tee
        near = np.linalg.norm(rel, axis=-1) < 2.0 * network.radius_m
        if visible:
            ahead = np.einsum("ntk,nk->nt", rel, traj.rotations[:, :, 2])
            near &= ahead > -network.radius_m
        out[idx[keep]] = near.any(axis=1)[keep]
    return out
