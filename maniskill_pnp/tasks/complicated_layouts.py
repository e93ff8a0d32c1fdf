"""Hand-designed "complicated" clutters of thesis chapter 6: 3–7 objects pressed together in locking arrangements.

In each layout the objects touch (:data:`GAP` apart) so that a top-down grasp at an object's centre finds one
finger landing on a neighbour, or the object is wider than the open jaws (8 cm) across its free direction: no
grasp fits until a slide has pushed something apart. No object stands taller than its neighbours (one that did
could be gripped by its part above them). The layouts are built with the explicit-layout API of
:mod:`maniskill_pnp.tasks.clutter` (a list of ``(ObjectSpec, pose)``) and sit at the workspace centre;
:func:`complicated_layouts` places them for a given :class:`WorkspaceSpec` and the tests validate every one.

========================  ==================================================================================
name                      arrangement
========================  ==================================================================================
row_of_three              three 4×9 cm bars side by side (9 cm is too wide for the jaws)
rotated_sandwich          a thin slab between two bars, the row turned 30° from world x
square_of_four            four 4.5 cm cubes in a 2×2 square
sandwich                  a thin slab between two bars
wall_with_cubes           an 11 cm wall with a pair of cubes pressed against each long side
block_of_six              six bars in two rows of three
ringed_cylinder           a cylinder between two bars, capped by a small cube on each open side
capped_row                a row of three bars, a wall along one side and a pair of cubes along the other
========================  ==================================================================================
"""

from __future__ import annotations

import numpy as np
import sapien

from maniskill_pnp.tasks.clutter import yaw_quat
from maniskill_pnp.tasks.objects import ObjectSpec
from maniskill_pnp.tasks.workspace import WorkspaceSpec

#: Space left between objects pressed together (m): they touch for the gripper, not for the physics solver.
GAP = 0.001

BAR = ObjectSpec("cuboid", (0.02, 0.045, 0.02), (0.15, 0.35, 0.85))
SLAB = ObjectSpec("cuboid", (0.0125, 0.045, 0.02), (0.95, 0.75, 0.1))
WALL = ObjectSpec("cuboid", (0.02, 0.055, 0.02), (0.2, 0.6, 0.25))
CUBE = ObjectSpec("cuboid", (0.0225, 0.0225, 0.02), (0.85, 0.2, 0.15))
SMALL_CUBE = ObjectSpec("cuboid", (0.015, 0.015, 0.015), (0.6, 0.25, 0.7))
CYLINDER = ObjectSpec("cylinder", (0.022, 0.02), (0.95, 0.5, 0.1))

# Entries (spec, x, y, yaw) relative to the workspace centre, objects resting on the table.
_Entry = tuple[ObjectSpec, float, float, float]


def _row(specs: list[ObjectSpec], yaw: float = 0.0, origin: tuple[float, float] = (0.0, 0.0)) -> list[_Entry]:
    """``specs`` side by side along the direction ``yaw`` (each object's x axis along the row), centred on ``origin``."""
    widths = np.array([s.extents[0] for s in specs])
    length = widths.sum() + GAP * (len(specs) - 1)
    along = -length / 2 + np.cumsum(widths + GAP) - widths / 2 - GAP
    u = np.array([np.cos(yaw), np.sin(yaw)])
    return [(s, origin[0] + a * u[0], origin[1] + a * u[1], yaw) for s, a in zip(specs, along)]


def _designs() -> dict[str, list[_Entry]]:
    bar_y = BAR.extents[1] / 2
    cube_pair_x = CUBE.extents[0] / 2 + GAP / 2
    wall_side = WALL.extents[0] / 2 + GAP + CUBE.extents[0] / 2
    cyl_r = CYLINDER.size[0]
    return {
        "row_of_three": _row([BAR, BAR, BAR]),
        "rotated_sandwich": _row([BAR, SLAB, BAR], yaw=np.pi / 6),
        "square_of_four": _row([CUBE, CUBE], origin=(0.0, -(CUBE.extents[1] + GAP) / 2))
        + _row([CUBE, CUBE], origin=(0.0, (CUBE.extents[1] + GAP) / 2)),
        "sandwich": _row([BAR, SLAB, BAR]),
        "wall_with_cubes": [(WALL, 0.0, 0.0, 0.0)]
        + [(CUBE, sx * wall_side, sy * cube_pair_x, 0.0) for sx in (-1, 1) for sy in (-1, 1)],
        "block_of_six": _row([BAR] * 3, origin=(0.0, -(bar_y + GAP / 2))) + _row([BAR] * 3, origin=(0.0, bar_y + GAP / 2)),
        "ringed_cylinder": [(CYLINDER, 0.0, 0.0, 0.0)]
        + [(BAR, sx * (cyl_r + GAP + BAR.extents[0] / 2), 0.0, 0.0) for sx in (-1, 1)]
        + [(SMALL_CUBE, 0.0, sy * (cyl_r + GAP + SMALL_CUBE.extents[1] / 2), 0.0) for sy in (-1, 1)],
        "capped_row": _row([BAR] * 3)
        + [(WALL, 0.0, bar_y + GAP + WALL.extents[0] / 2, np.pi / 2)]
        + _row([CUBE, CUBE], origin=(0.0, -(bar_y + GAP + CUBE.extents[1] / 2))),
    }


#: Names of the complicated layouts, in the order of their index.
COMPLICATED_LAYOUT_NAMES = tuple(_designs())


def complicated_layouts(workspace: WorkspaceSpec) -> list[list[tuple[ObjectSpec, sapien.Pose]]]:
    """Every complicated layout as a list of ``(ObjectSpec, pose)`` at ``workspace``'s centre, on its table.

    Not validated here: pass each through :func:`~maniskill_pnp.tasks.clutter.validate_layout`.
    """
    cx, cy = workspace.center
    return [
        [(s, sapien.Pose(p=[cx + x, cy + y, workspace.table_z + s.extents[2] / 2], q=yaw_quat(yaw))) for s, x, y, yaw in entries]
        for entries in _designs().values()
    ]
