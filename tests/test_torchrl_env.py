"""Tests for maniskill_pnp.torchrl_env (TorchRL wrapper around ManiSkill 3 envs)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from mani_skill.envs.sapien_env import BaseEnv
from tensordict import TensorDict
from torchrl.collectors import Collector, RandomPolicy
from torchrl.data import (
    Binary,
    Bounded,
    Categorical,
    Composite,
    MultiCategorical,
    Unbounded,
)
from torchrl.envs.utils import check_env_specs, step_mdp

from maniskill_pnp import make_torchrl_env
from maniskill_pnp.torchrl_env import ManiSkillTorchRLEnv, space_to_spec

MAX_STEPS = 50  # PickCube-v1's registered max_episode_steps


@pytest.fixture(scope="module")
def state_env():
    env = make_torchrl_env("PickCube-v1", obs_mode="state")
    yield env
    env.close()


@pytest.fixture(scope="module")
def rgbd_env():
    env = make_torchrl_env("PickCube-v1", obs_mode="rgbd")
    yield env
    env.close()


# --------------------------------------------------------------------------- #
# space -> spec conversion (no simulator needed)
# --------------------------------------------------------------------------- #
def test_discrete_space_to_categorical():
    spec = space_to_spec(gym.spaces.Discrete(5))
    assert isinstance(spec, Categorical)
    assert spec.n == 5 and spec.shape == torch.Size([]) and spec.dtype == torch.int64
    batched = spec.expand(3)
    assert batched.shape == torch.Size([3])
    assert batched.is_in(torch.tensor([0, 4, 2]))
    assert not batched.is_in(torch.tensor([0, 5, 2]))


def test_multidiscrete_space_to_multicategorical():
    space = gym.spaces.MultiDiscrete([3, 4])
    spec = space_to_spec(space)
    assert isinstance(spec, MultiCategorical)
    assert spec.shape == torch.Size([2])
    assert spec.nvec.tolist() == [3, 4]
    assert spec.is_in(torch.as_tensor(space.sample()))
    assert not spec.is_in(torch.tensor([3, 0]))


def test_nested_dict_space_to_composite():
    space = gym.spaces.Dict(
        {
            "agent": gym.spaces.Dict(
                {
                    "qpos": gym.spaces.Box(-np.inf, np.inf, (9,), np.float32),
                    "gripper": gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
                }
            ),
            "camera": gym.spaces.Dict(
                {"rgb": gym.spaces.Box(0, 255, (4, 5, 3), np.uint8)}
            ),
            "is_grasped": gym.spaces.Box(0, 1, (), bool),
            "contacts": gym.spaces.MultiBinary(3),
            "slot": gym.spaces.Discrete(4),
        }
    )
    spec = space_to_spec(space)
    assert isinstance(spec, Composite)
    assert set(spec.keys(True, True)) == {
        ("agent", "qpos"),
        ("agent", "gripper"),
        ("camera", "rgb"),
        "is_grasped",
        "contacts",
        "slot",
    }
    assert isinstance(spec["agent", "qpos"], Unbounded)
    assert isinstance(spec["agent", "gripper"], Bounded)
    assert isinstance(spec["camera", "rgb"], Bounded)
    assert spec["camera", "rgb"].dtype == torch.uint8
    assert spec["camera", "rgb"].shape == torch.Size([4, 5, 3])
    assert isinstance(spec["is_grasped"], Categorical)
    assert spec["is_grasped"].dtype == torch.bool
    assert isinstance(spec["contacts"], Binary)
    assert isinstance(spec["slot"], Categorical) and spec["slot"].n == 4

    # Batched like the wrapper does, and consistent with a gymnasium sample.
    batched = spec.expand(torch.Size([2]) + spec.shape)
    assert batched["camera", "rgb"].shape == torch.Size([2, 4, 5, 3])
    sample = TensorDict(space.sample(), batch_size=[]).expand(2)
    assert batched.is_in(sample)


def test_unsupported_spaces_raise_clear_errors():
    with pytest.raises(TypeError, match="Tuple"):
        space_to_spec(gym.spaces.Tuple((gym.spaces.Discrete(2),)))
    with pytest.raises(ValueError, match="start"):
        space_to_spec(gym.spaces.Discrete(3, start=1))
    with pytest.raises(TypeError, match="gymnasium.Space"):
        space_to_spec("not a space")


def test_spec_dtype_follows_real_sample():
    spec = Composite(a=Unbounded(shape=(1, 2), dtype=torch.float64), shape=(1,))
    ManiSkillTorchRLEnv._align_with_sample(spec, {"a": torch.zeros(1, 2)})
    assert spec["a"].dtype == torch.float32


def test_wrapper_rejects_non_maniskill_env():
    with pytest.raises(TypeError, match="BaseEnv"):
        ManiSkillTorchRLEnv(gym.make("CartPole-v1"))


class _CounterEnv(BaseEnv):
    """Simulator-free stand-in for a batched ManiSkill env (num_envs > 1).

    Each sub-env's observation is its step counter; ``reset`` honours
    ``options["env_idx"]`` like ManiSkill does. Lets us exercise true partial
    resets, which the CPU sim (num_envs=1 only) cannot.
    """

    def __init__(self, num_envs: int = 3):  # no BaseEnv.__init__: no simulator
        self.num_envs = num_envs
        self.device = torch.device("cpu")
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
        self.single_action_space = gym.spaces.Discrete(3)
        self.counter = torch.zeros(num_envs)
        self.reset_calls = []

    def get_info(self):
        return {"success": self.counter >= 100}

    def reset(self, seed=None, options=None):
        options = options or {}
        self.reset_calls.append((seed, options.get("env_idx")))
        idx = options.get("env_idx", torch.arange(self.num_envs))
        self.counter[idx] = 0
        return self.counter[:, None].clone(), self.get_info()

    def step(self, action):
        assert action.shape == (self.num_envs,) and action.dtype == torch.int64
        self.counter += 1
        obs = self.counter[:, None].clone()
        terminated = torch.zeros(self.num_envs, dtype=torch.bool)
        truncated = self.counter >= 2
        return obs, action.float(), terminated, truncated, self.get_info()

    def close(self):
        pass


def test_partial_reset_of_batched_env_with_discrete_actions():
    fake = _CounterEnv(num_envs=3)
    env = ManiSkillTorchRLEnv(fake)
    assert env.batch_size == torch.Size([3])
    assert isinstance(env.action_spec, Categorical) and env.action_spec.n == 3
    check_env_specs(env)

    env.set_seed(11)
    td = env.reset()
    assert fake.reset_calls[-1] == (11, None)
    td = step_mdp(env.rand_step(td))
    fake.counter[1] = 5.0  # make env 1 distinguishable from the others
    td["observation"][1] = 5.0
    td["_reset"] = torch.tensor([[True], [False], [True]])
    out = env.reset(td)
    seed, env_idx = fake.reset_calls[-1]
    assert seed is None and env_idx.tolist() == [0, 2]
    assert out["observation"].flatten().tolist() == [0.0, 5.0, 0.0]
    assert fake.counter.tolist() == [0.0, 5.0, 0.0]
    assert not out["done"].any()
    env.close()


# --------------------------------------------------------------------------- #
# real ManiSkill envs
# --------------------------------------------------------------------------- #
def test_state_env_specs(state_env):
    assert state_env.batch_size == torch.Size([1])
    assert state_env.device == state_env.base_env.device
    assert state_env.full_reward_spec["reward"].shape == torch.Size([1, 1])
    for key in ("done", "terminated", "truncated"):
        assert state_env.full_done_spec[key].shape == torch.Size([1, 1])
        assert state_env.full_done_spec[key].dtype == torch.bool
    check_env_specs(state_env)


def test_seeded_resets_are_reproducible(state_env):
    state_env.set_seed(3)
    a = state_env.reset()
    state_env.rand_step(a)
    state_env.set_seed(3)
    b = state_env.reset()
    torch.testing.assert_close(a["observation"], b["observation"], rtol=0, atol=0)
    state_env.set_seed(4)
    c = state_env.reset()
    assert not torch.equal(a["observation"], c["observation"])


def test_partial_reset(state_env):
    base = state_env.base_env
    state_env.set_seed(7)
    initial = state_env.reset()
    td = step_mdp(state_env.rand_step(initial.clone()))
    assert int(base.elapsed_steps[0]) == 1
    sim_state = base.get_state().clone()
    obs = td["observation"].clone()

    # Mask selecting no env: nothing in the simulator or the data changes.
    td["_reset"] = torch.zeros(1, 1, dtype=torch.bool)
    out = state_env.reset(td)
    assert "_reset" not in out.keys()
    assert int(base.elapsed_steps[0]) == 1
    torch.testing.assert_close(base.get_state(), sim_state, rtol=0, atol=0)
    torch.testing.assert_close(out["observation"], obs, rtol=0, atol=0)

    # Mask selecting the env: it is reset (to the seeded initial state).
    state_env.set_seed(7)
    out["_reset"] = torch.ones(1, 1, dtype=torch.bool)
    out = state_env.reset(out)
    assert int(base.elapsed_steps[0]) == 0
    assert not out["done"].any()
    torch.testing.assert_close(
        out["observation"], initial["observation"], rtol=0, atol=0
    )


def test_collector_with_random_policy(state_env):
    collector = Collector(
        state_env,
        policy=RandomPolicy(state_env.action_spec),
        frames_per_batch=100,
        total_frames=200,
    )
    action_spec = state_env.action_spec
    low, high = action_spec.space.low[0], action_spec.space.high[0]
    total, dones = 0, 0
    try:
        for batch in collector:
            total += batch.numel()
            assert batch.numel() == 100
            assert torch.isfinite(batch["next", "reward"]).all()
            action = batch["action"]
            assert action.shape[-1] == 8
            assert ((action >= low) & (action <= high)).all()
            dones += int(batch["next", "done"].sum())
    finally:
        collector.shutdown(close_env=False)
    assert total == 200
    # PickCube truncates after 50 steps; the collector must have reset through it.
    assert dones >= 200 // MAX_STEPS


def test_rgbd_dict_observation(rgbd_env):
    check_env_specs(rgbd_env)
    td = rgbd_env.reset()
    cam = rgbd_env.base_env._sensors["base_camera"].config
    rgb = td["sensor_data", "base_camera", "rgb"]
    assert rgb.dtype == torch.uint8
    assert rgb.shape == torch.Size([1, cam.height, cam.width, 3])
    depth = td["sensor_data", "base_camera", "depth"]
    assert depth.dtype == torch.int16
    assert rgbd_env.observation_spec["sensor_data", "base_camera", "rgb"].dtype == (
        torch.uint8
    )
    assert ("agent", "qpos") in rgbd_env.observation_spec.keys(True, True)
