"""ConveyorProximity-v1: registration, episodes, seeding, proximity sensing, bad input and the scripted oracle."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from maniskill_pnp.tasks import TASK_IDS, ConveyorProximityEnv
from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, SPEEDS, ConveyorSpec

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
ORACLE_SEEDS = range(50)


@pytest.fixture(scope="module")
def env():
    """One conveyor env for the whole module (random object kinds, alignments and speeds)."""
    env = gym.make("ConveyorProximity-v1", obs_mode="state", **CPU)
    yield env
    env.close()


def _oracle_episode(env, seed: int, **options):
    """Run one episode with the hand-marked best coordinates; returns (reward, info, sim steps)."""
    spec: ConveyorSpec = env.unwrapped.conveyor
    _, info = env.reset(seed=seed, options=options)
    steps, terminated = 0, False
    while not terminated:
        action = spec.oracle_action(info["phase"], info["sensed_alignment"], info["sensed_speed"])
        _, reward, terminated, _, info = env.step(action)
        steps += info["sim_steps"]
    return float(reward[0]), info, steps


def test_id_resolves_to_our_class(env):
    assert "ConveyorProximity-v1" in TASK_IDS
    assert isinstance(env.unwrapped, ConveyorProximityEnv)


def test_whole_episode_shapes_and_phases(env):
    spec: ConveyorSpec = env.unwrapped.conveyor
    obs, info = env.reset(seed=3)
    assert obs.shape == (1,) and obs.dtype == torch.int64
    assert info["phase"] == "initial" and info["valid_actions"] == 1
    assert (info["sensed_speed"], info["sensed_alignment"], info["last_coord"]) == ("unknown", "unknown", -1)
    assert env.observation_space.contains(obs.numpy())
    assert env.action_space == gym.spaces.Discrete(spec.action_n)
    obs, reward, terminated, truncated, info = env.step(0)
    assert info["phase"] == "pre_pick" and not terminated[0] and not truncated[0]
    assert spec.decode_state(int(obs[0])) == dict(
        phase="pre_pick", speed=info["sensed_speed"], alignment=info["sensed_alignment"], last=None
    )
    assert info["sim_steps"] > 0 and len(info["rays"]["align_distances"]) == len(spec.align_ray_x)
    obs, reward, terminated, _, info = env.step(4)
    assert info["phase"] == "grasp" and spec.decode_state(int(obs[0]))["last"] == 4
    obs, reward, terminated, truncated, info = env.step(0)
    assert reward.shape == (1,) and reward.dtype == torch.float32 and float(reward[0]) in (0.0, 0.5, 1.0)
    assert bool(terminated[0]) and info["phase"] == "done"
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)


def test_seeded_reset_is_reproducible(env):
    def first_state(seed):
        obs, info = env.reset(seed=seed)
        obs2, _, _, _, info2 = env.step(0)
        return int(obs[0]), int(obs2[0]), info["truth"], info2["rays"]["gate_times"]

    assert first_state(11) == first_state(11)
    truths = {tuple(sorted((k, v) for k, v in first_state(s)[2].items() if k != "yaw")) for s in range(6)}
    assert len(truths) > 1


@pytest.mark.parametrize("alignment", ALIGNMENTS)
def test_sensors_report_true_alignment_and_speed(env, alignment):
    for speed in SPEEDS:
        for seed in (0, 1):
            env.reset(seed=seed, options=dict(alignment=alignment, speed=speed))
            _, _, _, _, info = env.step(0)
            assert (info["sensed_alignment"], info["sensed_speed"]) == (alignment, speed), info["rays"]
            assert info["truth"]["alignment"] == alignment and info["truth"]["speed"] == speed


def test_bad_actions_raise_clear_errors(env):
    env.reset(seed=0)
    for bad, words in [
        (9, ["initial", "0..0"]), (1, ["initial", "0..0"]), (-1, ["initial"]),
        (np.nan, ["integer"]), (0.5, ["integer"]), (np.array([0, 1]), ["shape"]), (True, ["integer"]),
    ]:
        with pytest.raises(ValueError) as e:
            env.step(bad)
        assert all(w in str(e.value) for w in words), str(e.value)
    assert env.unwrapped.phase == "initial"  # nothing ran
    env.step(np.int64(0))
    with pytest.raises(ValueError, match="pre_pick"):
        env.step(env.unwrapped.conveyor.action_n)
    env.step(torch.tensor([1]))
    with pytest.raises(ValueError, match=r"'grasp'.*0\.\.5"):
        env.step(8)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(reward_scheme="sparse"), ["reward_scheme", "negative_bonus"]),
        (dict(object_kinds=("cuboid", "torus")), ["torus", "cylinder"]),
        (dict(alignment="middle"), ["alignment", "center"]),
        (dict(speed="warp"), ["speed", "medium"]),
        (dict(num_envs=2), ["one env", "num_envs=2"]),
        (dict(control_mode="pd_ee_delta_pose"), ["pd_joint_pos", "pd_ee_delta_pose"]),
    ],
)
def test_bad_options_raise_clear_errors(kwargs, words):
    with pytest.raises(ValueError) as e:
        gym.make("ConveyorProximity-v1", obs_mode="state", **CPU, **kwargs)
    assert all(w in str(e.value) for w in words), str(e.value)


def test_reward_schemes(env):
    unwrapped = env.unwrapped
    try:
        unwrapped.reward_scheme = "negative_bonus"
        reward, info, _ = _oracle_episode(env, seed=5, speed="medium")
        assert info["outcome"] == "placed" and reward == 2.0
        env.reset(seed=5, options=dict(alignment="right", speed="medium"))
        env.step(0)
        env.step(0)  # a pre-pick coordinate over the left lane
        _, reward, _, _, info = env.step(0)
        assert info["outcome"].startswith("grasp failed") and float(reward[0]) == -1.0
    finally:
        unwrapped.reward_scheme = "normal"


def test_scripted_oracle_catches_medium_speed_objects(env):
    rewards, steps = [], []
    for seed in ORACLE_SEEDS:
        reward, _, n = _oracle_episode(env, seed=1000 + seed, speed="medium")
        rewards.append(reward)
        steps.append(n)
    assert sum(r == 1.0 for r in rewards) >= 45, rewards


def test_gymnasium_checks_through_cpu_wrapper(env):
    """gymnasium's reset/step checks pass through ManiSkill's CPUGymWrapper. (The full ``check_env`` also steps
    with an unmasked ``action_space.sample()``, which is an invalid index in the one-action initial phase.)"""
    from gymnasium.utils import env_checker
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    wrapped = CPUGymWrapper(env)
    for check in (
        env_checker.check_reset_seed_determinism, env_checker.check_reset_options,
        env_checker.check_step_determinism, env_checker.check_returned_data_not_reused,
    ):
        check(wrapped)
