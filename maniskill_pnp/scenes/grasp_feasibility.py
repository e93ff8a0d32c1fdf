"""Which objects of a layout a top-down parallel-jaw grasp can take at all: an object no grasp fits is *locked*.

A candidate grasp is a jaw orientation (yaw of the closing direction, every ``yaw_step_deg`` over 180°; the open
gripper is symmetric under a half turn) at a position over the object (a grid of ``position_step`` over the cells
where the object is the topmost surface, as a heightmap sees it). Its fingertip TCP goes where the task sends it:
:meth:`~maniskill_pnp.cell.workspace.WorkspaceSpec.grasp_tcp_height` of the surface height at that position. It is
*feasible* when

1. the open gripper, lowered straight down to that depth, touches nothing on its way: no part of it (the fingers'
   collision boxes and the hand's collision hull, as ``panda_v2.urdf`` gives them, fingers
   :attr:`~maniskill_pnp.planning.robot.ArmSpec.gripper_open` open) comes below the highest surface of any object
   (the object itself included: a finger may not land on it) or of the table over the same point; and
2. closing would close on the object: it lies between the two finger pads (the space between their inner faces)
   within the pads' height band at that depth (at least :data:`MIN_GRIP` of it), across the pads' whole width, so
   that the pads bear on it flat (a pinch of a corner or an edge, where part of a pad's width closes on nothing, is
   not a grasp), and what each pad meets first slopes across the pad's width by at most :data:`FRICTION` × that
   width (the contact faces lie within the friction cone of the closing direction: a box turned up to ~17° from the
   jaws, a cylinder through its axis; a corner pinched obliquely slips out).

A vertical descent touches an object exactly when the object's highest point over some column of the gripper is above
the gripper's lowest point over that column, so the check compares height columns: every object's collision shapes
(:func:`~maniskill_pnp.scenes.objects.collision_shapes`: boxes, cylinders, spheres and convex parts, exactly, as
half-space intersections) become a map of their lowest and highest point per cell of a ``resolution`` grid (0.5 mm),
and the gripper a set of points with its lowest height above the TCP (finger boxes every 1 mm with their edges, the
hand every 2 mm). The answers are exact up to that grid.

:func:`grasp_feasibility` returns an :class:`ObjectGrasps` per object (locked or not, the feasible candidates, one
example grasp); ``maniskill-pnp check-scene FILE...`` prints them per scene file.
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sapien

from maniskill_pnp.scenes.layout_check import shape_bounds
from maniskill_pnp.scenes.objects import ObjectSpec, collision_shapes
from maniskill_pnp.cell.workspace import WorkspaceSpec

#: Defaults of the candidate grid: jaw orientations every 15° over 180°, positions every 3 mm.
YAW_STEP_DEG = 15.0
POSITION_STEP = 0.003
#: Cell size (m) of the height columns of the objects.
RESOLUTION = 5e-4
#: Sampling pitch (m) of the fingers' and the hand's collision geometry.
FINGER_PITCH = 1e-3
HAND_PITCH = 2e-3
#: The object must fill at least this much (m) of the pads' height band between them.
MIN_GRIP = 1e-3
#: Friction coefficient of the pads on objects (the task's material): the slope of a contact face across the pads
#: that still holds.
FRICTION = 0.3
#: Sides of the polygon standing in for a cylinder's circle (0.01 mm off for a 1 cm radius).
CYLINDER_SIDES = 64


@dataclass(frozen=True)
class GripperModel:
    """The open gripper pointing down, in the grasp frame: ``x`` along the pads' width, ``y`` the closing direction,
    heights above the fingertip TCP.

    Attributes:
        points: ``(M, 3)``: x, y and the lowest height (m above the TCP) of the gripper over that point.
        pad_half_width: Half the pads' extent along x (m).
        pad_inner: ``|y|`` of the open pads' inner faces (m).
        pad_band: Lowest and highest height of the pads above the TCP (m).
    """

    points: np.ndarray
    pad_half_width: float
    pad_inner: float
    pad_band: tuple[float, float]


@dataclass(frozen=True)
class ObjectGrasps:
    """The grasps of one object of a layout.

    Attributes:
        index: The object's index in the layout.
        label: Its kind (and a mesh's file name).
        candidates: (orientation, position) candidates over it.
        feasible: Those that pass (see the module docstring).
        example: One feasible grasp ``(x, y, tcp_z, yaw)`` (world m, rad), None when locked.
    """

    index: int
    label: str
    candidates: int
    feasible: int
    example: tuple[float, float, float, float] | None

    @property
    def locked(self) -> bool:
        """No grasp fits."""
        return self.feasible == 0

    @property
    def fraction(self) -> float:
        """Feasible candidates / candidates."""
        return self.feasible / self.candidates if self.candidates else 0.0


# ----------------------------------------------------------------------------- height columns of convex shapes
def _halfspaces(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A, b)`` with ``A @ x <= b`` inside the convex hull of ``vertices``."""
    from scipy.spatial import ConvexHull

    eq = ConvexHull(vertices).equations  # n . x + d <= 0
    return eq[:, :3], -eq[:, 3]


def _columns(a: np.ndarray, b: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest z of the convex set ``a @ x <= b`` over each point ``xy`` (``(N, 2)``); NaN where the
    vertical line misses it."""
    rest = b[None, :] - xy @ a[:, :2].T  # a_z z <= rest
    az = a[:, 2]
    up, down, side = az > 1e-9, az < -1e-9, np.abs(az) <= 1e-9
    hi = np.min(rest[:, up] / az[up], axis=1) if up.any() else np.full(len(xy), np.inf)
    lo = np.max(rest[:, down] / az[down], axis=1) if down.any() else np.full(len(xy), -np.inf)
    ok = lo <= hi
    if side.any():
        ok &= np.all(rest[:, side] >= -1e-9, axis=1)
    return np.where(ok, lo, np.nan), np.where(ok, hi, np.nan)


def _shape_vertices(kind: str, pose: sapien.Pose, params) -> np.ndarray | None:
    """World vertices of a convex collision shape (a cylinder as a :data:`CYLINDER_SIDES`-gon prism); None for a
    sphere."""
    t = pose.to_transformation_matrix()
    if kind == "box":
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * params[0]
    elif kind == "cylinder":
        radius, hh = params
        a = np.linspace(0, 2 * np.pi, CYLINDER_SIDES, endpoint=False)
        ring = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
        local = np.concatenate([np.column_stack([ring, np.full(len(a), z)]) for z in (-hh, hh)])
    elif kind == "sphere":
        return None
    else:
        local = np.asarray(params[0], dtype=np.float64)
    return local @ t[:3, :3].T + t[:3, 3]


# ----------------------------------------------------------------------------- the gripper
def _box_vertices(origin: ET.Element | None, size: np.ndarray) -> np.ndarray:
    xyz = np.zeros(3) if origin is None else np.array([float(v) for v in origin.get("xyz", "0 0 0").split()])
    rpy = np.zeros(3) if origin is None else np.array([float(v) for v in origin.get("rpy", "0 0 0").split()])
    from scipy.spatial.transform import Rotation

    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size / 2
    return corners @ Rotation.from_euler("xyz", rpy).as_matrix().T + xyz


def _joint(root: ET.Element, name: str) -> tuple[np.ndarray, np.ndarray]:
    joint = root.find(f"joint[@name='{name}']")
    if joint is None:
        raise ValueError(f"the Panda URDF has no joint {name!r}")
    origin = joint.find("origin")
    xyz = np.array([float(v) for v in origin.get("xyz").split()])
    axis = joint.find("axis")
    return xyz, np.zeros(3) if axis is None else np.array([float(v) for v in axis.get("xyz").split()])


def _sample(vertices: np.ndarray, pitch: float) -> np.ndarray:
    """Points ``(x, y, lowest height)`` of a convex part given in (x, y, height-above-TCP) coordinates, on a grid of
    ``pitch`` over its footprint's bounding rectangle with its edges."""
    lo, hi = vertices[:, :2].min(0), vertices[:, :2].max(0)
    axes = [np.linspace(lo[k], hi[k], max(2, int(math.ceil((hi[k] - lo[k]) / pitch)) + 1)) for k in range(2)]
    xy = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    a, b = _halfspaces(vertices)
    bottom, _ = _columns(a, b + 1e-9, xy)
    keep = ~np.isnan(bottom)
    return np.column_stack([xy[keep], bottom[keep]])


@functools.lru_cache(maxsize=4)
def panda_gripper(opening: float | None = None) -> GripperModel:
    """The open Panda gripper of ManiSkill's ``panda_v2.urdf`` (:func:`~maniskill_pnp.planning.robot.panda_spec`):
    its fingers' collision boxes at ``opening`` per finger (default the spec's ``gripper_open``, 4 cm) and its hand's
    collision mesh as its convex hull (as the simulator loads it), pointing down, in the frame of
    :class:`GripperModel`."""
    import trimesh

    from maniskill_pnp.planning.robot import panda_spec

    spec = panda_spec()
    opening = spec.gripper_open if opening is None else float(opening)
    root = ET.parse(spec.urdf).getroot()
    tcp, _ = _joint(root, "panda_hand_tcp_joint")
    parts, pads = [], []  # vertices in the hand frame, with their sampling pitch
    for link, joint in (("panda_leftfinger", "panda_finger_joint1"), ("panda_rightfinger", "panda_finger_joint2")):
        offset, axis = _joint(root, joint)
        boxes = [_box_vertices(c.find("origin"), np.array([float(v) for v in c.find("geometry/box").get("size").split()]))
                 + offset + opening * axis for c in root.findall(f"link[@name='{link}']/collision")]
        if not boxes:
            raise ValueError(f"the Panda URDF's {link} has no collision boxes")
        parts += [(v, FINGER_PITCH) for v in boxes]
        pads.append(max(boxes, key=lambda v: v[:, 2].max()))  # the fingertip pad: the box that reaches lowest
    mesh = root.find("link[@name='panda_hand']/collision/geometry/mesh")
    if mesh is not None:
        hull = trimesh.load(spec.urdf.parent / mesh.get("filename"), force="mesh").convex_hull
        parts.append((np.asarray(hull.vertices), HAND_PITCH))

    def grasp_frame(v):  # hand z points down to the fingers: height above the TCP is tcp_z - z
        return np.column_stack([v[:, 0], v[:, 1], tcp[2] - v[:, 2]])

    points = np.concatenate([_sample(grasp_frame(v), pitch) for v, pitch in parts])
    pad = [grasp_frame(v) for v in pads]
    inner = min(float(np.abs(v[:, 1]).min()) for v in pad)
    band = (min(float(v[:, 2].min()) for v in pad), max(float(v[:, 2].max()) for v in pad))
    half = min(float(np.abs(v[:, 0]).max()) for v in pad)
    return GripperModel(points, half, inner, band)


# ----------------------------------------------------------------------------- the layout's height maps
@dataclass
class _Maps:
    origin: np.ndarray  # world xy of cell (0, 0)
    step: float
    lo: np.ndarray  # (K, nx, ny) lowest z of object k over the cell, NaN where absent
    hi: np.ndarray
    top: np.ndarray  # (nx, ny) highest surface: objects or the table

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices of world points and whether they are on the map."""
        ij = np.rint((xy - self.origin) / self.step).astype(np.int64)
        return self._clipped(ij[..., 0], ij[..., 1])

    def moved(self, ii: np.ndarray, jj: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices ``(N, M)`` of the cells ``(ii, jj)`` (``N`` each) moved by the integer cell ``offsets``
        (``(M, 2)``), and whether they are on the map."""
        return self._clipped(ii[:, None] + offsets[None, :, 0], jj[:, None] + offsets[None, :, 1])

    def _clipped(self, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices clipped to the map, and whether they were on it."""
        inside = (i >= 0) & (i < self.top.shape[0]) & (j >= 0) & (j < self.top.shape[1])
        return np.clip(i, 0, self.top.shape[0] - 1), np.clip(j, 0, self.top.shape[1] - 1), inside


def _cell_offsets(xy: np.ndarray, yaw: float, step: float) -> np.ndarray:
    """Integer cell offsets ``(M, 2)`` of points ``xy`` (``(M, 2)``, the grasp frame: x along the pads, y the closing
    direction) turned by the jaw orientation ``yaw``: a candidate on a cell centre and a point of its gripper fall in
    cells that far apart, whatever the candidate."""
    w, c = np.array([-math.sin(yaw), math.cos(yaw)]), np.array([math.cos(yaw), math.sin(yaw)])
    return np.rint((xy[:, :1] * w + xy[:, 1:2] * c) / step).astype(np.int64)


def lowest_per_offset(offsets: np.ndarray, heights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct ``offsets`` and, for each, the lowest of the ``heights`` of the points that fall there (the
    gripper strikes a cell's surface first with its lowest point over it)."""
    unique, inverse = np.unique(offsets, axis=0, return_inverse=True)
    lowest = np.full(len(unique), np.inf)
    np.minimum.at(lowest, inverse.reshape(-1), heights)
    return unique, lowest


def _maps(layout, table_z: float, step: float) -> _Maps:
    shapes = [[(kind, pose * local, params) for kind, local, params in collision_shapes(spec)] for spec, pose in layout]
    bounds = [shape_bounds(s) for s in shapes]
    lo_all = np.min([b[0][:2] for b in bounds], axis=0) - 2 * step
    hi_all = np.max([b[1][:2] for b in bounds], axis=0) + 2 * step
    n = np.ceil((hi_all - lo_all) / step).astype(int) + 1
    lo = np.full((len(layout), *n), np.nan)
    hi = np.full((len(layout), *n), np.nan)
    for k, object_shapes in enumerate(shapes):
        for kind, pose, params in object_shapes:
            blo, bhi = shape_bounds([(kind, pose, params)])
            i0, j0 = np.floor((blo[:2] - lo_all) / step).astype(int)
            i1, j1 = np.ceil((bhi[:2] - lo_all) / step).astype(int) + 1
            ii, jj = np.meshgrid(np.arange(i0, i1), np.arange(j0, j1), indexing="ij")
            xy = lo_all + step * np.stack([ii.ravel(), jj.ravel()], axis=1)
            verts = _shape_vertices(kind, pose, params)
            if verts is None:  # sphere
                c, r = np.asarray(pose.p, dtype=np.float64), params[0]
                d2 = r ** 2 - np.sum((xy - c[:2]) ** 2, axis=1)
                h = np.sqrt(np.where(d2 >= 0, d2, np.nan))
                zlo, zhi = c[2] - h, c[2] + h
            else:
                zlo, zhi = _columns(*_halfspaces(verts), xy)
            cur_lo, cur_hi = lo[k, ii.ravel(), jj.ravel()], hi[k, ii.ravel(), jj.ravel()]
            lo[k, ii.ravel(), jj.ravel()] = np.fmin(cur_lo, zlo)
            hi[k, ii.ravel(), jj.ravel()] = np.fmax(cur_hi, zhi)
    top = np.fmax(np.nanmax(np.where(np.isnan(hi), -np.inf, hi), axis=0), table_z)
    return _Maps(lo_all, step, lo, hi, top)


# ----------------------------------------------------------------------------- the check
def grasp_feasibility(layout: Sequence[tuple[ObjectSpec, sapien.Pose]], workspace: WorkspaceSpec | None = None, *,
                      yaw_step_deg: float = YAW_STEP_DEG, position_step: float = POSITION_STEP,
                      resolution: float = RESOLUTION, gripper: GripperModel | None = None,
                      objects: Sequence[int] | None = None, first_only: bool = False) -> list[ObjectGrasps]:
    """Per object of ``layout`` (``(ObjectSpec, world pose)``, e.g. from
    :func:`~maniskill_pnp.scenes.scene_file.load_scene`): its grasp candidates and the feasible ones (see the module
    docstring). ``workspace`` gives the table height and the grasp depth rule (default :class:`WorkspaceSpec`).
    ``objects``: only these indices of ``layout`` are checked (every object still counts as an obstacle);
    ``first_only``: stop at the first jaw orientation with a feasible grasp (``feasible`` then counts that
    orientation's only; ``locked`` is exact either way, and much cheaper to learn for objects that are not).

    Raises:
        ValueError: an empty layout, an entry that is not ``(ObjectSpec, pose)``, an index of ``objects`` out of
            range, or a non-positive step.
    """
    layout = list(layout)
    if not layout:
        raise ValueError("grasp_feasibility needs a layout with at least one object")
    for i, entry in enumerate(layout):
        if not isinstance(entry, (tuple, list)) or len(entry) != 2 or not isinstance(entry[0], ObjectSpec) \
                or not isinstance(entry[1], sapien.Pose):
            raise ValueError(f"layout entry {i} must be (ObjectSpec, sapien.Pose), got {entry!r}")
    for name, v in (("yaw_step_deg", yaw_step_deg), ("position_step", position_step), ("resolution", resolution)):
        if not v > 0:
            raise ValueError(f"{name} must be > 0, got {v!r}")
    checked = range(len(layout)) if objects is None else [int(k) for k in objects]
    if any(not 0 <= k < len(layout) for k in checked):
        raise ValueError(f"objects must be indices into the layout's {len(layout)} objects, got {list(objects)}")
    workspace = workspace or WorkspaceSpec()
    gripper = gripper or panda_gripper()
    maps = _maps(layout, workspace.table_z, resolution)
    yaws = np.deg2rad(np.arange(0.0, 180.0 - 1e-9, yaw_step_deg))
    stride = max(1, int(round(position_step / resolution)))
    height_above = workspace.table_z
    # closing region: between the pads' inner faces, across their width
    cx = np.linspace(-gripper.pad_half_width, gripper.pad_half_width, 9)
    cy = np.linspace(-gripper.pad_inner, gripper.pad_inner, max(3, int(2 * gripper.pad_inner / FINGER_PITCH) + 1))[1:-1]
    closing = np.stack(np.meshgrid(cx, cy, indexing="ij"), axis=-1).reshape(-1, 2)
    out, under = [], {}
    for k in checked:
        spec = layout[k][0]
        visible = ~np.isnan(maps.hi[k]) & (maps.hi[k] >= maps.top - 1e-9)
        ii, jj = np.nonzero(visible & (np.arange(visible.shape[0])[:, None] % stride == 0)
                            & (np.arange(visible.shape[1])[None, :] % stride == 0))
        if not len(ii):
            ii, jj = np.nonzero(visible)
        pos = maps.origin + resolution * np.stack([ii, jj], axis=1)
        tcp = np.array([workspace.grasp_tcp_height(float(maps.top[i, j] - height_above)) for i, j in zip(ii, jj)])
        # gripper points that can reach below the highest surface near this object
        feasible, example = 0, None
        for yaw in yaws:
            if yaw not in under:  # the gripper's cells at this orientation, the same for every object
                under[yaw] = lowest_per_offset(_cell_offsets(gripper.points, yaw, resolution), gripper.points[:, 2])
            offsets, lowest = under[yaw]
            if len(tcp):  # only cells low enough to meet the highest surface near this object
                near = lowest + tcp.min() < float(maps.top.max())
                offsets, lowest = offsets[near], lowest[near]
            ok = np.ones(len(pos), dtype=bool)
            if len(offsets):
                i, j, inside = maps.moved(ii, jj, offsets)
                surface = np.where(inside, maps.top[i, j], workspace.table_z)
                ok = ~np.any(surface - lowest[None, :] > tcp[:, None] + 1e-6, axis=1)
            if not ok.any():
                continue
            sel = np.nonzero(ok)[0]
            i, j, inside = maps.moved(ii[sel], jj[sel], _cell_offsets(closing, yaw, resolution))
            band_lo = (tcp[sel] + gripper.pad_band[0])[:, None]
            band_hi = (tcp[sel] + gripper.pad_band[1])[:, None]
            overlap = np.minimum(maps.hi[k][i, j], band_hi) - np.maximum(maps.lo[k][i, j], band_lo)  # NaN: absent
            held = (inside & (np.nan_to_num(overlap, nan=-1.0) >= MIN_GRIP)).reshape(len(sel), len(cx), len(cy))
            ymax = np.max(np.where(held, cy, -np.inf), axis=2)  # where each line across a pad first meets it
            ymin = np.min(np.where(held, cy, np.inf), axis=2)
            tol = FRICTION * 2 * gripper.pad_half_width
            with np.errstate(invalid="ignore"):
                flat = (np.ptp(ymax, axis=1) <= tol) & (np.ptp(ymin, axis=1) <= tol)
            grip = np.all(np.isfinite(ymax), axis=1) & flat
            feasible += int(grip.sum())
            if example is None and grip.any():  # the feasible position nearest the middle of the object's top
                held_pos = sel[grip]
                m = held_pos[int(np.argmin(np.linalg.norm(pos[held_pos] - pos.mean(axis=0), axis=1)))]
                example = (float(pos[m, 0]), float(pos[m, 1]), float(tcp[m]), float(yaw))
            if first_only and feasible:
                break
        out.append(ObjectGrasps(k, spec.label, len(pos) * len(yaws), feasible, example))
    return out


def check_scene_file(path, workspace: WorkspaceSpec | None = None, **kwargs) -> list[ObjectGrasps]:
    """:func:`grasp_feasibility` of the scene file ``path`` (loaded and validated in ``workspace``, default
    :class:`WorkspaceSpec`)."""
    from maniskill_pnp.scenes.scene_file import load_scene

    workspace = workspace or WorkspaceSpec()
    return grasp_feasibility(load_scene(Path(path), workspace), workspace, **kwargs)


def format_report(name: str, grasps: Sequence[ObjectGrasps]) -> str:
    """A scene's report: a header line (objects, locked) and one line per object."""
    locked = sum(g.locked for g in grasps)
    lines = [f"{name}: {len(grasps)} objects, {locked} locked"]
    for g in grasps:
        state = "LOCKED" if g.locked else "free  "
        lines.append(f"  object {g.index} ({g.label}): {state} {g.feasible}/{g.candidates} grasps feasible "
                     f"({100 * g.fraction:.1f}%)")
    return "\n".join(lines)


__all__ = ["GripperModel", "ObjectGrasps", "check_scene_file", "format_report", "grasp_feasibility", "lowest_per_offset", "panda_gripper"]
