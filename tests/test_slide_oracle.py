"""The oracles that see the objects' shapes (maniskill_pnp.agents.scripted.slide_oracle): on a locked row the grasp-only
oracle has no feasible grasp, the slide-then-grasp oracle slides the end bar free, the task's "unlock" judgement
agrees, and the next choice is a feasible grasp that succeeds; guarded at 20 N throughout."""

from __future__ import annotations

import gymnasium as gym
import pytest

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.bench.clutter_oracle import ClutterOracleBenchConfig, run
from maniskill_pnp.scenes.complicated_layouts import COMPLICATED_LAYOUT_NAMES
from maniskill_pnp.agents.scripted.slide_oracle import FeasibleGraspOracle
from maniskill_pnp.cell.workspace import WorkspaceSpec

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=16)


@pytest.fixture(scope="module")
def row():
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout="complicated", reward_scheme="unlock", guard_force=20.0,
                 complicated_index=COMPLICATED_LAYOUT_NAMES.index("row_of_three"), **CPU)
    yield e
    e.close()


def test_grasp_only_oracle_falls_back_on_a_locked_row(row):
    obs, _ = row.reset(seed=0)
    oracle = FeasibleGraspOracle(row.unwrapped, slides=False)
    oracle(obs)
    assert oracle.last.kind == "fallback_grasp"


def test_slide_then_grasp_oracle_frees_the_row_and_grasps(row):
    obs, _ = row.reset(seed=0)
    oracle = FeasibleGraspOracle(row.unwrapped, slides=True)
    action = oracle(obs)
    assert oracle.last.kind == "slide" and oracle.last.predicted_unlocked >= 1
    obs, reward, _, _, info = row.step(action)
    assert info["slide_changed"] and info["slide_unlocked"] >= 1 and reward.item() == 0.5, info
    action = oracle(obs)
    assert oracle.last.kind == "grasp"
    obs, _, _, _, info = row.step(action)
    assert info["grasp_success"], info


def test_grasp_fit_mask_sees_the_locked_row_and_the_bar_the_slide_freed(row):
    """The heightmap's grasp-fit mask agrees with the shape check: no grasp fits over the locked row; after the
    oracle's slide, some grasps fit (on the freed bar)."""
    import torch

    from maniskill_pnp.agents.pixel.mask import HeightmapActionMask

    mask = HeightmapActionMask.for_workspace(("grasp",), WS, grasp_fit=True)

    def fitting(obs):
        height = torch.as_tensor(obs["depth_heightmap"]).reshape(1, WS.heightmap_size, WS.heightmap_size)
        return int(mask.grasp_fits(height, height > mask.min_height).sum())

    obs, _ = row.reset(seed=0)
    assert fitting(obs) == 0
    oracle = FeasibleGraspOracle(row.unwrapped, slides=True)
    obs, _, _, _, info = row.step(oracle(obs))
    assert info["slide_unlocked"] >= 1 and fitting(obs) > 0


def test_grasp_fit_mask_at_the_tasks_default_size_sees_the_locked_row():
    """The same judgement on the task's own 224 px heightmap (2 mm pixels), as a user who turns the mask on at the
    default size gets it: no grasp fits over the locked row, while the bare slide starts around it stay allowed."""
    import torch

    from maniskill_pnp.agents.pixel.mask import HeightmapActionMask

    env = gym.make("ClutterGraspSlide-v1", layout="complicated", guard_force=20.0,
                   complicated_index=COMPLICATED_LAYOUT_NAMES.index("row_of_three"), **CPU)
    try:
        obs, _ = env.reset(seed=0)
        ws = env.unwrapped.workspace
        assert ws.heightmap_size == 224
        mask = HeightmapActionMask.for_workspace(("grasp", "left_slide", "right_slide"), ws, grasp_fit=True)
        height = torch.as_tensor(obs["depth_heightmap"]).reshape(1, 224, 224)
        maps = mask.pixel_masks(height)[0]
        assert (height > mask.min_height).sum() > 1000 and not maps[0].any() and maps[1:].any()
    finally:
        env.close()


def test_oracle_bench_names_bad_options():
    with pytest.raises(ValueError, match="unknown oracle"):
        run(ClutterOracleBenchConfig(oracle="psychic"))
    grasp_only = gym.make("ClutterGrasp-v1", workspace=WS, num_objects=1, **CPU)
    try:
        with pytest.raises(ValueError, match="primitives"):
            FeasibleGraspOracle(grasp_only.unwrapped, slides=True)
    finally:
        grasp_only.close()
