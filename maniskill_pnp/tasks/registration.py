"""How this package's tasks register: ManiSkill's registry and ``gym.make`` ids, a time limit that keeps a task's own
truncation and can be recreated from ``env.spec``, and resets that seed gymnasium's ``np_random``."""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np
import torch
from gymnasium.envs.registration import WrapperSpec

from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.utils.registration import register_env


class SeededNpRandom:
    """Mixin for a ManiSkill task: its reset also seeds gymnasium's ``np_random`` with the reset's seed, as
    gymnasium's checker and wrappers expect (ManiSkill's own reset seeds only its episode RNGs)."""

    def reset(self, seed=None, options=None):
        gym.Env.reset(self, seed=None if seed is None else int(np.ravel(seed)[0]))
        return super().reset(seed=seed, options=options)


class TaskTimeLimit(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The time limit ``gym.make`` puts on this package's tasks: ``truncated`` is the task's own truncation (e.g.
    after 10 consecutive failed grasps) OR ``elapsed_steps >= max_episode_steps``, as a batched tensor.

    ManiSkill's :class:`~mani_skill.utils.registration.TimeLimitWrapper` *replaces* the env's ``truncated`` by the
    step count, so a task that truncates on its own would never end. Like it, a ``max_episode_steps`` given to
    ``gym.make`` replaces the registered one (gymnasium's own ``TimeLimit``, which ``gym.make`` then adds, is
    removed). It records its arguments, so ``env.spec.make()`` recreates the env.
    """

    def __init__(self, env: gym.Env, max_episode_steps: int | None = None):
        gym.utils.RecordConstructorArgs.__init__(self, max_episode_steps=max_episode_steps)
        gym.Wrapper.__init__(self, env)
        caller = sys._getframe(1)
        if caller.f_code.co_name == "make" and "max_episode_steps" in caller.f_locals:
            given = caller.f_locals["max_episode_steps"]
            if given is not None:
                max_episode_steps = None if given == -1 else given
            inner = env
            while isinstance(inner, gym.Wrapper):
                if isinstance(inner, gym.wrappers.TimeLimit):
                    self.env = inner.env
                    break
                inner = inner.env
        self._max_episode_steps = max_episode_steps

    @property
    def base_env(self) -> BaseEnv:
        return self.env.unwrapped

    def step(self, action):
        observation, reward, terminated, own, info = self.env.step(action)
        n = self.base_env.num_envs
        truncated = torch.as_tensor(own, device=self.base_env.device).to(torch.bool).reshape(n)
        if self._max_episode_steps is not None:
            truncated = truncated | (self.base_env.elapsed_steps >= self._max_episode_steps).reshape(n)
        return observation, reward, terminated, truncated, info


def register_task(uid: str, max_episode_steps: int | None = None, **kwargs):
    """ManiSkill's ``register_env`` decorator, with :class:`TaskTimeLimit` as the ``gym.make`` time limit (which
    ``env.spec.make()`` can recreate)."""
    register = register_env(uid, max_episode_steps=max_episode_steps, **kwargs)

    def decorate(cls):
        cls = register(cls)
        gym.registry[uid].additional_wrappers = (
            WrapperSpec("TaskTimeLimit", entry_point=f"{__name__}:TaskTimeLimit",
                        kwargs=dict(max_episode_steps=max_episode_steps)),
        )
        return cls

    return decorate
