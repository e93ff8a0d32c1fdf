"""The tasks as plain single-env gymnasium environments (numpy in and out), for gymnasium's tooling.

ManiSkill's :class:`~mani_skill.utils.wrappers.gymnasium.CPUGymWrapper` turns a one-env ManiSkill task into a
standard gymnasium env (unbatched numpy observations, Python rewards and flags). It does not record its
constructor arguments, so ``env.spec.make()`` (which gymnasium's ``check_env`` and vector envs call to recreate an
env) fails on it; :class:`GymEnv` is the same wrapper with its arguments recorded.

Example:
    >>> import maniskill_pnp
    >>> env = maniskill_pnp.make_gym_env("ConveyorProximity-v1")
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample(mask=info["action_mask"]))
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

from maniskill_pnp.runtime import with_default_backends


class GymEnv(CPUGymWrapper, gym.utils.RecordConstructorArgs):
    """ManiSkill's ``CPUGymWrapper`` that records its arguments, so that ``env.spec.make()`` recreates it."""

    def __init__(self, env: gym.Env, ignore_terminations: bool = False, record_metrics: bool = False):
        gym.utils.RecordConstructorArgs.__init__(self, ignore_terminations=ignore_terminations, record_metrics=record_metrics)
        CPUGymWrapper.__init__(self, env, ignore_terminations=ignore_terminations, record_metrics=record_metrics)


def make_gym_env(env_id: str, **make_kwargs: Any) -> GymEnv:
    """``gymnasium.make(env_id, **make_kwargs)`` as a single-env numpy gymnasium env (one env on the CPU; backends
    not given default to :func:`maniskill_pnp.runtime.default_backends`)."""
    if make_kwargs.get("num_envs", 1) != 1:
        raise ValueError(f"a gymnasium env runs one env; got num_envs={make_kwargs['num_envs']} (use make_torchrl_env for batches)")
    return GymEnv(gym.make(env_id, **with_default_backends(make_kwargs)))
