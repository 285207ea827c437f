"""The JSON sidecar ``<file>.json`` of every point file: what was measured with which settings
(profile, chirp, ADC, calibration id, hardware and wall time, coverage, software version, simulated,
partial; on a simulated bench the scene file and its sha256).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from .files import atomic_write, dumps_meta

__all__ = ["read_sidecar", "scene_identity", "sidecar_path", "write_sidecar"]


def sidecar_path(path: str | os.PathLike) -> Path:
    p = Path(path)
    return p.with_name(p.name + ".json")


def write_sidecar(path: str | os.PathLike, meta: dict[str, Any]) -> Path:
    """Write ``<path>.json`` describing the point file ``path``."""
    side = sidecar_path(path)
    text = dumps_meta(meta)
    with atomic_write(side) as f:
        f.write(text.encode("utf-8"))
    return side


def scene_identity(path: str | os.PathLike) -> dict[str, str]:
    """The sidecar's ``scene`` entry on a simulated bench: the scene file's absolute path and the
    sha256 of its bytes, so a point cloud names exactly the world it was measured in."""
    import hashlib

    from ..errors import ConfigError

    p = Path(path).resolve()
    try:
        digest = hashlib.sha256(p.read_bytes()).hexdigest()
    except FileNotFoundError:
        # the bench could not load it either: name the scene, not the sidecar that asked first
        raise ConfigError(f"scene file {p} not found (--scene, or sim.scene of the configuration)") from None
    except OSError as exc:
        raise ConfigError(f"scene file {p} cannot be read ({exc.strerror or exc})") from None
    return {"path": str(p), "sha256": digest}


def read_sidecar(path: str | os.PathLike) -> dict[str, Any]:
    return json.loads(sidecar_path(path).read_text(encoding="utf-8"))
