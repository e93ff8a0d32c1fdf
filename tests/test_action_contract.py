"""The contract every registered task keeps with gymnasium and TorchRL users.

* gymnasium's full ``check_env`` passes on each id through ManiSkill's ``CPUGymWrapper`` (:func:`make_gym_env`,
  which records its arguments so ``env.spec.make()`` can recreate it), at the sizes users run (each id's defaults,
  and ``ClutterGraspSlide-v1`` also at ``medium`` density); its render check opens a window for
  ``render_mode="human"``, so the headless ``rgb_array`` mode is checked on its own.
* The first loop every gymnasium user writes, ``env.step(env.action_space.sample())`` with resets at episode ends,
  runs several episodes on each id (:data:`RANDOM_STEPS`): every action inside ``action_space`` is executed (a failed attempt if impossible now).
* ``info`` carries the outcome of :data:`~maniskill_pnp.tasks.OUTCOME_KEYS` as ``(num_envs,)`` tensors.
* TorchRL's ``check_env_specs`` passes on each id, with the outcome keys (and the conveyor's action mask) exposed.

Every check runs each id at its default sizes (``ClutterGrasp-v1``: 10-15 objects, ``ClutterGraspSlide-v1``: 10, both
on 224 px heightmaps with 16 rotations); the random-action loop is shorter for the clutter ids, whose steps are
whole planned motions.
"""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch
from gymnasium.utils.env_checker import check_env, env_render_passive_checker
from torchrl.envs.utils import check_env_specs

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.gym_env import GymEnv, make_gym_env
from maniskill_pnp.tasks import OUTCOME_KEYS, TASK_IDS
from maniskill_pnp.torchrl_env import ManiSkillTorchRLEnv

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
SETTINGS = {
    "CubeToBin-v1": dict(obs_mode="state"),
    "ConveyorProximity-v1": dict(),
    "ClutterGrasp-v1": dict(),
    "ClutterGraspSlide-v1": dict(),
}
PRIMITIVE_IDS = [i for i in TASK_IDS if i != "CubeToBin-v1"]
#: Random actions per id: enough for several episodes (a clutter episode of random grasps ends after 10 failures).
RANDOM_STEPS = {"CubeToBin-v1": 200, "ConveyorProximity-v1": 200, "ClutterGrasp-v1": 30, "ClutterGraspSlide-v1": 30}


@pytest.fixture(scope="module", params=TASK_IDS)
def task(request):
    """(id, the env as ``gym.make`` returns it) for each registered id, made once."""
    env = gym.make(request.param, **SETTINGS[request.param], **CPU)
    yield request.param, env
    env.close()


def test_settings_cover_every_registered_id():
    assert set(SETTINGS) == set(TASK_IDS)


def test_full_gymnasium_checker_passes_through_cpu_gym_wrapper(task):
    uid, env = task
    wrapped = GymEnv(env)
    check_env(wrapped, skip_render_check=True)  # the close check recreates the env from wrapped.spec; its reset and
    # step determinism checks run after the resets and steps of the checks before them
    rendering = wrapped.spec.make(render_mode="rgb_array")
    try:
        rendering.reset(seed=0)
        env_render_passive_checker(rendering)
    finally:
        rendering.close()


def test_full_gymnasium_checker_passes_at_medium_density():
    """ClutterGraspSlide-v1 with 15-20 objects dropped into a pile: the density of the results table."""
    env = make_gym_env("ClutterGraspSlide-v1", num_objects="medium", **CPU)
    try:
        check_env(env, skip_render_check=True)
    finally:
        env.close()


def test_random_in_space_actions_run_episodes(task):
    """``env.step(env.action_space.sample())`` never raises; episodes end and reset; outcomes are (1,) tensors."""
    uid, env = task
    env.action_space.seed(0)
    _, info = env.reset(seed=0)
    if uid in PRIMITIVE_IDS:  # after a reset: the outcome of no action
        assert info["primitive_index"].tolist() == [-1]
        assert not any(info[k].item() for k in ("grasp_success", "place_success", "slide_changed", "invalid_action", "fault"))
    episodes, invalid = 0, 0
    for _ in range(RANDOM_STEPS[uid]):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert reward.shape == (1,) and terminated.shape == (1,) and truncated.shape == (1,)
        if uid in PRIMITIVE_IDS:
            for key in OUTCOME_KEYS:
                assert isinstance(info[key], torch.Tensor) and info[key].shape == (1,), key
            invalid += int(info["invalid_action"].item())
        if bool(terminated.item() or truncated.item()):
            episodes += 1
            _, info = env.reset()
    if uid in PRIMITIVE_IDS:
        assert episodes >= 1  # (CubeToBin-v1's 400-step time limit is not reached)
    if uid == "ConveyorProximity-v1":
        assert invalid > 0  # most unmasked draws are beyond the phase's coordinates: executed as failed attempts


def test_torchrl_specs_hold_with_outcomes_exposed(task):
    uid, env = task
    wrapped = ManiSkillTorchRLEnv(env)
    check_env_specs(wrapped, seed=0)
    td = wrapped.rollout(3, break_when_any_done=False)
    if uid in PRIMITIVE_IDS:
        for key in OUTCOME_KEYS:
            assert td["next", key].shape == (1, 3, 1), key
    if uid == "ConveyorProximity-v1":
        mask = td["action_mask"]
        assert mask.dtype == torch.bool and mask.shape == (1, 3, env.unwrapped.single_action_space.n)
