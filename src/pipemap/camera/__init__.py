"""Camera models behind one interface, and the `camera:` block of dataset.yaml."""

from __future__ import annotations

from pathlib import Path

import yaml

from pipemap.camera.base import CameraModel
from pipemap.camera.kannala_brandt import KannalaBrandtCamera
from pipemap.camera.pinhole import PinholeCamera
from pipemap.camera.polynomial import PolynomialCamera
from pipemap.errors import PipemapError
from pipemap.yamlfile import read_yaml

MODELS: dict[str, type[CameraModel]] = {
    cls.model: cls for cls in (PolynomialCamera, KannalaBrandtCamera, PinholeCamera)
}

__all__ = ["CameraModel", "PolynomialCamera", "KannalaBrandtCamera", "PinholeCamera", "MODELS",
           "camera_from_dict", "load_camera", "save_camera"]


def camera_from_dict(block, where: str | Path | None = None) -> CameraModel:
    """Build a camera from a `camera:` block; errors name `where` and the key."""
    if not isinstance(block, dict):
        raise PipemapError("expected a mapping with model, width, height, params", where, "camera")
    name = block.get("model")
    if name not in MODELS:
        raise PipemapError(f"unknown camera model {name!r} (expected one of {', '.join(MODELS)})", where,
                           "camera.model")
    for key in ("width", "height", "params"):
        if key not in block:
            raise PipemapError("missing", where, f"camera.{key}")
    unknown = set(block) - {"model", "width", "height", "params", "max_theta_deg"}
    if unknown:
        raise PipemapError(f"unknown key(s) {', '.join(sorted(unknown))}", where, "camera")
    if not isinstance(block["params"], dict):
        raise PipemapError("expected a mapping of parameter names to numbers", where, "camera.params")
    max_theta = block.get("max_theta_deg")
    if max_theta is not None and not isinstance(max_theta, (int, float)):
        raise PipemapError("must be a number", where, "camera.max_theta_deg")
    try:
        return MODELS[name](block["width"], block["height"], block["params"], max_theta)
    except PipemapError as exc:
        raise PipemapError(exc.message, where, exc.key) from None


def load_camera(path: str | Path) -> CameraModel:
    """Read a camera file: either a bare camera block or a file with a top-level `camera:` key."""
    data = read_yaml(path, "camera file", mapping=False)
    if isinstance(data, dict) and "camera" in data:
        data = data["camera"]
    return camera_from_dict(data, path)


def save_camera(path: str | Path, camera: CameraModel, extra: dict | None = None) -> None:
    """Write `camera:` (and any extra top-level keys, e.g. calibration residuals)."""
    doc = {"camera": camera.to_dict()}
    if extra:
        doc.update(extra)
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))
