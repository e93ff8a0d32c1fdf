"""Hand-designed "complicated" clutters of thesis chapter 6: 3–7 objects pressed together in locking arrangements.

In each layout the objects touch (1 mm apart: they touch for the gripper, not for the physics solver) so that a
top-down grasp at an object's centre finds one finger landing on a neighbour, or the object is wider than the open
jaws (8 cm) across its free direction: no grasp fits until a slide has pushed something apart. No object stands
taller than its neighbours (one that did could be gripped by its part above them). The layouts ship with the package
as scene files (:mod:`~maniskill_pnp.scenes.scene_file`, workspace frame: centred on the workspace, on its table) in
``scenes/complicated/<name>.yaml``; :func:`complicated_layouts` loads them for a given :class:`WorkspaceSpec`.

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

from pathlib import Path

import sapien

from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.scenes.scene_file import load_scene
from maniskill_pnp.cell.workspace import WorkspaceSpec

#: Names of the complicated layouts, in the order of their index.
COMPLICATED_LAYOUT_NAMES = ("row_of_three", "rotated_sandwich", "square_of_four", "sandwich", "wall_with_cubes",
                            "block_of_six", "ringed_cylinder", "capped_row")
#: Folder of their scene files.
COMPLICATED_SCENES_DIR = Path(__file__).resolve().parent / "complicated"


def complicated_layout_files() -> list[Path]:
    """The scene file of every complicated layout, in the order of :data:`COMPLICATED_LAYOUT_NAMES` (e.g. for
    ``gym.make(..., layout_file=...)``)."""
    return [COMPLICATED_SCENES_DIR / f"{name}.yaml" for name in COMPLICATED_LAYOUT_NAMES]


def complicated_layouts(workspace: WorkspaceSpec) -> list[list[tuple[ObjectSpec, sapien.Pose]]]:
    """Every complicated layout as a list of ``(ObjectSpec, pose)`` at ``workspace``'s centre, on its table, read
    from its scene file and validated (:func:`~maniskill_pnp.scenes.scene_file.load_scene`)."""
    return [load_scene(path, workspace) for path in complicated_layout_files()]
