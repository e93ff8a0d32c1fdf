"""Clutter generation: random or hand-designed piles of objects (procedural or from mesh files) in the workspace.

* :func:`sample_clutter` draws poses for a list of :class:`ObjectSpec`: loosely packed (upright, random yaw,
  footprints kept ``min_gap`` apart by rejection sampling, so every object can be grasped) or any packing
  (random orientation, anywhere in the spawn square, dropped from staggered heights so they pile up).
* :func:`sample_packed` draws tightly packed clusters: upright objects side by side, a few millimetres apart, so
  the jaws fit between few of them (a slide has to make room first).
* :func:`redrop_poses` drops again the objects of a drop that settled outside the workspace.
* :func:`validate_layout` checks an explicit layout (a list of ``(ObjectSpec, pose)``) by the objects' collision
  shapes (:mod:`~maniskill_pnp.scenes.layout_check`): inside the workspace, above the table, no two interpenetrating,
  and touching objects at rest in a short physics settle; it raises a ``ValueError`` naming the culprits.
* :func:`object_status` says where each object is: in the workspace, in the bin, or lost.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sapien

from maniskill_pnp.scenes.objects import KINDS, ObjectSpec, random_object_spec
from maniskill_pnp.cell.workspace import WorkspaceSpec

#: Object counts (min, max) per clutter density (thesis chapters 5 and 6).
DENSITY_PRESETS = {"minimum": (6, 10), "thesis": (10, 15), "medium": (15, 20), "maximum": (25, 30), "complicated": (3, 7)}
#: Chapter 6's short names for presets of :data:`DENSITY_PRESETS`.
DENSITY_ALIASES = {"min": "minimum", "max": "maximum"}


def density_range(name: str) -> tuple[int, int]:
    """Object count range (min, max) of a density preset name of :data:`DENSITY_PRESETS` or :data:`DENSITY_ALIASES`.

    Raises:
        ValueError: an unknown name (the message lists the valid ones).
    """
    key = DENSITY_ALIASES.get(name, name)
    if key not in DENSITY_PRESETS:
        raise ValueError(f"unknown density preset {name!r}; valid: {list(DENSITY_PRESETS) + list(DENSITY_ALIASES)}")
    return DENSITY_PRESETS[key]

Pose7 = tuple[float, float, float, float, float, float, float]  # x, y, z, qw, qx, qy, qz


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def as_pose(pose) -> sapien.Pose:
    """A sapien.Pose from a sapien.Pose, a 7-vector (p, q wxyz) or a 3-vector (position, identity rotation)."""
    if isinstance(pose, sapien.Pose):
        return pose
    a = np.asarray(pose, dtype=np.float64).reshape(-1)
    if a.shape == (3,):
        return sapien.Pose(p=a)
    if a.shape != (7,) or not np.isfinite(a).all():
        raise ValueError(f"a pose is (x, y, z) or (x, y, z, qw, qx, qy, qz), got {pose!r}")
    q = a[3:] / np.linalg.norm(a[3:])
    return sapien.Pose(p=a[:3], q=q)


def random_specs(rng: np.random.Generator, n: int, kinds: Sequence[str] = KINDS) -> list[ObjectSpec]:
    """``n`` random objects of ``kinds``."""
    return [random_object_spec(rng, tuple(kinds)) for _ in range(n)]


def sample_clutter(
    rng: np.random.Generator,
    specs: Sequence[ObjectSpec],
    workspace: WorkspaceSpec,
    loosely_packed: bool = True,
    min_gap: float = 0.01,
    max_tries: int = 300,
    restarts: int = 30,
) -> list[sapien.Pose]:
    """Drop poses for ``specs`` over the spawn square of ``workspace``.

    Loosely packed: upright, random yaw, footprints (bounding rectangles) at least ``min_gap`` apart and inside
    the spawn square, released 2 mm above the table. Otherwise: random orientation anywhere in the square, each
    released just above the objects already dropped under it (they pile up).

    Raises:
        ValueError: the objects do not fit loosely (fewer objects or a smaller ``min_gap`` would).
    """
    (x0, x1), (y0, y1) = workspace.spawn_bounds
    poses: list[sapien.Pose] = []
    if loosely_packed:
        # Largest footprints first (they are the hard ones to fit); whole restarts when one no longer fits.
        order = sorted(range(len(specs)), key=lambda i: -specs[i].extents[0] * specs[i].extents[1])
        for _ in range(restarts):
            placed: list[tuple] = []
            by_index: dict[int, sapien.Pose] = {}
            for i in order:
                spec = specs[i]
                for _ in range(max_tries):
                    xy = rng.uniform([x0, y0], [x1, y1])
                    yaw = rng.uniform(-np.pi, np.pi)
                    pose, box = _upright(spec, xy, yaw, workspace, grow=min_gap / 2)
                    if _inside_xy(box, (x0, x1, y0, y1)) and not any(_footprints_overlap(box, other) for other in placed):
                        placed.append(box)
                        by_index[i] = pose
                        break
                else:
                    break
            if len(by_index) == len(specs):
                return [by_index[i] for i in range(len(specs))]
        raise ValueError(
            f"could not place {len(specs)} objects loosely (min gap {min_gap} m) in the spawn square; "
            "use fewer objects, a smaller min_gap or loosely_packed=False"
        )
    # Bounding spheres (xy centre, radius, top) released so far; a new one goes above those whose footprint
    # circles it overlaps, so no two objects start inside each other and none falls from higher than it must.
    dropped: list[tuple[np.ndarray, float, float]] = []
    for spec in specs:
        xy = rng.uniform([x0, y0], [x1, y1])
        q = rng.normal(size=4)
        r = float(np.linalg.norm(spec.extents)) / 2
        z = workspace.table_z + r + 0.005
        for xy2, r2, top2 in dropped:
            if np.hypot(*(xy - xy2)) < r + r2:
                z = max(z, top2 + r + 0.005)
        dropped.append((xy, r, z + r))
        poses.append(sapien.Pose(p=[xy[0], xy[1], z], q=q / np.linalg.norm(q)))
    return poses


def redrop_poses(
    rng: np.random.Generator,
    specs: Sequence[ObjectSpec],
    resting: Sequence[tuple[ObjectSpec, np.ndarray]],
    workspace: WorkspaceSpec,
    upright: bool = True,
    gap: float = 0.01,
    tries: int = 100,
) -> list[sapien.Pose]:
    """Poses that drop ``specs`` again over the spawn square of ``workspace``, beside or onto the objects ``resting``
    there (``(spec, position)`` each): the objects of a drop that settled outside the workspace.

    Each goes where its bounding circle stays ``gap`` clear of every other one's, when one of ``tries`` random
    points is such a place, released just above the table; else at the last point tried, released just above the
    bounding spheres it overlaps (it lands on the pile). ``upright``: standing with a random yaw (as loosely packed
    and packed clutters stand); otherwise a random orientation (as piles fall).
    """
    (x0, x1), (y0, y1) = workspace.spawn_bounds
    others = [(np.asarray(p, dtype=np.float64), float(np.linalg.norm(spec.extents)) / 2) for spec, p in resting]
    poses = []
    for spec in specs:
        r = float(np.linalg.norm(spec.extents)) / 2
        for _ in range(tries):
            xy = rng.uniform([x0, y0], [x1, y1])
            if all(np.hypot(*(xy - p[:2])) >= r + r2 + gap for p, r2 in others):
                break
        z = workspace.table_z + (spec.extents[2] / 2 if upright else r) + 0.002
        for p, r2 in others:
            if np.hypot(*(xy - p[:2])) < r + r2 + gap:
                z = max(z, p[2] + r2 + r + 0.005)
        if upright:
            q = yaw_quat(rng.uniform(-np.pi, np.pi))
        else:
            q = rng.normal(size=4)
            q /= np.linalg.norm(q)
        poses.append(sapien.Pose(p=[xy[0], xy[1], z], q=q))
        others.append((np.array([xy[0], xy[1], z]), r))
    return poses


def sample_packed(
    rng: np.random.Generator,
    specs: Sequence[ObjectSpec],
    workspace: WorkspaceSpec,
    gap: tuple[float, float] = (0.001, 0.003),
    cluster_size: tuple[int, int] = (3, 6),
    max_tries: int = 200,
    restarts: int = 30,
) -> list[sapien.Pose]:
    """Poses that pack ``specs`` into tight clusters over the spawn square of ``workspace``.

    Each cluster (``cluster_size`` objects, the last one what is left) has one random yaw. Its first object stands
    at a random point; each next one stands beside a random member of the cluster, along one of that member's
    sides, ``gap`` (m, uniform in the range) from it and shifted along the side by up to half of it. Objects are
    upright (as :func:`sample_clutter` places loose ones), released 2 mm above the table, footprints apart from
    every other object's and inside the spawn square.

    Raises:
        ValueError: bad ``gap`` or ``cluster_size``, or the objects do not fit (fewer objects would).
    """
    lo_gap, hi_gap = (float(g) for g in gap)
    lo_n, hi_n = (int(n) for n in cluster_size)
    if not 0 <= lo_gap <= hi_gap or not 1 <= lo_n <= hi_n:
        raise ValueError(f"need 0 <= gap[0] <= gap[1] and 1 <= cluster_size[0] <= cluster_size[1], got {gap}, {cluster_size}")
    (x0, x1), (y0, y1) = workspace.spawn_bounds
    rect = (x0, x1, y0, y1)

    for _ in range(restarts):
        placed: list[tuple] = []
        poses: list[sapien.Pose] = []
        cluster: list[tuple[np.ndarray, np.ndarray]] = []  # (xy, half extents) of the current cluster's members
        left_in_cluster, yaw = 0, 0.0
        for spec in specs:
            if left_in_cluster == 0:
                cluster, left_in_cluster, yaw = [], int(rng.integers(lo_n, hi_n + 1)), float(rng.uniform(-np.pi, np.pi))
            axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])  # the cluster's x and y
            half = spec.extents[:2] / 2
            for _ in range(max_tries):
                if not cluster:
                    xy = rng.uniform([x0, y0], [x1, y1])
                else:
                    xy0, half0 = cluster[int(rng.integers(len(cluster)))]
                    k, sign = int(rng.integers(2)), float(rng.choice([-1.0, 1.0]))
                    along = (half0[k] + half[k] + rng.uniform(lo_gap, hi_gap)) * sign
                    shift = rng.uniform(-0.5, 0.5) * half0[1 - k]
                    xy = xy0 + along * axes[k] + shift * axes[1 - k]
                pose, box = _upright(spec, xy, yaw, workspace)
                if _inside_xy(box, rect) and not any(_footprints_overlap(box, other) for other in placed):
                    placed.append(box)
                    poses.append(pose)
                    cluster.append((xy, half))
                    left_in_cluster -= 1
                    break
            else:
                break
        if len(poses) == len(specs):
            return poses
    raise ValueError(f"could not pack {len(specs)} objects into clusters in the spawn square; use fewer objects")


def _upright(spec: ObjectSpec, xy, yaw: float, workspace: WorkspaceSpec, grow: float = 0.0) -> tuple[sapien.Pose, tuple]:
    """The pose of ``spec`` standing upright at ``xy`` with ``yaw``, released 2 mm above the table, and its footprint:
    a tall slab in z (centre, rotation, half size), grown by ``grow`` in x and y."""
    pose = sapien.Pose(p=[xy[0], xy[1], workspace.table_z + spec.extents[2] / 2 + 0.002], q=yaw_quat(yaw))
    c, rot, half = _obb(spec, pose)
    return pose, (np.array([c[0], c[1], 0.0]), rot, np.array([half[0] + grow, half[1] + grow, 1.0]))


def _obb(spec: ObjectSpec, pose: sapien.Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rot = pose.to_transformation_matrix()[:3, :3]
    return np.asarray(pose.p, dtype=np.float64), rot, spec.extents / 2


def _obb_overlap(a, b, tol: float = 1e-4) -> bool:
    """Separating-axis test of two oriented boxes (centre, rotation, half size); touching does not count."""
    ca, ra, ha = a
    cb, rb, hb = b
    axes = [ra[:, i] for i in range(3)] + [rb[:, i] for i in range(3)]
    axes += [np.cross(ra[:, i], rb[:, j]) for i in range(3) for j in range(3)]
    d = cb - ca
    for ax in axes:
        n = np.linalg.norm(ax)
        if n < 1e-9:
            continue
        ax = ax / n
        pa = np.sum(np.abs(ra.T @ ax) * ha)
        pb = np.sum(np.abs(rb.T @ ax) * hb)
        if abs(d @ ax) >= pa + pb - tol:
            return False
    return True


def _footprints_overlap(a, b) -> bool:
    """Overlap of two footprint slabs; far-apart pairs are ruled out by their bounding circles first."""
    if np.hypot(*(a[0][:2] - b[0][:2])) > np.hypot(*a[2][:2]) + np.hypot(*b[2][:2]):
        return False
    return _obb_overlap(a, b)


def _inside_xy(box, rect) -> bool:
    c, rot, half = box
    ext = np.abs(rot[:2, :2]) @ half[:2]
    x0, x1, y0, y1 = rect
    return x0 <= c[0] - ext[0] and c[0] + ext[0] <= x1 and y0 <= c[1] - ext[1] and c[1] + ext[1] <= y1


def validate_layout(layout: Sequence[tuple[ObjectSpec, object]], workspace: WorkspaceSpec
                    ) -> list[tuple[ObjectSpec, sapien.Pose]]:
    """Check an explicit layout and return it with poses as ``sapien.Pose``.

    Each entry is ``(ObjectSpec, pose)``; pose as for :func:`as_pose`. Each object's centre must lie over the heightmap
    square; its collision shapes (not its bounding box) must not reach below the table nor interpenetrate another's; objects that
    touch others must rest where they are in a short physics settle (:func:`~maniskill_pnp.scenes.layout_check.check_layout`,
    which also reports the contacts and how far the settle moved each object).

    Raises:
        ValueError: empty layout, a bad entry, an object outside the workspace or below the table, two
            interpenetrating objects, or touching objects that do not rest where they are placed.
    """
    from maniskill_pnp.scenes.layout_check import check_layout

    if not layout:
        raise ValueError("a layout needs at least one (ObjectSpec, pose) entry")
    out = []
    for i, entry in enumerate(layout):
        if not isinstance(entry, (tuple, list)) or len(entry) != 2 or not isinstance(entry[0], ObjectSpec):
            raise ValueError(f"layout entry {i} must be (ObjectSpec, pose), got {entry!r}")
        out.append((entry[0], as_pose(entry[1])))
    return check_layout(out, workspace).layout


def object_status(positions: np.ndarray, workspace: WorkspaceSpec, bin_margin: float = 0.01) -> list[str]:
    """Where each object (world positions, N×3) is: ``"workspace"``, ``"bin"`` or ``"lost"``.

    An object is in the workspace when it lies over the heightmap square no lower than 5 cm below the table
    (objects that fell off the table are lost) and no higher than ``max_height`` (a held object counts as there).
    """
    region = workspace.bin.region()
    b = workspace.bounds
    out = []
    for p in np.asarray(positions, dtype=np.float64).reshape(-1, 3):
        if region.contains(p, margin=bin_margin):
            out.append("bin")
        elif workspace.contains_xy(p[:2]) and workspace.table_z - 0.05 <= p[2] <= b[2, 1] + 0.2:
            out.append("workspace")
        else:
            out.append("lost")
    return out
