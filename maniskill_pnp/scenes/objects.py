"""Objects for clutter: procedural regular and irregular kinds (no downloaded assets) and meshes from files.

Kinds and their ``size`` parameters (metres):

=========  =====================================================  ==========================================
kind       size                                                   collision shapes
=========  =====================================================  ==========================================
cuboid     (hx, hy, hz) half extents                              one box
cylinder   (radius, half_height), upright                         one convex mesh (a prism of 32 sides)
sphere     (radius,)                                              one sphere
L          (length, width, thickness, height)                     two boxes
T          (length, width, thickness, height)                     two boxes
U          (length, width, thickness, height)                     three boxes
arch       (length, width, leg, height)                           three boxes (two legs and a lintel)
wedge      (length, width, height)                                one convex mesh (a triangular prism)
hull       (dx, dy, dz) bounding extents; random points (seed)   one convex mesh (trimesh hull)
mesh       none: ``file`` (OBJ, STL, GLB, PLY) and ``scale``      convex parts (:mod:`~maniskill_pnp.scenes.meshes`)
=========  =====================================================  ==========================================

Every object is centred on its axis-aligned bounding box, rests on its bottom face when upright, is at least
2 cm high and at most 7 cm across in at least one horizontal direction (what the Panda's jaws, 8 cm open, take).
Convex meshes are written once to a cache folder (``MANISKILL_PNP_CACHE`` or ``~/.cache/maniskill_pnp``, see
:func:`~maniskill_pnp.cache.cache_dir` ``("meshes")``) and loaded with the builder's convex-mesh API; non-convex
kinds are unions of convex parts in one actor. A cylinder collides as a prism of :data:`CYLINDER_SIDES` sides
inscribed in it (0.5% of its radius inside the circle at most), the tessellation PhysX's maintainers advise: SAPIEN's
own cylinder shape gains energy when it rolls (a cylinder of 2 cm radius lying on the table, set rolling at 0.1 m/s,
runs at 0.5 m/s two seconds later, at the tasks' 100 Hz), a convex prism does not. Its visual shape stays the
cylinder, and :func:`collision_shapes` gives the exact cylinder.

A ``mesh`` object is the file's mesh, scaled (one factor or three per-axis factors) and centred on its bounding box,
in the file's axes (z up). Its visual shape is the file itself (in ``color``, or with the file's own materials and
textures when ``texture=True``); its collision shapes are convex parts: the hull of a convex mesh, a CoACD
decomposition of another watertight mesh, or the components of a ``collision`` file, cached per file content and
scale. Its mass is ``density`` (kg/m³) times the parts' volume (the builder's density-based mass; the procedural kinds
use the builder's default density, 1000). Its narrowest width (:attr:`ObjectSpec.grasp_width`) is that of its whole
footprint, so it must fit the open jaws as a whole. :mod:`~maniskill_pnp.scenes.ycb` makes such specs of ManiSkill's
YCB models.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sapien

from maniskill_pnp.cache import cache_dir

#: The procedural kinds (random clutters draw among them).
KINDS = ("cuboid", "cylinder", "sphere", "L", "T", "U", "arch", "wedge", "hull")
REGULAR_KINDS = ("cuboid", "cylinder", "sphere")
IRREGULAR_KINDS = ("L", "T", "U", "arch", "wedge", "hull")
#: Objects from mesh files.
MESH_KIND = "mesh"
#: Every kind an :class:`ObjectSpec` can have.
ALL_KINDS = (*KINDS, MESH_KIND)
#: Density (kg/m³) of a mesh object unless given (the builder's default, which the procedural kinds use).
DEFAULT_DENSITY = 1000.0
#: Names of the ``size`` values of each kind, in order (see the module table).
SIZE_PARAMS = {
    "cuboid": ("hx", "hy", "hz"), "cylinder": ("radius", "half_height"), "sphere": ("radius",),
    "L": ("length", "width", "thickness", "height"), "T": ("length", "width", "thickness", "height"),
    "U": ("length", "width", "thickness", "height"), "arch": ("length", "width", "leg", "height"),
    "wedge": ("length", "width", "height"), "hull": ("dx", "dy", "dz"), MESH_KIND: (),
}
_SIZE_ARITY = {kind: len(names) for kind, names in SIZE_PARAMS.items()}

#: Sides of the convex prism a cylinder collides as (see the module docstring).
CYLINDER_SIDES = 32
#: Graspability limits (m).
MAX_GRASP_WIDTH = 0.07
MIN_HEIGHT = 0.02
MAX_SIDE = 0.12
#: Arch lintels are at least this thick, so jaws closing on the lintel's top part stay above the tunnel
#: (deeper, a finger can hook under the lintel and the object stays on the finger when the jaws open).
ARCH_MIN_LINTEL = 0.02

PALETTE = (
    (0.85, 0.2, 0.15), (0.2, 0.6, 0.25), (0.15, 0.35, 0.85), (0.95, 0.75, 0.1), (0.6, 0.25, 0.7),
    (0.95, 0.5, 0.1), (0.1, 0.7, 0.75), (0.9, 0.4, 0.6), (0.55, 0.4, 0.2), (0.45, 0.8, 0.3),
)


_MESH_DEFAULTS = dict(file=None, scale=(1.0, 1.0, 1.0), texture=False, density=DEFAULT_DENSITY, collision=None)


@dataclass(frozen=True)
class ObjectSpec:
    """One object: procedural, or a mesh file (``kind="mesh"``).

    Attributes:
        kind: One of :data:`ALL_KINDS`.
        size: Size parameters of the kind (see the module table), metres; empty for a mesh.
        color: RGB in [0, 1].
        seed: Seed of the random points of a ``hull`` (ignored by other kinds).
        file: Mesh only: the mesh file (OBJ, STL, GLB, PLY), stored as an absolute path.
        scale: Mesh only: scale of the file's coordinates, one number (uniform) or three (per axis); stored as three.
        texture: Mesh only: show the file's own materials and textures instead of ``color``.
        density: Mesh only: kg/m³ of its collision parts (the mass follows from their volume).
        collision: Mesh only: optional file of ready-made convex collision parts (its connected components), in the
            mesh file's coordinates; without it the parts are computed (see :mod:`~maniskill_pnp.scenes.meshes`).

    Raises:
        ValueError: bad parameters or an object the gripper cannot take; for a mesh, also a missing, unreadable or
            degenerate file (the message names the file).
    """

    kind: str
    size: tuple[float, ...] = ()
    color: tuple[float, float, float] = (0.8, 0.3, 0.2)
    seed: int = 0
    file: str | None = None
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    texture: bool = False
    density: float = DEFAULT_DENSITY
    collision: str | None = None

    def __post_init__(self):
        if self.kind not in ALL_KINDS:
            raise ValueError(f"unknown object kind {self.kind!r}; valid kinds: {list(ALL_KINDS)}")
        size = tuple(float(v) for v in self.size)
        object.__setattr__(self, "size", size)
        if self.kind == MESH_KIND:
            self._check_mesh()
            return
        given = [k for k, v in _MESH_DEFAULTS.items() if getattr(self, k) != v]
        if given:
            raise ValueError(f"{given} are fields of mesh objects, not of kind {self.kind!r}")
        if len(size) != _SIZE_ARITY[self.kind]:
            raise ValueError(f"{self.kind} takes {_SIZE_ARITY[self.kind]} size values, got {len(size)}: {size}")
        if not all(np.isfinite(size)) or min(size) <= 0:
            raise ValueError(f"object sizes must be positive, got {size}")
        if self.kind in ("L", "T", "U", "arch"):
            length, width, thick, height = size
            if thick >= min(length, width) / (2 if self.kind == "U" else 1):
                raise ValueError(f"{self.kind}: thickness {thick} leaves no gap in a {length} x {width} footprint")
        if len(self.color) != 3 or not all(0 <= c <= 1 for c in self.color):
            raise ValueError(f"color must be RGB in [0, 1], got {self.color}")
        ext = self.extents
        if ext[2] < MIN_HEIGHT - 1e-9:
            raise ValueError(f"{self.kind} {size} is {ext[2]:.3f} m high; objects must be at least {MIN_HEIGHT} m high")
        if min(self.grasp_width, ext[0], ext[1]) > MAX_GRASP_WIDTH + 1e-9 or max(ext[:2]) > MAX_SIDE + 1e-9:
            raise ValueError(
                f"{self.kind} {size} does not fit the gripper: some horizontal width must be <= {MAX_GRASP_WIDTH} m "
                f"and no side above {MAX_SIDE} m"
            )

    def _check_mesh(self) -> None:
        from maniskill_pnp.scenes.meshes import mesh_info, resolve_mesh_path

        if self.size:
            raise ValueError(f"mesh objects take no size (give file and scale), got size {self.size}")
        if self.file is None or not isinstance(self.file, (str, os.PathLike)):
            raise ValueError(f"a mesh object needs file= (a path to an OBJ, STL, GLB or PLY file), got {self.file!r}")
        object.__setattr__(self, "file", str(resolve_mesh_path(self.file)))
        if self.collision is not None:
            if not isinstance(self.collision, (str, os.PathLike)):
                raise ValueError(f"collision must be a path to a mesh file of convex parts, got {self.collision!r}")
            object.__setattr__(self, "collision", str(resolve_mesh_path(self.collision)))
        scale = self.scale
        scale = (scale,) * 3 if isinstance(scale, (int, float, np.number)) and not isinstance(scale, bool) else scale
        try:
            scale = tuple(float(v) for v in scale)
        except (TypeError, ValueError):
            scale = ()
        if len(scale) != 3 or not all(np.isfinite(scale)) or min(scale) <= 0:
            raise ValueError(f"mesh {self.file}: scale must be a positive number or three positive numbers, got {self.scale!r}")
        object.__setattr__(self, "scale", scale)
        if not isinstance(self.texture, (bool, np.bool_)):
            raise ValueError(f"mesh {self.file}: texture must be True or False, got {self.texture!r}")
        object.__setattr__(self, "texture", bool(self.texture))
        density = self.density
        if isinstance(density, bool) or not isinstance(density, (int, float, np.number)) or not np.isfinite(density) or density <= 0:
            raise ValueError(f"mesh {self.file}: density must be a positive number (kg/m³), got {density!r}")
        object.__setattr__(self, "density", float(density))
        if len(self.color) != 3 or not all(0 <= c <= 1 for c in self.color):
            raise ValueError(f"color must be RGB in [0, 1], got {self.color}")
        info = mesh_info(self.file, scale)
        ext, what = info.extents, f"mesh {self.file} (scale {list(scale)})"
        if ext[2] < MIN_HEIGHT - 1e-9:
            raise ValueError(f"{what} is {ext[2]:.3f} m high; objects must be at least {MIN_HEIGHT} m high")
        if self.grasp_width > MAX_GRASP_WIDTH + 1e-9 or max(ext[:2]) > MAX_SIDE + 1e-9:
            raise ValueError(
                f"{what} does not fit the gripper: its footprint is {ext[0]:.3f} x {ext[1]:.3f} m, {self.grasp_width:.3f} m "
                f"at its narrowest; the narrowest width must be <= {MAX_GRASP_WIDTH} m and no side above {MAX_SIDE} m"
            )

    @property
    def label(self) -> str:
        """The kind, and a mesh's file name (for messages)."""
        return f"{self.kind} {Path(self.file).name}" if self.kind == MESH_KIND else self.kind

    @property
    def extents(self) -> np.ndarray:
        """Full extents (dx, dy, dz) of the bounding box, object frame."""
        s = self.size
        if self.kind == MESH_KIND:
            from maniskill_pnp.scenes.meshes import mesh_info

            return mesh_info(self.file, self.scale).extents.copy()
        if self.kind == "cuboid":
            return 2 * np.array(s)
        if self.kind == "cylinder":
            return np.array([2 * s[0], 2 * s[0], 2 * s[1]])
        if self.kind == "sphere":
            return np.full(3, 2 * s[0])
        if self.kind in ("L", "T", "U", "arch"):
            return np.array([s[0], s[1], s[3]])
        if self.kind == "wedge":
            return np.array(s)
        return np.ptp(_hull_points(self), axis=0)

    @property
    def grasp_width(self) -> float:
        """Narrowest width across which the jaws can close on some part of the object (m)."""
        s = self.size
        if self.kind in ("L", "T", "U"):
            return s[2]
        if self.kind == "arch":
            return s[1]
        if self.kind == MESH_KIND:  # the whole footprint's narrowest width (rotating calipers)
            from maniskill_pnp.scenes.meshes import mesh_info

            return mesh_info(self.file, self.scale).footprint_width
        return float(np.min(self.extents[:2]))

    @property
    def footprint_radius(self) -> float:
        """Radius of the circle around the centre that holds the footprint at any yaw (m)."""
        return float(np.hypot(*self.extents[:2]) / 2)

    def boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Convex parts of the box kinds as (centre, half size) in the object frame (empty for other kinds)."""
        s = self.size
        if self.kind == "cuboid":
            return [(np.zeros(3), np.array(s))]
        if self.kind not in ("L", "T", "U", "arch"):
            return []
        length, width, t, height = s
        hz = height / 2
        if self.kind == "L":  # a bar along x and a foot along y at the -x end
            return [
                (np.array([0.0, -width / 2 + t / 2, 0.0]), np.array([length / 2, t / 2, hz])),
                (np.array([-length / 2 + t / 2, t / 2, 0.0]), np.array([t / 2, (width - t) / 2, hz])),
            ]
        if self.kind == "T":  # a bar along x and a stem along y from its middle
            return [
                (np.array([0.0, -width / 2 + t / 2, 0.0]), np.array([length / 2, t / 2, hz])),
                (np.array([0.0, t / 2, 0.0]), np.array([t / 2, (width - t) / 2, hz])),
            ]
        if self.kind == "U":  # a base along x, two arms along y
            return [
                (np.array([0.0, -width / 2 + t / 2, 0.0]), np.array([length / 2, t / 2, hz])),
                (np.array([-length / 2 + t / 2, t / 2, 0.0]), np.array([t / 2, (width - t) / 2, hz])),
                (np.array([length / 2 - t / 2, t / 2, 0.0]), np.array([t / 2, (width - t) / 2, hz])),
            ]
        # arch: two legs (leg = their x thickness) and a lintel of the same thickness on top, spanning x
        lintel = min(max(t, ARCH_MIN_LINTEL), height / 2)
        leg_h = height - lintel
        return [
            (np.array([-length / 2 + t / 2, 0.0, -hz + leg_h / 2]), np.array([t / 2, width / 2, leg_h / 2])),
            (np.array([length / 2 - t / 2, 0.0, -hz + leg_h / 2]), np.array([t / 2, width / 2, leg_h / 2])),
            (np.array([0.0, 0.0, hz - lintel / 2]), np.array([length / 2, width / 2, lintel / 2])),
        ]

    def mesh_vertices(self) -> np.ndarray | None:
        """Vertices (object frame, centred on the bounding box) of the kinds that collide as one convex mesh (wedge,
        hull, and the prism a cylinder collides as), else None."""
        if self.kind == "cylinder":
            radius, half_height = self.size
            angle = 2 * np.pi * np.arange(CYLINDER_SIDES) / CYLINDER_SIDES
            ring = radius * np.stack([np.cos(angle), np.sin(angle)], axis=1)
            return np.concatenate([np.c_[ring, np.full(CYLINDER_SIDES, z)] for z in (-half_height, half_height)])
        if self.kind == "wedge":
            lx, ly, lz = self.size
            tri = np.array([[-lx / 2, -lz / 2], [lx / 2, -lz / 2], [-lx / 2, lz / 2]])  # right triangle in x-z
            return np.array([[x, y, z] for y in (-ly / 2, ly / 2) for x, z in tri])
        if self.kind == "hull":
            return _hull_points(self)
        return None


def _hull_points(spec: ObjectSpec) -> np.ndarray:
    """Random points of a hull: box corners pulled in at random plus points inside, centred on their bounding box."""
    rng = np.random.default_rng(spec.seed)
    half = np.array(spec.size) / 2
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    pts = corners * half * rng.uniform(0.55, 1.0, size=(8, 3))
    pts = np.concatenate([pts, rng.uniform(-1, 1, size=(8, 3)) * half])
    # Keep the full extents so the spec's size is the hull's bounding box.
    for axis in range(3):
        pts[np.argmin(pts[:, axis]), axis] = -half[axis]
        pts[np.argmax(pts[:, axis]), axis] = half[axis]
    return pts - (pts.max(0) + pts.min(0)) / 2


def mesh_file(spec: ObjectSpec) -> Path:
    """Path of the convex-hull mesh (.obj) of a mesh kind, written on first use."""
    import trimesh

    verts = spec.mesh_vertices()
    if verts is None:
        raise ValueError(f"{spec.kind} objects have no mesh")
    key = hashlib.sha1(np.round(verts, 6).tobytes()).hexdigest()[:16]
    path = cache_dir("meshes") / f"{spec.kind}_{key}.obj"
    if not path.exists():
        hull = trimesh.convex.convex_hull(verts)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.obj")
        hull.export(tmp)
        os.replace(tmp, path)
    return path


_UPRIGHT = sapien.Pose(q=[np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])  # SAPIEN cylinder visuals lie along x


def add_collisions(builder, spec: ObjectSpec, material=None) -> None:
    """Add the collision shapes of ``spec`` (object frame) to an actor builder (SAPIEN's or ManiSkill's); ``material``:
    a physical material, or None for the default one."""
    s = spec.size
    if spec.kind == "sphere":
        builder.add_sphere_collision(radius=s[0], material=material)
    elif spec.kind in ("cylinder", "wedge", "hull"):
        builder.add_convex_collision_from_file(filename=str(mesh_file(spec)), material=material)
    elif spec.kind == MESH_KIND:
        from maniskill_pnp.scenes.meshes import convex_parts

        for part in convex_parts(spec.file, spec.scale, spec.collision):
            builder.add_convex_collision_from_file(filename=str(part), material=material, density=spec.density)
    else:
        for center, half in spec.boxes():
            builder.add_box_collision(pose=sapien.Pose(p=center), half_size=half, material=material)


def add_visuals(builder, spec: ObjectSpec) -> None:
    """Add the visual shapes of ``spec`` (object frame) to an actor builder."""
    material = sapien.render.RenderMaterial(base_color=[*spec.color, 1.0])
    s = spec.size
    if spec.kind == "cylinder":
        builder.add_cylinder_visual(pose=_UPRIGHT, radius=s[0], half_length=s[1], material=material)
    elif spec.kind == "sphere":
        builder.add_sphere_visual(radius=s[0], material=material)
    elif spec.kind in ("wedge", "hull"):
        builder.add_visual_from_file(filename=str(mesh_file(spec)), material=material)
    elif spec.kind == MESH_KIND:
        from maniskill_pnp.scenes.meshes import mesh_info

        offset = mesh_info(spec.file, spec.scale).offset
        builder.add_visual_from_file(filename=spec.file, pose=sapien.Pose(p=offset), scale=spec.scale,
                                     material=None if spec.texture else material)
    else:
        for center, half in spec.boxes():
            builder.add_box_visual(pose=sapien.Pose(p=center), half_size=half, material=material)


def collision_shapes(spec: ObjectSpec) -> list[tuple[str, sapien.Pose, tuple]]:
    """The collision shapes :func:`add_collisions` adds (a cylinder as the exact cylinder its prism approximates), as
    ``(kind, local pose, parameters)`` in the object frame:
    ``("box", pose, (half_size,))``, ``("cylinder", pose, (radius, half_height))`` along the pose's z axis,
    ``("sphere", pose, (radius,))`` or ``("convex", pose, (vertices, triangles))``."""
    s = spec.size
    if spec.kind == "cylinder":
        return [("cylinder", sapien.Pose(), (s[0], s[1]))]
    if spec.kind == "sphere":
        return [("sphere", sapien.Pose(), (s[0],))]
    if spec.kind in ("wedge", "hull", MESH_KIND):
        from maniskill_pnp.scenes.meshes import convex_parts, part_arrays

        files = [mesh_file(spec)] if spec.kind != MESH_KIND else convex_parts(spec.file, spec.scale, spec.collision)
        return [("convex", sapien.Pose(), part_arrays(f)) for f in files]
    return [("box", sapien.Pose(p=center), (np.asarray(half, dtype=np.float64),)) for center, half in spec.boxes()]


def build_object(scene, spec: ObjectSpec, name: str, initial_pose: sapien.Pose | None = None):
    """Build ``spec`` as one dynamic actor called ``name`` in a ManiSkill scene (all its convex parts in one builder)."""
    builder = scene.create_actor_builder()
    add_collisions(builder, spec)
    add_visuals(builder, spec)
    builder.initial_pose = initial_pose or sapien.Pose(p=[0.0, 0.0, float(spec.extents[2] / 2)])
    return builder.build(name=name)


def random_object_spec(rng: np.random.Generator, kinds: tuple[str, ...] = KINDS) -> ObjectSpec:
    """A random graspable object of one of ``kinds`` (sizes drawn within the graspability limits)."""
    kind = kinds[int(rng.integers(len(kinds)))]
    color = PALETTE[int(rng.integers(len(PALETTE)))]
    u = rng.uniform
    if kind == "cuboid":
        size = (u(0.012, 0.025), u(0.012, 0.035), u(0.012, 0.025))
    elif kind == "cylinder":
        size = (u(0.012, 0.025), u(0.012, 0.03))
    elif kind == "sphere":
        size = (u(0.015, 0.025),)
    elif kind in ("L", "T", "U"):
        size = (u(0.05, 0.08), u(0.04, 0.07), u(0.012, 0.02), u(0.025, 0.04))
    elif kind == "arch":
        size = (u(0.06, 0.09), u(0.025, 0.04), u(0.012, 0.018), u(0.035, 0.045))
    elif kind == "wedge":
        size = (u(0.04, 0.07), u(0.025, 0.05), u(0.025, 0.045))
    else:
        size = (u(0.03, 0.06), u(0.03, 0.06), u(0.025, 0.045))
    return ObjectSpec(kind, size, color, seed=int(rng.integers(2**31)))
