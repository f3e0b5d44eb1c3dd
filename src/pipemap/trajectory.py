"""Camera trajectories as T_wc poses, and the TUM text format of formats.md."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.geometry.rotations import matrix_to_quat, quat_to_matrix


@dataclass(frozen=True)
class Trajectory:
    """Poses T_wc: `positions` are camera centres, `rotations` map camera to world axes."""

    timestamps: np.ndarray  # (N,) seconds
    positions: np.ndarray  # (N, 3)
    rotations: np.ndarray  # (N, 3, 3)

    def __post_init__(self) -> None:
        n = len(self.timestamps)
        if self.positions.shape != (n, 3) or self.rotations.shape != (n, 3, 3):
            raise ValueError(
                f"trajectory arrays disagree: {self.timestamps.shape}, {self.positions.shape}, {self.rotations.shape}"
            )

    def __len__(self) -> int:
        return len(self.timestamps)

    @classmethod
    def from_quaternions(cls, timestamps, positions, quaternions_xyzw) -> "Trajectory":
        return cls(np.asarray(timestamps, float), np.asarray(positions, float), quat_to_matrix(quaternions_xyzw))

    @classmethod
    def from_matrices(cls, timestamps, T_wc: np.ndarray) -> "Trajectory":
        T_wc = np.asarray(T_wc, float)
        return cls(np.asarray(timestamps, float), T_wc[:, :3, 3].copy(), T_wc[:, :3, :3].copy())

    @property
    def quaternions(self) -> np.ndarray:
        """(N, 4) unit quaternions (x, y, z, w)."""
        return matrix_to_quat(self.rotations)

    def matrices(self) -> np.ndarray:
        """(N, 4, 4) homogeneous T_wc."""
        T = np.tile(np.eye(4), (len(self), 1, 1))
        T[:, :3, :3] = self.rotations
        T[:, :3, 3] = self.positions
        return T

    def subset(self, index) -> "Trajectory":
        return Trajectory(self.timestamps[index], self.positions[index], self.rotations[index])

    def path_length(self) -> float:
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())


def read_tum(path: str | Path) -> Trajectory:
    """Read `timestamp tx ty tz qx qy qz qw` lines; '#' starts a comment."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise PipemapError("trajectory file not found", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PipemapError(f"cannot read trajectory: {exc}", path) from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 8:
            raise PipemapError(f"expected 8 numbers (timestamp tx ty tz qx qy qz qw), found {len(fields)}", path,
                               f"line {lineno}")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise PipemapError("not a number", path, f"line {lineno}") from None
        if not np.all(np.isfinite(values)):
            raise PipemapError("non-finite value", path, f"line {lineno}")
        q = np.array(values[4:])
        if abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise PipemapError(f"quaternion is not unit length (|q| = {np.linalg.norm(q):.4f})", path, f"line {lineno}")
        rows.append(values)
    if not rows:
        raise PipemapError("trajectory file has no poses", path)
    data = np.array(rows)
    return Trajectory.from_quaternions(data[:, 0], data[:, 1:4], data[:, 4:8])


def write_tum(path: str | Path, trajectory: Trajectory, header: str | None = None) -> None:
    path = Path(path)
    q = trajectory.quaternions
    lines = [] if header is None else [f"# {h}" for h in header.splitlines()]
    lines.append("# timestamp tx ty tz qx qy qz qw")
    for t, p, qq in zip(trajectory.timestamps, trajectory.positions, q):
        lines.append(
            f"{t:.6f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {qq[0]:.9f} {qq[1]:.9f} {qq[2]:.9f} {qq[3]:.9f}"
        )
    path.write_text("\n".join(lines) + "\n")
