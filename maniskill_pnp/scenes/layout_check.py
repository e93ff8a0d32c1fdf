"""Shape-exact checks of an explicit layout: the objects' collision shapes, not their bounding boxes.

:func:`check_layout` (what :func:`~maniskill_pnp.scenes.clutter.validate_layout` runs) tests, in this order:

1. every object lies wholly over the workspace square, the heightmap (its collision shapes,
   :func:`~maniskill_pnp.scenes.objects.collision_shapes` at its pose, within :data:`EDGE_TOL` of it), where the arm
   reaches some grasp at its centre (the cell's :class:`~maniskill_pnp.cell.reach_map.ReachMap`), and no lower than
   :data:`BELOW_TABLE_TOL` below the table top (:func:`placement_problem`; a drawn clutter's objects that settle
   otherwise are drawn again);
2. no two objects interpenetrate by more than :data:`PENETRATION_TOL` (PhysX's contact generation on the collision
   shapes in a SAPIEN CPU scene: the separation of every pair closer than :data:`CONTACT_OFFSET`, negative for a
   penetration, as the simulation will see it; objects may touch, and one may lie in another's hollow (a
   cylinder in an arch's tunnel, a part in a U), which bounding boxes cannot tell apart from an overlap;
3. objects that touch another (closer than :data:`CONTACT_GAP`: a stack, a cylinder lying in a cradle, a prism leaning
   on a block) must rest where they are: a short physics settle of those objects on the table (a SAPIEN CPU scene
   of collision shapes only, :data:`SETTLE_TIME` seconds) may move none of them more than :data:`SETTLE_TOL`. Objects
   that touch nothing need no settle: on the table they rest, above it they are dropped (a clutter task lets every
   layout settle before its first observation).

Errors name the objects (``layout object i (kind)``) and the numbers: the penetration depth, or how far each object in
contact moved in the settle. :class:`LayoutCheck` also reports the contacts and those displacements.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import sapien

from maniskill_pnp.scenes.objects import ObjectSpec, add_collisions, collision_shapes
from maniskill_pnp.cell.workspace import WorkspaceSpec

logger = logging.getLogger(__name__)

#: Objects may interpenetrate this deep (m): resting contacts of a simulation, rounding of written poses.
PENETRATION_TOL = 1e-3
#: Shapes may reach this far (m) below the table top.
BELOW_TABLE_TOL = 1e-3
#: Shapes may reach this far (m) past the workspace square's edges.
EDGE_TOL = 1e-3
#: Objects closer than this (m) touch: they are checked by the settle.
CONTACT_GAP = 5e-4
#: Contact offset (m) of the shapes in the check's physics scenes: pairs closer than this are reported.
CONTACT_OFFSET = 2e-3
#: Duration (s) of the settle of touching objects, and the farthest (m) any point of their bounding boxes may move.
SETTLE_TIME = 0.3
SETTLE_TOL = 3e-3
#: Physics of the settle: ManiSkill's default simulation frequency and material (friction 0.3, no restitution).
SETTLE_FREQ = 100
SETTLE_FRICTION = 0.3


@dataclass
class LayoutCheck:
    """What :func:`check_layout` found.

    Attributes:
        layout: The layout with poses as ``sapien.Pose``.
        contacts: Touching pairs ``(i, j, d)``: ``d`` the distance of their shapes (m), negative for a penetration.
        settled: Indices of the objects the settle checked (those in some contact), empty when none was needed.
        displacement: Per object, how far (m) the settle moved its bounding box's farthest corner; NaN for objects
            not in the settle.
    """

    layout: list[tuple[ObjectSpec, sapien.Pose]]
    contacts: list[tuple[int, int, float]] = field(default_factory=list)
    settled: tuple[int, ...] = ()
    displacement: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _name(i: int, spec: ObjectSpec) -> str:
    return f"{i} ({spec.label})"


def world_shapes(spec: ObjectSpec, pose: sapien.Pose) -> list[tuple[str, sapien.Pose, tuple]]:
    return [(kind, pose * local, params) for kind, local, params in collision_shapes(spec)]


def _rot(pose: sapien.Pose) -> np.ndarray:
    return pose.to_transformation_matrix()[:3, :3]


def reachable_pixels(workspace: WorkspaceSpec) -> np.ndarray | None:
    """``bool (H, W)``: the workspace's heightmap pixels where the clutter cell's arm reaches some grasp; None where no
    reach table of its table height is at hand (:meth:`~maniskill_pnp.cell.reach_map.ReachTable.of`)."""
    from maniskill_pnp.cell.reach_map import ReachMap
    from maniskill_pnp.cell.workspace import DEFAULT_ROBOT_BASE

    reach = ReachMap.of(workspace, DEFAULT_ROBOT_BASE)
    return None if reach is None else reach.any_line()


def placement_problem(spec: ObjectSpec, pose: sapien.Pose, workspace: WorkspaceSpec, reach: np.ndarray | None) -> str:
    """Why the object ``spec`` at ``pose`` cannot start a scene ("" when it can): its collision shapes reach past the
    workspace square (by more than :data:`EDGE_TOL`) or below the table (by more than :data:`BELOW_TABLE_TOL`), or,
    with ``reach`` (:func:`reachable_pixels`), its centre lies where the arm reaches no grasp."""
    lo, hi = shape_bounds(world_shapes(spec, pose))
    b = workspace.bounds
    if (lo[:2] < b[:2, 0] - EDGE_TOL).any() or (hi[:2] > b[:2, 1] + EDGE_TOL).any():
        return (f"reaches x {lo[0]:.3f}..{hi[0]:.3f}, y {lo[1]:.3f}..{hi[1]:.3f}: not wholly over the workspace "
                f"x {b[0, 0]:.3f}..{b[0, 1]:.3f}, y {b[1, 0]:.3f}..{b[1, 1]:.3f} (the heightmap the agents see)")
    if lo[2] < workspace.table_z - BELOW_TABLE_TOL:
        return (f"reaches z {lo[2]:.4f}, below the table at {workspace.table_z} (by {(workspace.table_z - lo[2]) * 1000:.1f} "
                f"mm; {BELOW_TABLE_TOL * 1000:.1f} mm allowed)")
    if reach is not None:
        row, col = (int(v) for v in workspace.world_to_pixel(np.asarray(pose.p, dtype=np.float64)))
        if not (0 <= row < reach.shape[0] and 0 <= col < reach.shape[1] and reach[row, col]):
            c = np.asarray(pose.p, dtype=np.float64)
            return f"has its centre at x {c[0]:.3f}, y {c[1]:.3f}, where the arm reaches no top-down grasp"
    return ""


def shape_bounds(shapes) -> tuple[np.ndarray, np.ndarray]:
    """World axis-aligned bounds (lo, hi) of world-posed collision shapes (exact for every shape kind)."""
    los, his = [], []
    for kind, pose, params in shapes:
        c, r = np.asarray(pose.p, dtype=np.float64), _rot(pose)
        if kind == "box":
            half = np.abs(r) @ params[0]
        elif kind == "cylinder":
            radius, hh = params
            axis = r[:, 2]
            half = hh * np.abs(axis) + radius * np.sqrt(np.clip(1.0 - axis ** 2, 0.0, 1.0))
        elif kind == "sphere":
            half = np.full(3, params[0])
        else:
            v = params[0] @ r.T + c
            los.append(v.min(0))
            his.append(v.max(0))
            continue
        los.append(c - half)
        his.append(c + half)
    return np.min(los, axis=0), np.max(his, axis=0)


def _physics_scene(layout, workspace: WorkspaceSpec | None, timestep: float):
    """A SAPIEN CPU physics scene of the collision shapes of ``layout`` (dynamic, named ``object_<k>``) and, with a
    workspace, its table top (a static box); contacts are generated within :data:`CONTACT_OFFSET` of a shape."""
    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
    scene.set_timestep(timestep)
    material = sapien.physx.PhysxMaterial(SETTLE_FRICTION, SETTLE_FRICTION, 0.0)
    if workspace is not None:
        table = scene.create_actor_builder()
        (x0, x1), (y0, y1) = workspace.bounds[:2]
        half = [(x1 - x0) / 2 + 0.5, (y1 - y0) / 2 + 0.5, 0.05]
        table.add_box_collision(pose=sapien.Pose(p=[(x0 + x1) / 2, (y0 + y1) / 2, workspace.table_z - 0.05]),
                                half_size=half, material=material)
        table.build_static(name="table")
    entities = []
    for k, (spec, pose) in enumerate(layout):
        builder = scene.create_actor_builder()
        add_collisions(builder, spec, material=material)
        builder.initial_pose = pose
        entity = builder.build(name=f"object_{k}")
        for shape in entity.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent).collision_shapes:
            shape.set_contact_offset(CONTACT_OFFSET)
        entities.append(entity)
    return scene, entities


def contact_separations(layout: Sequence[tuple[ObjectSpec, sapien.Pose]]) -> dict[tuple[int, int], float]:
    """Per pair of objects of ``layout`` within :data:`CONTACT_OFFSET` of each other: the smallest separation (m) of
    their collision shapes, negative for a penetration (its depth), from PhysX's contact generation (what the simulation
    will see; the objects do not move: one step of a microsecond)."""
    scene, _ = _physics_scene(layout, None, 1e-6)
    scene.step()
    out: dict[tuple[int, int], float] = {}
    for contact in scene.get_contacts():
        names = [body.entity.name for body in contact.bodies]
        if not contact.points or not all(n.startswith("object_") for n in names):
            continue
        i, j = sorted(int(n.split("_")[1]) for n in names)
        sep = min(float(pt.separation) for pt in contact.points)
        out[(i, j)] = min(out.get((i, j), np.inf), sep)
    return out


def settle_displacement(layout: Sequence[tuple[ObjectSpec, sapien.Pose]], workspace: WorkspaceSpec,
                        duration: float = SETTLE_TIME, sim_freq: int = SETTLE_FREQ) -> np.ndarray:
    """How far (m) each object's bounding box (its farthest corner) moves when ``layout`` settles for ``duration``
    seconds on the table: a SAPIEN CPU physics scene of the collision shapes only, nothing else in it."""
    scene, entities = _physics_scene(layout, workspace, 1.0 / sim_freq)
    for _ in range(max(1, int(round(duration * sim_freq)))):
        scene.step()
    out = []
    for (spec, pose), entity in zip(layout, entities):
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * spec.extents / 2
        t0, t1 = pose.to_transformation_matrix(), entity.pose.to_transformation_matrix()
        moved = corners @ t1[:3, :3].T + t1[:3, 3] - (corners @ t0[:3, :3].T + t0[:3, 3])
        out.append(float(np.linalg.norm(moved, axis=1).max()))
    return np.array(out)


def check_layout(layout: Sequence[tuple[ObjectSpec, sapien.Pose]], workspace: WorkspaceSpec, *,
                 penetration_tol: float = PENETRATION_TOL, settle_tol: float = SETTLE_TOL,
                 settle_time: float = SETTLE_TIME) -> LayoutCheck:
    """Check ``layout`` (``(ObjectSpec, sapien.Pose)`` entries, world poses) by its collision shapes (see the module
    docstring).

    Raises:
        ValueError: an object outside the workspace or below the table, two objects interpenetrating (the message
            names both and the depth), or touching objects that do not rest where they are (the message gives how far
            each moved).
    """
    layout = list(layout)
    reach = reachable_pixels(workspace)
    for i, (spec, pose) in enumerate(layout):
        problem = placement_problem(spec, pose, workspace, reach)
        if problem:
            raise ValueError(f"layout object {_name(i, spec)} {problem}")
    contacts = []
    for (i, j), d in sorted(contact_separations(layout).items()):
        if -d > penetration_tol:
            raise ValueError(
                f"layout objects {_name(i, layout[i][0])} and {_name(j, layout[j][0])} overlap: their shapes "
                f"interpenetrate by {-d * 1000:.1f} mm (at most {penetration_tol * 1000:.1f} mm allowed)"
            )
        if d < CONTACT_GAP:
            contacts.append((i, j, d))
    displacement = np.full(len(layout), np.nan)
    touching = tuple(sorted({k for i, j, _ in contacts for k in (i, j)}))
    if touching:
        moved = settle_displacement([layout[k] for k in touching], workspace, settle_time)
        displacement[list(touching)] = moved
        summary = ", ".join(f"object {_name(k, layout[k][0])} {d * 1000:.1f} mm" for k, d in zip(touching, moved))
        logger.debug("layout settle (%.2f s) of the touching objects: %s", settle_time, summary)
        worst = int(np.argmax(moved))
        if moved[worst] > settle_tol:
            k = touching[worst]
            raise ValueError(
                f"layout object {_name(k, layout[k][0])} does not rest where it is placed: it moves {moved[worst] * 1000:.1f} "
                f"mm in a {settle_time:.2f} s physics settle (at most {settle_tol * 1000:.1f} mm allowed); the touching "
                f"objects moved: {summary}"
            )
    return LayoutCheck(layout, contacts, touching, displacement)
