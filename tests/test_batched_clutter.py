"""The vision tasks' batched path: per-env actions and infos, the one-env CPU run through it, and (GPU) several
envs drawing their own clutter and executing their primitives in lockstep."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.agents.scripted.clutter_oracle import HeightmapGraspOracle
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.tasks.primitive_env import batch_infos, parse_discrete_actions
from maniskill_pnp.cell.workspace import WorkspaceSpec

WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=4)
CUBE = ObjectSpec("cuboid", (0.02, 0.02, 0.02))


def test_actions_are_parsed_per_env_and_a_bad_one_is_named():
    assert parse_discrete_actions(5, 1, 10, "0..9") == [5]
    assert parse_discrete_actions(torch.tensor([1, 0, 9]), 3, 10, "0..9") == [1, 0, 9]
    assert parse_discrete_actions(np.array([[2], [3]]), 2, 10, "0..9") == [2, 3]
    with pytest.raises(ValueError, match=r"one index per env, shape \(3,\)"):
        parse_discrete_actions(np.array([1, 2]), 3, 10, "0..9")
    with pytest.raises(ValueError, match="env 1: action 10 out of range"):
        parse_discrete_actions(np.array([1, 10, 2]), 3, 10, "0..9")
    with pytest.raises(ValueError, match="integer indices.*dtype float64"):
        parse_discrete_actions(np.array([1.0, 2.0, 0.5]), 3, 10, "0..9")


def test_infos_are_tensors_for_any_number_of_envs_and_text_is_listed_for_several():
    one = batch_infos([dict(success=False, num_actions=2, stage="done", mask=np.array([True, False]))], torch.device("cpu"))
    assert torch.equal(one["num_actions"], torch.tensor([2])) and torch.equal(one["success"], torch.tensor([False]))
    assert one["stage"] == "done" and torch.equal(one["mask"], torch.tensor([[True, False]]))
    many = batch_infos([dict(success=s, num_actions=k, stage=st, pixel=(0, k, k))
                        for s, k, st in ((True, 1, "done"), (False, 4, "grasp_check"))], torch.device("cpu"))
    assert torch.equal(many["success"], torch.tensor([True, False]))
    assert torch.equal(many["num_actions"], torch.tensor([1, 4]))
    assert many["stage"] == ["done", "grasp_check"] and many["pixel"] == [(0, 1, 1), (0, 4, 4)]


def test_one_cpu_env_runs_the_batched_path():
    """On the CPU the task is the batched code with one env: one primitive program per env, driven by one shared
    lockstep executor; per-env state is indexed by env, and a (1,) action array equals the plain int."""
    cx, cy = WS.center
    env = gym.make("ClutterGrasp-v1", workspace=WS, layout=[(CUBE, (cx, cy, 0.02))], sim_backend="physx_cpu",
                   render_backend="cpu")
    base = env.unwrapped
    obs, info = env.reset(seed=0)
    assert len(base.prims) == 1 and base.prims[0].env_idx == 0 and base.prims[0].executor.lockstep.num_envs == 1
    assert base.clutter.active == [[base.clutter.names[0]]] and base.settle_steps[0] >= base.SETTLE.min_steps
    assert info["settle_steps"] == base.settle_steps[0] and info["stage"] == "reset"
    action = HeightmapGraspOracle(WS)(obs["depth_heightmap"][0])
    _, reward, terminated, truncated, info = env.step(np.array([action]))
    assert reward.shape == terminated.shape == truncated.shape == (1,)
    assert info["grasp_success"].item() and info["place_success"].item() and terminated.item() and info["home_ok"].item()
    assert base.num_actions.tolist() == [1] and base.last[0]["action"] == action
    env.close()


@pytest.mark.gpu
def test_gpu_envs_draw_their_own_clutter_and_grasp_in_lockstep():
    n = 4
    env = gym.make("ClutterGraspSlide-v1", num_envs=n, workspace=WS, num_objects=(3, 5), sim_backend="physx_cuda",
                   render_backend="sapien_cuda")
    base = env.unwrapped
    obs, info = env.reset(seed=0)
    assert obs["color_heightmap"].shape == (n, 64, 64, 3) and obs["depth_heightmap"].shape == (n, 64, 64)
    assert len({tuple(names) for names in base.clutter.active}) > 1  # each env drew its own clutter
    assert info["num_objects"].tolist() == [len(names) for names in base.clutter.active]
    assert len(base.prims) == n and len({id(p.executor.lockstep) for p in base.prims}) == 1
    oracle = HeightmapGraspOracle(WS)
    actions = torch.tensor([oracle(obs["depth_heightmap"][e].cpu()) for e in range(n)])
    obs, reward, terminated, truncated, info = env.step(actions)
    assert reward.shape == terminated.shape == truncated.shape == (n,)
    assert info["num_actions"].tolist() == [1] * n and len(info["stage"]) == n
    assert int(info["grasp_success"].sum()) >= n // 2, info["reason"]
    placed = info["objects_in_bin"].tolist()
    assert placed == info["place_success"].long().tolist()
    kept = [a.pose.p.cpu().numpy() for a in base.clutter.active_actors[0]]
    env.reset(options=dict(env_idx=torch.tensor([1], device=base.device)))
    assert base.num_actions.tolist() == [1, 0, 1, 1]  # only env 1 started a new episode
    after = [a.pose.p.cpu().numpy() for a in base.clutter.active_actors[0]]
    assert all(np.abs(a[0] - k[0]).max() < 0.01 for a, k in zip(after, kept))  # env 0's objects stayed put
    env.close()


@pytest.mark.gpu
def test_gpu_torchrl_env_rolls_out_several_envs():
    from maniskill_pnp.torchrl_env import make_torchrl_env

    env = make_torchrl_env("ClutterGrasp-v1", num_envs=4, workspace=WS, num_objects=3)
    td = env.rollout(2, break_when_any_done=False)
    assert td.batch_size == torch.Size([4, 2])
    assert td["next", "reward"].shape == (4, 2, 1) and td["depth_heightmap"].shape == (4, 2, 64, 64)
    env.close()
