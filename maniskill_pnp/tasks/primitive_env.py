"""What every task whose one step is a whole motion primitive shares: a Discrete action space, strict action
parsing, and gymnasium's ``np_random`` seeded with ManiSkill's seed.

ManiSkill tasks take one low-level control action per step; the tasks of this package take one decision (a
coordinate, a pixel) and execute a planned primitive inside ``step``. They subclass :class:`PrimitiveStepEnv`.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from mani_skill.envs.sapien_env import BaseEnv


def parse_discrete_action(action, n: int, valid: str) -> int:
    """One integer index in ``0..n-1`` from an int, numpy or torch scalar (or shape-(1,) array).

    Raises:
        ValueError: naming ``valid`` (what a valid action is) for a wrong shape, a non-integer dtype (float, NaN,
            bool) or an index out of range; raised before anything moves.
    """
    a = action.detach().cpu().numpy() if isinstance(action, torch.Tensor) else np.asarray(action)
    if a.size != 1 or a.ndim > 1:
        raise ValueError(f"action must be {valid} (shape () or (1,)), got shape {a.shape}")
    a = a.reshape(())
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"action must be {valid}, got {a.item()!r} of dtype {a.dtype}")
    index = int(a)
    if not 0 <= index < n:
        raise ValueError(f"action {index} out of range: must be {valid}")
    return index


class PrimitiveStepEnv(BaseEnv):
    """A ManiSkill task whose step executes a whole primitive chosen by one Discrete action.

    It runs one env (primitives of parallel envs do not run in lockstep yet) in the ``pd_joint_pos`` control mode
    the primitives drive; other values raise a ValueError before the scene is built.
    """

    def __init__(self, *args, **kwargs):
        name = type(self).__name__
        if kwargs.get("num_envs", 1) != 1:
            raise ValueError(f"{name} runs one env (one whole primitive per step); got num_envs={kwargs['num_envs']}")
        kwargs.setdefault("control_mode", "pd_joint_pos")
        if kwargs["control_mode"] != "pd_joint_pos":
            raise ValueError(f"{name} needs control_mode='pd_joint_pos', got {kwargs['control_mode']!r}")
        super().__init__(*args, **kwargs)

    def _use_discrete_actions(self, n: int) -> None:
        """Replace the agent's low-level action space by ``Discrete(n)``; call after ``super().__init__``."""
        self.single_action_space = spaces.Discrete(n)
        self.action_space = spaces.Discrete(n)
        self._orig_single_action_space = self.single_action_space

    def reset(self, seed=None, options=None):
        """ManiSkill's reset, plus gymnasium's ``np_random`` seeded from the same seed (checkers and wrappers use it)."""
        gym.Env.reset(self, seed=None if seed is None else int(np.ravel(seed)[0]))
        return super().reset(seed=seed, options=options)
