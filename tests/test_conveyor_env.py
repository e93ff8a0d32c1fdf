"""ConveyorProximity-v1: registration, episodes, seeding, proximity sensing, bad input and the scripted oracle."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from maniskill_pnp.tasks import OUTCOME_KEYS, TASK_IDS, ConveyorProximityEnv
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
    assert info["phase"] == "initial" and info["action_mask"].tolist() == [[True] + [False] * (spec.action_n - 1)]
    assert (info["sensed_speed"], info["sensed_alignment"], info["last_coord"]) == ("unknown", "unknown", -1)
    assert env.observation_space.contains(obs.numpy())
    assert env.action_space == gym.spaces.Discrete(spec.action_n)
    obs, reward, terminated, truncated, info = env.step(0)
    assert info["phase"] == "pre_pick" and not terminated[0] and not truncated[0]
    assert spec.decode_state(int(obs[0])) == dict(
        phase="pre_pick", speed=info["sensed_speed"], alignment=info["sensed_alignment"], last=None
    )
    assert info["sim_steps"] > 0 and len(info["rays"]["align_distances"]) == len(spec.align_ray_x)
    assert info["action_mask"].shape == (1, spec.action_n) and info["action_mask"].dtype == torch.bool
    assert info["action_mask"][0].sum() == spec.num_actions["pre_pick"] and info["primitive_index"].tolist() == [0]
    obs, reward, terminated, _, info = env.step(4)
    assert info["phase"] == "grasp" and spec.decode_state(int(obs[0]))["last"] == 4
    obs, reward, terminated, truncated, info = env.step(0)
    assert reward.shape == (1,) and reward.dtype == torch.float32 and float(reward[0]) in (0.0, 0.5, 1.0)
    assert bool(terminated[0]) and info["phase"] == "done" and not info["action_mask"].any()
    assert info["primitive_index"].tolist() == [2] and not info["invalid_action"][0]
    for key in OUTCOME_KEYS:
        assert info[key].shape == (1,), key
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


def test_out_of_space_actions_raise_clear_errors_before_moving(env):
    env.reset(seed=0)
    n = env.unwrapped.conveyor.action_n
    for bad, words in [
        (n, [f"0..{n - 1}"]), (-1, [f"0..{n - 1}"]), (np.nan, ["integer"]), (0.5, ["integer"]),
        (np.array([0, 1]), ["shape"]), (np.zeros((1, 1, 1), dtype=np.int64), ["shape"]), (True, ["integer"]),
    ]:
        with pytest.raises(ValueError) as e:
            env.step(bad)
        assert all(w in str(e.value) for w in words), str(e.value)
    assert env.unwrapped.phase == "initial" and env.unwrapped.elapsed_steps.item() == 0  # nothing ran


@pytest.mark.parametrize("phase_steps", [0, 2])  # initial: 1 of 9 actions; grasp: 6 of 9 (pre_pick offers all 9)
def test_in_space_actions_the_phase_does_not_offer_are_failed_attempts(env, phase_steps):
    """An action inside Discrete(9) beyond the phase's coordinates runs nothing, earns the failure reward and ends
    the episode as a failure would; it never raises."""
    spec: ConveyorSpec = env.unwrapped.conveyor
    _, info = env.reset(seed=2, options=dict(alignment="center", speed="slow"))
    for a in [0, 1][:phase_steps]:
        _, _, _, _, info = env.step(a)
    phase = info["phase"]
    invalid = int(spec.num_actions[phase])  # the first index the phase does not offer
    assert invalid < spec.action_n and not info["action_mask"][0, invalid]
    q0 = env.unwrapped.agent.robot.get_qpos().clone()
    _, reward, terminated, truncated, info = env.step(invalid)
    assert bool(info["invalid_action"][0]) and info["primitive_index"].tolist() == [-1]
    assert float(reward[0]) == 0.0 and bool(terminated[0]) and not bool(truncated[0])
    assert info["phase"] == "done" and info["outcome"] == f"invalid action {invalid} in phase {phase!r}"
    assert info["sim_steps"].item() == 0 and torch.equal(env.unwrapped.agent.robot.get_qpos(), q0)


def test_masked_sampling_only_draws_valid_actions(env):
    _, info = env.reset(seed=4)
    draws = {int(env.action_space.sample(mask=info["action_mask"])) for _ in range(20)}
    assert draws == {0}
    _, _, _, _, info = env.step(0)
    draws = {int(env.action_space.sample(mask=info["action_mask"])) for _ in range(200)}
    assert draws == set(range(env.unwrapped.conveyor.num_actions["pre_pick"]))


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
        for seed in range(5, 10):  # the first catch the oracle places (it placed 150 of 150 medium-speed objects)
            reward, info, _ = _oracle_episode(env, seed=seed, speed="medium")
            if info["outcome"] == "placed":
                break
        assert info["outcome"] == "placed" and reward == 2.0  # 1 for the place, +1 for the hand-marked coordinates
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
    # 150 of 150 medium-speed catches placed when measured (2026-12-06; seeds 1000-1049 and 5000-5099): 45 of 50
    # leaves room for a few catches that another machine's physics ends otherwise, not for a broken oracle or task.
    assert sum(r == 1.0 for r in rewards) >= 45, rewards
