"""The 3D view's contents, read from a result folder: trajectory, junctions, wall pieces and a sample of the
appearance map. An absent file gives nothing (the page says so); a file present but unreadable is an error
naming it."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np

from pipemap.errors import PipemapError
from pipemap.mapping.elbow_piece import piece_from_dict
from pipemap.trajectory import read_tum
from pipemap.yamlfile import read_yaml


def read_run_json(result_dir: Path) -> dict | None:
    path = Path(result_dir) / "run.json"
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise PipemapError(f"cannot read: {exc}", path) from None
    if not isinstance(data, dict):
        raise PipemapError("expected a JSON object", path)
    return data


def read_trajectory(result_dir: Path) -> list[list[float]] | None:
    """Camera centres of trajectory.tum, to 0.1 mm."""
    path = Path(result_dir) / "trajectory.tum"
    if not path.exists():
        return None
    return np.round(read_tum(path).positions, 4).tolist()


def read_junctions(result_dir: Path) -> list[dict] | None:
    path = Path(result_dir) / "junctions.yaml"
    if not path.exists():
        return None
    items = read_yaml(path, "junctions file").get("junctions") or []
    if not isinstance(items, list):
        raise PipemapError("junctions must be a list", path)
    out = []
    for i, j in enumerate(items):
        try:
            centre = [round(float(v), 4) for v in j["centroid"]]
            if len(centre) != 3:
                raise ValueError("centroid needs three numbers")
        except (KeyError, TypeError, ValueError) as exc:
            raise PipemapError(f"not a junction ({exc})", path, f"junctions[{i}]") from None
        rec = {"id": str(j.get("id", f"J{i + 1}")), "type": str(j.get("type", "tee")), "centroid": centre}
        if isinstance(j.get("chainage_m"), (int, float)):
            rec["chainage_m"] = float(j["chainage_m"])
        out.append(rec)
    return out


def read_pieces(run: dict | None, walls) -> list[dict]:
    """The wall pieces' axes (run.json "wall_pieces"; without it, the unrolled walls' axes): name, kind, start,
    end, radius, up (12 o'clock across the axis; an elbow's as given, taken across the arc's tangent), unroll;
    an elbow's also centre, normal and angle_deg."""
    where = "run.json: wall_pieces"
    items = (run or {}).get("wall_pieces")
    if isinstance(items, list):
        pieces = [piece_from_dict(d, f"{where}[{i}]") for i, d in enumerate(items)]
    else:
        pieces = [w.piece for w in walls]
    out = []
    for p in pieces:
        rec = {"name": p.name, "kind": p.kind, "start": np.round(p.start, 4).tolist(),
               "end": np.round(p.end, 4).tolist(), "radius": float(p.radius), "unroll": bool(p.unroll)}
        if p.kind == "arc":
            e_up = p.up / np.linalg.norm(p.up)  # taken across the local tangent all along the arc
            rec.update(centre=np.round(p.centre, 4).tolist(), normal=np.round(p.normal, 6).tolist(),
                       angle_deg=round(p.angle_deg, 4))
        else:
            e_up = p.frame()[1]
        rec["up"] = np.round(e_up, 6).tolist()
        out.append(rec)
    return out


def sample_cloud(result_dir: Path, count: int, seed: int) -> dict | None:
    """A seeded random sample of `count` appearance points: float32 x y z and uint8 grey, base64."""
    path = Path(result_dir) / "appearance.ply"
    if not path.exists() or count <= 0:
        return None
    from plyfile import PlyData

    try:
        vertex = PlyData.read(str(path), mmap=True)["vertex"].data
        names = vertex.dtype.names or ()
        if not {"x", "y", "z", "intensity"} <= set(names):
            raise ValueError("needs x, y, z and intensity")
        total = len(vertex)
        keep = np.sort(np.random.default_rng(seed).choice(total, size=min(count, total), replace=False))
        chosen = vertex[keep]
    except FileNotFoundError:
        raise PipemapError("file not found", path) from None
    except (KeyError, ValueError, OSError) as exc:
        raise PipemapError(f"not an appearance PLY ({exc})", path) from None
    xyz = np.stack([chosen[k] for k in ("x", "y", "z")], axis=-1).astype("<f4")
    grey = np.asarray(chosen["intensity"], np.uint8)
    return {"total": int(total), "count": int(len(keep)), "xyz": base64.b64encode(xyz.tobytes()).decode("ascii"),
            "grey": base64.b64encode(grey.tobytes()).decode("ascii")}


def world_up(pieces: list[dict]) -> list[float]:
    """The 3D view's up: the pieces' mean 12 o'clock direction; the frame's z without pieces."""
    if not pieces:
        return [0.0, 0.0, 1.0]
    up = np.mean([p["up"] for p in pieces], axis=0)
    n = np.linalg.norm(up)
    return (up / n).round(6).tolist() if n > 1e-6 else [0.0, 0.0, 1.0]


__all__ = ["read_run_json", "read_trajectory", "read_junctions", "read_pieces", "sample_cloud", "world_up"]
