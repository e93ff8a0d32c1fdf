"""The package's cache folder of generated files (meshes, planning models).

:func:`cache_dir` is ``$MANISKILL_PNP_CACHE/<name>`` (default ``~/.cache/maniskill_pnp/<name>``), created on first use.
It imports nothing of the package, so that every subpackage can use it: :mod:`~maniskill_pnp.scenes.objects` writes the
convex hulls of its procedural kinds to ``cache_dir("meshes")`` and :mod:`~maniskill_pnp.scenes.meshes` the convex
collision parts of mesh files (``objects`` imports ``meshes``, never the reverse); :mod:`~maniskill_pnp.planning.collision`
writes its planning model of the arm to ``cache_dir("planning")``.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir(name: str) -> Path:
    """The cache subfolder ``name`` (``$MANISKILL_PNP_CACHE/<name>`` or ``~/.cache/maniskill_pnp/<name>``), created if
    missing."""
    if not name or "/" in name or name in (".", ".."):
        raise ValueError(f"a cache folder name is one path component, got {name!r}")
    root = Path(os.environ.get("MANISKILL_PNP_CACHE", Path.home() / ".cache" / "maniskill_pnp")) / name
    root.mkdir(parents=True, exist_ok=True)
    return root


__all__ = ["cache_dir"]
