"""Where the arm can act: per heightmap pixel and rotation, whether its IK reaches a top-down grasp there.

The far corners of the workspace lie at the edge of the Panda's reach, and there a grasp's pre-grasp pose (or the
grasp itself, at the table) has no IK solution: the primitive fails with "no IK solution reaches the pose" and,
the scene unchanged, a greedy agent would try it again. :class:`ReachMap` answers, with the planner's own IK
(:class:`~maniskill_pnp.planning.kinematics.Kinematics`: joint limits, self-collision, the same random restarts),
which top-down grasps the arm reaches:

* a :class:`ReachTable` samples the table around the robot, in the robot's frame: a square grid of :data:`SAMPLE_STEP`
  over the half disc of :data:`TABLE_RADIUS` in front of the base (farther out nothing is reached), for
  :data:`LINES` jaw lines (a rotation and its 180° twin are one grasp for parallel jaws);
* at each sample, the grasp at its lowest (the fingertips at the workspace's ``min_tip_height`` above the table) and
  its pre-grasp 10 cm above: reachable when both have a valid IK solution (each solve seeded from the last sample's,
  with random restarts where that fails, as a primitive's own IK does);
* a workspace's :class:`ReachMap` reads it per pixel and rotation, on the rotation's nearest jaw line: reached where
  the four samples around the pixel's centre, weighted bilinearly, are reached by half or more (the nearest samples
  decide; near the border of the reach a pixel may come out either way, within about a sample step).

The table depends only on the fingertips' height relative to the base, so one serves every workspace on the same
table. The clutter tasks' cell's ships with the package (``maniskill_pnp/cell/reach/``, written by ``python -m
maniskill_pnp.cell.reach_map``). Another table height has none until ``python -m maniskill_pnp.cell.reach_map
--tip-height H`` computes it (about 10 minutes on one core) into the cache (``cache_dir("reach")``); until then the
reach is not checked there, and a warning says so once. A slide reaches where its start and its end do (the closed fingers near the table,
on the same jaw line).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from maniskill_pnp.cache import cache_dir
from maniskill_pnp.cell.workspace import DEFAULT_ROBOT_BASE, WorkspaceSpec
from maniskill_pnp.planning.collision import CollisionWorld
from maniskill_pnp.planning.kinematics import Kinematics
from maniskill_pnp.planning.primitives import MotionPrimitives, grasp_pose, grasp_twins
from maniskill_pnp.planning.robot import ArmSpec, panda_spec

logger = logging.getLogger(__name__)

#: Spacing (m) of the sampled grasp positions.
SAMPLE_STEP = 0.015
#: Jaw lines sampled, evenly over 180 degrees.
LINES = 8
#: The sampled half disc's radius (m) about the base: the Panda reaches no top-down grasp beyond about 0.86 m.
TABLE_RADIUS = 0.9
#: Bumped whenever what the table holds changes, so old cache files are not read.
VERSION = 3
#: Tables shipped with the package (the clutter cell's), read before the cache.
SHIPPED_DIR = Path(__file__).resolve().parent / "reach"


@dataclass(frozen=True)
class ReachTable:
    """Which top-down grasps an arm reaches around its base, at one fingertip height.

    Attributes:
        reachable: ``bool (LINES, N, 2N - 1)``: jaw line ``l`` (yaw ``l * 180° / LINES``), sample row ``i`` (base-frame x
            ``i * SAMPLE_STEP``, in front of the base) and column ``j`` (base-frame y ``(j - N + 1) * SAMPLE_STEP``).
    """

    reachable: np.ndarray

    @classmethod
    def of(cls, tip_height: float, arm: ArmSpec | None = None, compute: bool = False,
           progress: bool = True) -> "ReachTable | None":
        """The table of fingertips ``tip_height`` (m) above the base, shipped or cached; without one, computed and cached
        with ``compute`` (minutes), else None (and a warning naming the command that computes it)."""
        arm = arm or panda_spec()
        key = table_key(tip_height, arm)
        path = cache_dir("reach") / f"{key}.npy"
        for known in (SHIPPED_DIR / f"{key}.npy", path):
            if known.exists():
                try:
                    return cls(np.load(known))
                except (OSError, ValueError):
                    pass  # an unreadable file is computed again
        if not compute:
            _warn_missing(tip_height)
            return None
        reachable = compute_table(tip_height, arm, progress=progress)
        tmp = path.with_name(f"{key}.{np.random.default_rng().integers(1 << 30)}.tmp.npy")
        np.save(tmp, reachable)
        tmp.replace(path)  # atomic: parallel workers may compute the same table
        return cls(reachable)

    def at(self, xy: np.ndarray) -> np.ndarray:
        """``bool (LINES, *S)``: per jaw line, whether the arm reaches base-frame points ``xy`` ``(*S, 2)``: the four
        samples around each point, weighted bilinearly, are reached by half or more (False off the table)."""
        n = self.reachable.shape[1]
        fx = np.asarray(xy[..., 0]) / SAMPLE_STEP
        fy = np.asarray(xy[..., 1]) / SAMPLE_STEP + (n - 1)
        i0, j0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
        wx, wy = fx - i0, fy - j0
        share = np.zeros((LINES, *fx.shape))
        for di, w_i in ((0, 1 - wx), (1, wx)):
            for dj, w_j in ((0, 1 - wy), (1, wy)):
                i, j = i0 + di, j0 + dj
                inside = (i >= 0) & (i < n) & (j >= 0) & (j < 2 * n - 1)
                share += w_i * w_j * (self.reachable[:, np.clip(i, 0, n - 1), np.clip(j, 0, 2 * n - 2)] & inside)
        return share >= 0.5


@dataclass(frozen=True)
class ReachMap:
    """The :class:`ReachTable` of an arm read over one workspace's heightmap.

    Attributes:
        workspace: The workspace.
        base: The robot base position (world, m); its yaw is 0 (facing +x), as in the clutter tasks.
        table: The arm's reach table at the workspace's fingertip height.
    """

    workspace: WorkspaceSpec
    base: tuple[float, float, float]
    table: ReachTable

    @classmethod
    def of(cls, workspace: WorkspaceSpec, base: tuple[float, float, float] = DEFAULT_ROBOT_BASE,
           arm: ArmSpec | None = None, compute: bool = False, progress: bool = True) -> "ReachMap | None":
        """The map of ``workspace`` for an arm standing at ``base``; None where its table is neither shipped nor
        cached and ``compute`` is off (see :meth:`ReachTable.of`)."""
        tip = workspace.table_z + workspace.min_tip_height - float(base[2])
        table = ReachTable.of(tip, arm, compute=compute, progress=progress)
        return None if table is None else cls(workspace, tuple(float(v) for v in base), table)

    def pixels(self, num_rotations: int | None = None, size: int | None = None) -> np.ndarray:
        """``bool (R, H, W)``: whether a grasp at each rotation and heightmap pixel is reachable; ``size`` pixels per
        side (default: the workspace's heightmap), ``num_rotations`` rotations (default: the workspace's; each reads its
        nearest jaw line)."""
        ws = self.workspace
        r = ws.num_rotations if num_rotations is None else num_rotations
        n = ws.heightmap_size if size is None else size
        centres = (np.arange(n) + 0.5) * (ws.side / n)
        x = ws.bounds[0, 0] + centres[None, :] - self.base[0]  # (1, W): columns follow world x
        y = ws.bounds[1, 0] + centres[:, None] - self.base[1]  # (H, 1): rows world y
        near = self.table.at(np.stack(np.broadcast_arrays(x, y), axis=-1))  # (LINES, H, W)
        line = np.round(np.arange(r) * (2 * LINES) / r).astype(np.int64) % LINES
        return near[line]

    def any_line(self, size: int | None = None) -> np.ndarray:
        """``bool (H, W)``: the heightmap pixels where some grasp is reachable."""
        return self.pixels(num_rotations=2 * LINES, size=size).any(axis=0)

    def share_per_line(self) -> list[tuple[float, float]]:
        """``(yaw in degrees, share of the heightmap's pixels reached)`` per jaw line."""
        cells = self.pixels(num_rotations=2 * LINES)[:LINES]
        return [(180.0 * k / LINES, float(cells[k].mean())) for k in range(LINES)]


_warned: set[float] = set()


def _warn_missing(tip_height: float) -> None:
    if round(tip_height, 6) in _warned:
        return
    _warned.add(round(tip_height, 6))
    logger.warning("no reach table for fingertips %.4f m above the robot base (a workspace on another table): actions "
                   "and scenes are not checked for reach; `python -m maniskill_pnp.cell.reach_map --tip-height %.4f` "
                   "computes and caches it (a few minutes)", tip_height, tip_height)


def compute_table(tip_height: float, arm: ArmSpec, progress: bool = True) -> np.ndarray:
    """The :attr:`ReachTable.reachable` array of fingertips ``tip_height`` above the base (see the module docstring)."""
    from maniskill_pnp.progress import progress_bar

    world = CollisionWorld(arm)  # base frame
    kin = Kinematics(world, seed=0)
    n = int(math.ceil(TABLE_RADIUS / SAMPLE_STEP)) + 1
    xs, ys = SAMPLE_STEP * np.arange(n), SAMPLE_STEP * np.arange(-(n - 1), n)
    out = np.zeros((LINES, n, 2 * n - 1), dtype=bool)
    for k in progress_bar(range(LINES), desc="reach table", unit="jaw line", disable=not progress):
        yaw = math.pi * k / LINES
        seed = arm.home.copy()
        for i in range(n):
            cols = range(2 * n - 1) if i % 2 == 0 else range(2 * n - 2, -1, -1)  # serpentine: seed from the last
            for j in cols:
                if math.hypot(xs[i], ys[j]) > TABLE_RADIUS:
                    continue
                grasp = grasp_pose(np.array([xs[i], ys[j], tip_height]), yaw)
                above = grasp_pose(np.array([xs[i], ys[j], tip_height + MotionPrimitives.PREGRASP_HEIGHT]), yaw)
                ik = kin.ik_any(grasp_twins(above), seed)
                if ik.ok and kin.ik_any(grasp_twins(grasp), ik.q).ok:
                    out[k, i, j] = True
                    seed = ik.q
    return out


def table_key(tip_height: float, arm: ArmSpec | None = None) -> str:
    """The file stem a table of fingertips ``tip_height`` above the base is stored under."""
    arm = arm or panda_spec()
    what = dict(version=VERSION, step=SAMPLE_STEP, lines=LINES, radius=TABLE_RADIUS, tip=round(float(tip_height), 6),
                urdf=Path(arm.urdf).name, urdf_bytes=Path(arm.urdf).stat().st_size, tcp=arm.tcp_link,
                lower=np.asarray(arm.lower).round(6).tolist(), upper=np.asarray(arm.upper).round(6).tolist())
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:20]


def main(argv: list[str] | None = None) -> None:
    """Compute a reach table: the clutter cell's into the package, or, with ``--tip-height``, another into the cache."""
    import argparse

    parser = argparse.ArgumentParser(description="compute the reach table of the clutter cell's arm (into the package), "
                                                 "or of fingertips at another height above its base (into the cache)")
    parser.add_argument("--tip-height", type=float, default=None,
                        help="fingertips' height above the robot base (m); default: the clutter cell's, shipped")
    args = parser.parse_args(argv)
    if args.tip_height is not None:
        table = ReachTable.of(args.tip_height, compute=True)
        print(f"reach table at {args.tip_height} m: {table.reachable.mean():.1%} of the samples reached (cached)")
        return
    ws = WorkspaceSpec()
    tip = ws.table_z + ws.min_tip_height - DEFAULT_ROBOT_BASE[2]
    SHIPPED_DIR.mkdir(exist_ok=True)
    path = SHIPPED_DIR / f"{table_key(tip)}.npy"
    np.save(path, compute_table(tip, panda_spec()))
    print(f"{path}: {np.load(path).mean():.1%} of the samples reached")


__all__ = ["LINES", "SAMPLE_STEP", "SHIPPED_DIR", "ReachMap", "ReachTable", "compute_table", "table_key"]


if __name__ == "__main__":
    main()
