"""The heightmap grasp-fit test and its graspable regions (the ``fit_gain`` slide reward's measure)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from maniskill_pnp.agents.pixel.mask import HeightmapActionMask
from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.heightmap_fit import HeightmapGraspFit, graspable_regions

WS = WorkspaceSpec(heightmap_size=64, num_rotations=8)


def cubes(*centres, side_px: int = 10, height: float = 0.04) -> torch.Tensor:
    """A 64 px heightmap with square blocks of ``side_px`` pixels (2 mm each) at the (row, col) ``centres``."""
    h = torch.zeros(1, 64, 64)
    for r, c in centres:
        h[0, r - side_px // 2: r + side_px // 2, c - side_px // 2: c + side_px // 2] = height
    return h


def regions(height: torch.Tensor) -> int:
    fit = HeightmapGraspFit.for_workspace(WS)
    occupied = height > 0.01
    return graspable_regions(fit(height, occupied)[0].any(dim=0), occupied[0])


def test_a_free_cube_is_one_region_two_apart_are_two_and_four_pressed_together_none():
    assert regions(cubes()) == 0
    assert regions(cubes((32, 32))) == 1
    assert regions(cubes((32, 16), (32, 48))) == 2
    # two 2 cm cubes pressed together are one 2 x 4 cm block, taken across its 2 cm: one region
    assert regions(cubes((32, 27), (32, 37))) == 1
    # four 5 cm cubes pressed into a 10 cm square, wider than the open jaws every way: none
    assert regions(cubes((20, 20), (20, 45), (45, 20), (45, 45), side_px=25)) == 0


def test_the_masks_grasp_fit_is_this_test():
    mask = HeightmapActionMask.for_workspace(("grasp",), WS, grasp_fit=True)
    fit = HeightmapGraspFit(WS.num_rotations, mask.pixel_size, mask.grasp_depth, mask.min_tip_height, mask.fit_tolerance)
    h = cubes((20, 20), (40, 30), (41, 41))
    assert torch.equal(mask.grasp_fits(h[:, :, :], h > 0.01), fit(h, h > 0.01))
    assert fit == HeightmapGraspFit.for_workspace(WS)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="num_rotations"):
        HeightmapGraspFit(0)
    with pytest.raises(ValueError, match="pixel_size"):
        HeightmapGraspFit(8, pixel_size=0.0)
    with pytest.raises(ValueError, match=r"\(H, W\) maps of one shape"):
        graspable_regions(np.zeros((2, 3, 3), dtype=bool), np.zeros((2, 3, 3), dtype=bool))
