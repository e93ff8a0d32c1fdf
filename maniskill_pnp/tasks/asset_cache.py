"""The cache folder of generated mesh files (shared by the procedural objects and the mesh objects).

:func:`mesh_cache_dir` is ``$MANISKILL_PNP_CACHE/meshes`` (default ``~/.cache/maniskill_pnp/meshes``), created on first
use. :mod:`~maniskill_pnp.tasks.objects` writes the convex hulls of its procedural kinds there,
:mod:`~maniskill_pnp.tasks.meshes` the convex collision parts of mesh files. It imports neither, so that both can
import it (:mod:`~maniskill_pnp.tasks.objects` imports :mod:`~maniskill_pnp.tasks.meshes`, never the reverse).
"""

from __future__ import annotations

from pathlib import Path

from maniskill_pnp.cache import cache_dir


def mesh_cache_dir() -> Path:
    """The folder of cached mesh files (``$MANISKILL_PNP_CACHE/meshes`` or ``~/.cache/maniskill_pnp/meshes``), created
    if missing."""
    return cache_dir("meshes")


__all__ = ["mesh_cache_dir"]
