"""Reading the project's YAML files with one-line errors that name the file."""

from __future__ import annotations

from pathlib import Path

import yaml

from pipemap.errors import PipemapError


def read_yaml(path: str | Path, what: str = "file", mapping: bool = True):
    """Parse `path`; a missing, unreadable or malformed file (or, with `mapping`, one whose top level
    is not a mapping) raises PipemapError naming it."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise PipemapError(f"{what} not found", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PipemapError(f"cannot read: {exc}", path) from None
    except yaml.YAMLError as exc:
        raise PipemapError(f"cannot parse YAML: {str(exc).splitlines()[0]}", path) from None
    if mapping and not isinstance(data, dict):
        raise PipemapError("expected a mapping at the top level", path)
    return data
