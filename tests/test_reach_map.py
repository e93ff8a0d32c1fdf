"""The reach map (maniskill_pnp.cell.reach_map): the pixels it leaves out are those the planner's own IK cannot reach,
and the agents' mask leaves out the grasps and slides there."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.factories import make_action_mask
from maniskill_pnp.cell.reach_map import LINES, ReachMap, ReachTable, table_key, SHIPPED_DIR
from maniskill_pnp.cell.workspace import DEFAULT_ROBOT_BASE, WorkspaceSpec
from maniskill_pnp.planning.collision import CollisionWorld
from maniskill_pnp.planning.kinematics import Kinematics
from maniskill_pnp.planning.primitives import MotionPrimitives, grasp_pose, grasp_twins
from maniskill_pnp.planning.robot import panda_spec

WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=16)


@pytest.fixture(scope="module")
def reach() -> ReachMap:
    return ReachMap.of(WS, DEFAULT_ROBOT_BASE, progress=False)


def test_the_clutter_cells_table_ships_and_serves_every_workspace_on_its_table(reach):
    tip = WS.table_z + WS.min_tip_height - DEFAULT_ROBOT_BASE[2]
    assert (SHIPPED_DIR / f"{table_key(tip)}.npy").exists()
    moved = WorkspaceSpec(center=(-0.1, 0.05), heightmap_size=32, pixel_size=0.01, num_rotations=8)
    assert ReachMap.of(moved, DEFAULT_ROBOT_BASE, progress=False).table.reachable is not None  # read, not computed
    pixels = reach.pixels()
    assert pixels.shape == (16, 64, 64)
    assert 0.95 < pixels.mean() < 1.0  # the far corner is out of reach
    assert pixels[:, 24:40, 24:40].all()  # the middle is reached at every rotation
    assert not pixels[:, 0, 63].any()  # the corner farthest from the base (x max, y min) at none
    assert len(reach.share_per_line()) == LINES


def test_pixels_left_out_are_those_the_planners_ik_cannot_reach(reach):
    """Pixels the map leaves out for every rotation, away from the border of the reach (their neighbours left out
    too): no valid IK solution reaches the grasp and its pre-grasp (12 random restarts, both twins) at any jaw line;
    pixels it keeps in the middle have one."""
    kin = Kinematics(CollisionWorld(panda_spec(), base_pose=np.array([*DEFAULT_ROBOT_BASE, 1.0, 0.0, 0.0, 0.0])))
    arm = panda_spec()
    kept = np.pad(reach.any_line(), 1, constant_values=False)
    near_kept = np.zeros_like(kept)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near_kept |= np.roll(np.roll(kept, dr, axis=0), dc, axis=1)
    out = np.argwhere(~near_kept[1:-1, 1:-1])
    assert len(out)
    rng = np.random.default_rng(0)
    tip = WS.table_z + WS.min_tip_height
    for row, col in out[rng.choice(len(out), size=min(6, len(out)), replace=False)]:
        xyz = WS.pixel_to_world(int(row), int(col), 0.0)
        for line in range(0, LINES, 2):
            above = grasp_pose(np.array([xyz[0], xyz[1], tip + MotionPrimitives.PREGRASP_HEIGHT]), np.pi * line / LINES)
            grasp = grasp_pose(np.array([xyz[0], xyz[1], tip]), np.pi * line / LINES)
            ik = kin.ik_any(grasp_twins(above), arm.home)
            assert not (ik.ok and kin.ik_any(grasp_twins(grasp), ik.q).ok), (row, col, line)
    for row, col in ((32, 32), (20, 40), (45, 10)):
        xyz = WS.pixel_to_world(row, col, 0.0)
        assert kin.ik_any(grasp_twins(grasp_pose(np.array([xyz[0], xyz[1], tip + 0.1]), 0.0)), arm.home).ok


def test_the_agents_mask_leaves_out_grasps_and_slides_out_of_reach(reach):
    cfg = ClutterConfig.from_preset("gs-cpu-equi")
    mask = make_action_mask(cfg)
    height = torch.zeros(1, 64, 64)
    height[0, 0:6, 54:64] = 0.03  # material over the unreachable corner and the reachable pixels beside it
    height[0, 30:34, 30:34] = 0.03
    maps = mask.pixel_masks(height)[0]
    pixels = torch.from_numpy(reach.pixels())
    assert not (maps[0] & ~pixels).any() and maps[0, :, 0:6, 54:64].any() and maps[0, :, 30:34, 30:34].all()
    unmasked = make_action_mask(ClutterConfig.from_preset("gs-cpu-equi", mask_reach=False)).pixel_masks(height)[0]
    assert unmasked[0, :, 0, 63].all() and not maps[0, :, 0, 63].any()
    assert not (maps[1:] & ~pixels[None]).any()  # a slide starts where the arm reaches
    assert (unmasked[1:] & ~maps[1:]).any()


def test_an_unreadable_cache_file_is_computed_again(tmp_path, monkeypatch):
    """A table that is neither shipped nor cached is computed only on request (the scene checks and the mask then skip
    the reach); an unreadable cache file is not trusted (here a tiny stand-in computation)."""
    import maniskill_pnp.cell.reach_map as rm

    monkeypatch.setenv("MANISKILL_PNP_CACHE", str(tmp_path))
    tip = 0.5  # no shipped table at this height
    key = table_key(tip)
    (tmp_path / "reach").mkdir()
    (tmp_path / "reach" / f"{key}.npy").write_bytes(b"not a numpy file")
    calls = []
    monkeypatch.setattr(rm, "compute_table", lambda t, arm, progress: calls.append(t) or np.zeros((LINES, 3, 5), bool))
    assert ReachTable.of(tip, progress=False) is None and calls == []  # not computed unasked
    table = ReachTable.of(tip, compute=True, progress=False)
    assert calls == [tip] and table.reachable.shape == (LINES, 3, 5)
    assert ReachTable.of(tip, progress=False).reachable.shape == (LINES, 3, 5) and calls == [tip]  # cached now
