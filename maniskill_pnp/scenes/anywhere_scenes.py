"""Packed arrangements anywhere in the workspace: the ``anywhere`` test set.

The hard sets sit within 2 cm of the workspace centre, so a slide that pushes objects off the workspace never shows
in their figures. This set draws the same families (the hard set's rows and blocks,
:mod:`~maniskill_pnp.scenes.hard_scenes`, and the packed families of :mod:`~maniskill_pnp.scenes.packed_families`,
the held-out ones included) turned by any yaw and placed anywhere their objects lie wholly over the heightmap, where
the arm reaches each object's centre: the even-numbered scenes with their objects' edge within :data:`NEAR_EDGE`
(5 cm, less than a slide's 8 cm) of one of the workspace's edges, the odd-numbered ones anywhere. A draw is kept when it passes
:func:`~maniskill_pnp.scenes.layout_check.check_layout` (which also checks the edge and the reach) with at least half
of its objects locked (:func:`~maniskill_pnp.scenes.hard_scenes.first_qualifying_draw`).

``python -m maniskill_pnp.scenes.anywhere_scenes`` writes :data:`ANYWHERE_COUNT` scenes (seeds :data:`ANYWHERE_SEED`
+ i) to ``scenes/anywhere/anywhere_<ii>.yaml``: the ``anywhere`` scenario of ``eval-clutter``. No training draws them.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import sapien

from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes import hard_scenes, packed_families
from maniskill_pnp.scenes.hard_scenes import first_qualifying_draw, place_parts, write_scene_set
from maniskill_pnp.scenes.layout_check import shape_bounds, world_shapes
from maniskill_pnp.scenes.objects import ObjectSpec

ANYWHERE_DIR = Path(__file__).resolve().parent / "anywhere"
ANYWHERE_SEED = 69000
ANYWHERE_COUNT = 24
#: Every family of the hard sets and the packed sets.
FAMILIES = hard_scenes.FAMILIES + packed_families.FAMILIES
#: Draws tried per seed before giving up.
MAX_DRAWS = 200
#: The near-edge scenes end this close (m) to an edge, at most; every scene keeps at least EDGE_GAP from the edges.
NEAR_EDGE = 0.05
EDGE_GAP = 0.005


def anywhere_scene_files() -> list[Path]:
    """The ``anywhere`` scenario's scene files, in order."""
    return [ANYWHERE_DIR / f"anywhere_{i:02d}.yaml" for i in range(ANYWHERE_COUNT)]


def _parts(rng: np.random.Generator, family: str) -> list[tuple[ObjectSpec, float, float, float]]:
    if family in hard_scenes.FAMILIES:
        return [(spec, x, y, 0.0) for spec, x, y in hard_scenes.cells(rng, family)]
    return packed_families.family_parts(rng, family)


def _draw(rng: np.random.Generator, workspace: WorkspaceSpec, near_edge: bool
          ) -> tuple[str, list[tuple[ObjectSpec, sapien.Pose]]]:
    family = FAMILIES[int(rng.integers(len(FAMILIES)))]
    parts = _parts(rng, family)
    turn = rng.uniform(0.0, 2 * math.pi)
    middle = np.asarray(workspace.center, dtype=np.float64)
    lo, hi = footprint(place_parts(parts, turn, middle, workspace))
    lo, hi = lo - middle, hi - middle  # the arrangement's extent about its centre
    b = workspace.bounds[:2]
    low, high = b[:, 0] - lo + EDGE_GAP, b[:, 1] - hi - EDGE_GAP  # where its centre keeps it over the heightmap
    if (low >= high).any():
        raise ValueError(f"a {family} arrangement of {hi - lo} m does not fit the workspace")
    centre = rng.uniform(low, high)
    if near_edge:  # to within NEAR_EDGE of a random edge
        axis, side = int(rng.integers(2)), int(rng.integers(2))
        room = rng.uniform(EDGE_GAP, NEAR_EDGE)
        centre[axis] = b[axis, 1] - hi[axis] - room if side else b[axis, 0] - lo[axis] + room
    return family, place_parts(parts, turn, centre, workspace)


def footprint(layout) -> tuple[np.ndarray, np.ndarray]:
    """The xy bounds (lo, hi) of a layout's collision shapes."""
    bounds = [shape_bounds(world_shapes(spec, pose)) for spec, pose in layout]
    return np.min([lo[:2] for lo, _ in bounds], axis=0), np.max([hi[:2] for _, hi in bounds], axis=0)


def edge_distance(layout, workspace: WorkspaceSpec) -> float:
    """The smallest distance (m) from the layout's objects (their collision shapes) to the workspace's edge."""
    lo, hi = footprint(layout)
    b = workspace.bounds[:2]
    return float(min((lo - b[:, 0]).min(), (b[:, 1] - hi).min()))


def anywhere_layout(seed: int, workspace: WorkspaceSpec | None = None
                    ) -> tuple[str, list[tuple[ObjectSpec, sapien.Pose]], int]:
    """The ``anywhere`` arrangement of ``seed``: ``(family, layout, locked count)``; even seeds lie within
    :data:`NEAR_EDGE` of the workspace's edge.

    Raises:
        RuntimeError: no draw of :data:`MAX_DRAWS` qualified.
    """
    workspace = workspace or WorkspaceSpec()
    near_edge = seed % 2 == 0
    found = first_qualifying_draw(np.random.default_rng(seed), lambda rng: _draw(rng, workspace, near_edge), workspace,
                                  MAX_DRAWS, objects=(3, 8))
    if found is None:
        raise RuntimeError(f"no arrangement anywhere for seed {seed} in {MAX_DRAWS} draws")
    return found


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="write the anywhere test set's scene files")
    parser.add_argument("--out", type=Path, default=ANYWHERE_DIR, help="folder (default: the package's scene folder)")
    parser.add_argument("--count", type=int, default=ANYWHERE_COUNT)
    args = parser.parse_args(argv)
    write_scene_set(args.out, args.count, ANYWHERE_SEED, anywhere_layout, "anywhere", "anywhere",
                    "maniskill_pnp.scenes.anywhere_scenes")


__all__ = ["ANYWHERE_COUNT", "ANYWHERE_DIR", "ANYWHERE_SEED", "FAMILIES", "anywhere_layout", "anywhere_scene_files",
           "edge_distance"]


if __name__ == "__main__":
    main()
