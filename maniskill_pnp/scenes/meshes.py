"""Objects from mesh files (OBJ, STL, GLB, PLY): loading, graspability, and convex collision parts (cached).

An :class:`~maniskill_pnp.scenes.objects.ObjectSpec` of kind ``mesh`` names a file, a scale (one factor or three
per-axis factors) and optionally a second file of ready-made convex collision parts (as ManiSkill's YCB models ship).
This module reads such files once per (path, modification time, scale) and gives:

* :func:`mesh_info`: the scaled mesh centred on its axis-aligned bounding box (what the object frame is, as for the
  procedural kinds), its extents, whether it is watertight and convex, and the narrowest width of its footprint;
* :func:`convex_parts`: the convex collision parts (object frame) as ``.obj`` files in the cache folder
  (``MANISKILL_PNP_CACHE`` or ``~/.cache/maniskill_pnp``, see :func:`~maniskill_pnp.cache.cache_dir` ``("meshes")``),
  one file per part, computed once per (file content hash, scale, decomposition parameters):

  - a mesh that is already convex (its volume within :data:`CONVEX_TOLERANCE` of its hull's) is one hull;
  - another watertight mesh is decomposed by CoACD (``coacd`` package, :data:`COACD_PARAMS`);
  - with a collision file, its connected components are the parts (each replaced by its hull), no decomposition.

Every failure is a ``ValueError`` that names the file: missing or unreadable, no triangles, degenerate (flat or zero
volume), not watertight where its volume is needed (the convexity test and the decomposition need a closed surface;
give a collision file for an open mesh).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from maniskill_pnp.cache import cache_dir

#: File types read (trimesh reads them for the geometry, SAPIEN for the visual shape).
MESH_SUFFIXES = (".obj", ".stl", ".glb", ".gltf", ".ply")
#: A mesh whose volume is within this fraction of its convex hull's is convex: one hull, no decomposition.
CONVEX_TOLERANCE = 0.01
#: Parameters of ``coacd.run_coacd`` (part of the cache key). ``threshold`` is the concavity allowed per part
#: (relative to the mesh size), the rest CoACD's defaults except a fixed seed and hulls decimated to 128 vertices
#: (PhysX cooks at most 255 per convex mesh).
COACD_PARAMS = dict(threshold=0.05, max_convex_hull=-1, preprocess_mode="auto", preprocess_resolution=50, resolution=2000,
                    mcts_nodes=20, mcts_iterations=150, mcts_max_depth=3, pca=False, merge=True, decimate=True,
                    max_ch_vertex=128, seed=0)
#: Version of the cached part files (change it when the way parts are made changes).
_PARTS_VERSION = 1


@dataclass(frozen=True)
class MeshInfo:
    """A mesh file read at one scale, in the object frame (scaled, centred on its bounding box).

    Attributes:
        path: The file.
        digest: SHA-1 of the file's bytes.
        vertices, faces: The geometry (faces index vertices; vertices merged by position).
        offset: What was added to the scaled file coordinates to centre them (the visual shape's local position).
        extents: Full extents (dx, dy, dz) of the bounding box.
        watertight: The surface is closed (its volume is defined).
        volume: Enclosed volume (m³) of a watertight mesh, else None.
        hull_volume: Volume of the convex hull (m³).
        footprint_width: Narrowest width of the footprint (the xy projection) over all horizontal directions (m).
    """

    path: Path
    digest: str
    vertices: np.ndarray
    faces: np.ndarray
    offset: np.ndarray
    extents: np.ndarray
    watertight: bool
    volume: float | None
    hull_volume: float
    footprint_width: float

    @property
    def convex(self) -> bool:
        """Watertight and as voluminous as its hull (within :data:`CONVEX_TOLERANCE`)."""
        return self.volume is not None and abs(self.hull_volume - self.volume) <= CONVEX_TOLERANCE * self.hull_volume


def _file_stat(path: Path) -> tuple[int, int]:
    st = path.stat()
    return st.st_mtime_ns, st.st_size


def resolve_mesh_path(file) -> Path:
    """``file`` as an absolute path of an existing mesh file of a supported type.

    Raises:
        ValueError: a missing file, a folder or an unsupported extension (the message names the file).
    """
    path = Path(os.path.expanduser(str(file))).resolve()
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"mesh file {path}: unsupported type {path.suffix or '(no extension)'!r}; "
                         f"supported: {', '.join(MESH_SUFFIXES)}")
    if not path.exists():
        raise ValueError(f"mesh file {path} does not exist")
    if not path.is_file():
        raise ValueError(f"mesh file {path} is not a file")
    return path


def _read_trimesh(path: Path):
    """The triangles of every geometry in ``path`` as one trimesh (vertices merged by position, no visuals)."""
    import trimesh

    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 (trimesh raises many kinds for a bad file)
        raise ValueError(f"cannot read mesh file {path}: {type(e).__name__}: {e}") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0 or len(vertices) < 4:
        raise ValueError(f"mesh file {path} holds no triangles")
    if not np.isfinite(vertices).all():
        raise ValueError(f"mesh file {path} has non-finite vertex coordinates")
    return trimesh.Trimesh(vertices, faces, process=True)


def _min_width_2d(points: np.ndarray) -> float:
    """Narrowest width of a 2-D point set over all directions (rotating calipers on its convex hull)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.unique(np.round(points, 9), axis=0)
    try:
        hull = pts[ConvexHull(pts).vertices]
    except (QhullError, ValueError):  # collinear or too few points: no area
        return 0.0
    edges = np.roll(hull, -1, axis=0) - hull
    normals = np.stack([-edges[:, 1], edges[:, 0]], axis=1) / np.linalg.norm(edges, axis=1, keepdims=True)
    proj = hull @ normals.T  # (vertices, edges)
    return float((proj.max(0) - proj.min(0)).min())


@functools.lru_cache(maxsize=256)
def _load(path: Path, stat: tuple[int, int], scale: tuple[float, float, float]) -> MeshInfo:
    digest = hashlib.sha1(path.read_bytes()).hexdigest()
    mesh = _read_trimesh(path)
    mesh.apply_transform(np.diag([*scale, 1.0]))
    lo, hi = mesh.bounds
    offset = -(lo + hi) / 2
    mesh.apply_translation(offset)
    extents = hi - lo
    try:
        hull_volume = float(mesh.convex_hull.volume) if min(extents) > 1e-6 else 0.0
    except Exception:  # noqa: BLE001 (qhull fails on flat input)
        hull_volume = 0.0
    if min(extents) <= 1e-6 or hull_volume <= 1e-12:
        raise ValueError(f"mesh file {path} (scale {list(scale)}) is degenerate: extents {np.round(extents, 6).tolist()} m, "
                         f"hull volume {hull_volume:.3g} m³ (flat or zero volume)")
    watertight = bool(mesh.is_watertight)
    volume = abs(float(mesh.volume)) if watertight else None
    if volume is not None and volume <= 1e-12:
        raise ValueError(f"mesh file {path} (scale {list(scale)}) encloses no volume")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    return MeshInfo(path, digest, vertices, np.asarray(mesh.faces, dtype=np.int64), offset, extents, watertight, volume,
                    hull_volume, _min_width_2d(vertices[:, :2]))


def mesh_info(file, scale=(1.0, 1.0, 1.0)) -> MeshInfo:
    """The mesh file ``file`` read at ``scale`` (cached per path, modification time and scale).

    Raises:
        ValueError: see the module docstring.
    """
    path = resolve_mesh_path(file)
    return _load(path, _file_stat(path), tuple(float(s) for s in scale))


# ----------------------------------------------------------------------------- convex parts
def _coacd_parts(info: MeshInfo) -> list[tuple[np.ndarray, np.ndarray]]:
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(info.vertices, info.faces.astype(np.int32)), **COACD_PARAMS)
    return [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in parts]


def _component_parts(path: Path, scale, offset) -> list[tuple[np.ndarray, np.ndarray]]:
    """The connected components of a collision file (each a convex part), scaled and moved by ``offset``."""
    mesh = _read_trimesh(path)
    mesh.apply_transform(np.diag([*scale, 1.0]))
    mesh.apply_translation(offset)
    return [(np.asarray(c.vertices), np.asarray(c.faces)) for c in mesh.split(only_watertight=False)]


def _hull(vertices: np.ndarray):
    import trimesh

    try:
        hull = trimesh.convex.convex_hull(vertices)
    except Exception:  # noqa: BLE001 (qhull fails on flat input)
        return None
    return hull if hull.volume > 1e-12 else None


def parts_key(info: MeshInfo, scale, collision: MeshInfo | None = None) -> str:
    """Cache key of the convex parts: file contents, scale and how the parts are made."""
    if collision is not None:
        how = dict(collision=collision.digest)
    elif info.convex:
        how = dict(convex_hull=True)
    else:
        how = dict(coacd=COACD_PARAMS)
    text = json.dumps(dict(v=_PARTS_VERSION, mesh=info.digest, scale=[float(s) for s in scale], **how), sort_keys=True)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def convex_parts(file, scale=(1.0, 1.0, 1.0), collision=None) -> list[Path]:
    """The convex collision parts of a mesh object (object frame, one ``.obj`` each), made once and cached.

    Args:
        file: The mesh file (its bounding box centre is the object's origin).
        scale: Per-axis scale.
        collision: Optional file of ready-made convex parts (its connected components), in the mesh's coordinates.

    Raises:
        ValueError: see the module docstring; a non-watertight mesh without a collision file.
    """
    info = mesh_info(file, scale)
    coll = mesh_info(collision, scale) if collision is not None else None
    key = parts_key(info, scale, coll)
    folder = cache_dir("meshes") / f"parts_{key}"
    manifest = folder / "parts.json"
    if manifest.exists():
        names = json.loads(manifest.read_text())["parts"]
        paths = [folder / name for name in names]
        if all(p.exists() for p in paths):
            return paths
    if coll is not None:
        raw = _component_parts(coll.path, scale, info.offset)
    elif not info.watertight:
        raise ValueError(f"mesh file {info.path} is not watertight: its volume (needed to test convexity and to decompose "
                         "it into convex parts) is undefined; close the surface or give a collision file of convex parts")
    elif info.convex:
        raw = [(info.vertices, info.faces)]
    else:
        raw = _coacd_parts(info)
    hulls = [h for h in (_hull(v) for v, _ in raw) if h is not None]
    if not hulls:
        raise ValueError(f"mesh file {collision or info.path}: no convex part with a volume")
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for k, hull in enumerate(hulls):
        name = f"part_{k:03d}.obj"
        tmp = folder / f".{name}.{os.getpid()}.tmp.obj"
        hull.export(tmp)
        os.replace(tmp, folder / name)
        names.append(name)
    tmp = folder / f".parts.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(dict(parts=names, source=str(info.path), collision=str(coll.path) if coll else None,
                                   scale=[float(s) for s in scale])))
    os.replace(tmp, manifest)
    return [folder / name for name in names]


@functools.lru_cache(maxsize=1024)
def _part_arrays(path: Path, stat: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    mesh = trimesh.load(str(path), force="mesh", process=True)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def part_arrays(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of one cached convex part file."""
    return _part_arrays(Path(path), _file_stat(Path(path)))
