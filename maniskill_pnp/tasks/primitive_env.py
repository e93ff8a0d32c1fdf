"""What every task whose one step is a whole motion primitive shares: a Discrete action space, strict action
parsing, gymnasium's ``np_random`` seeded with ManiSkill's seed, and a time limit that keeps the task's own
truncation.

ManiSkill tasks take one low-level control action per step; the tasks of this package take one decision (a
coordinate, a pixel) and execute a planned primitive inside ``step``. They subclass :class:`PrimitiveStepEnv`.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from gymnasium.envs.registration import WrapperSpec

from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.utils.registration import TimeLimitWrapper, register_env


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


def parse_discrete_actions(action, num_envs: int, n: int, valid: str) -> list[int]:
    """One integer index in ``0..n-1`` per env: as :func:`parse_discrete_action` for one env, else an array or
    tensor of shape ``(num_envs,)`` (or ``(num_envs, 1)``).

    Raises:
        ValueError: naming the env whose action is invalid, or the expected shape; raised before anything moves.
    """
    if num_envs == 1:
        return [parse_discrete_action(action, n, valid)]
    a = action.detach().cpu().numpy() if isinstance(action, torch.Tensor) else np.asarray(action)
    if a.shape not in ((num_envs,), (num_envs, 1)):
        raise ValueError(f"action must be one index per env, shape ({num_envs},), each {valid}; got shape {a.shape}")
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"action must be integer indices, each {valid}; got dtype {a.dtype}")
    out = []
    for i, x in enumerate(a.reshape(num_envs)):
        try:
            out.append(parse_discrete_action(x, n, valid))
        except ValueError as e:
            raise ValueError(f"env {i}: {e}") from None
    return out


class PrimitiveTimeLimit(TimeLimitWrapper):
    """ManiSkill's time limit, except that a truncation the task reports itself is kept.

    ManiSkill's :class:`~mani_skill.utils.registration.TimeLimitWrapper` (which ``gym.make`` adds to every
    registered id) *replaces* the env's ``truncated`` by ``elapsed_steps >= max_episode_steps``, so a task that
    truncates on its own (e.g. after 10 consecutive failed grasps) would never end. This wrapper returns the OR.
    """

    def step(self, action):
        observation, reward, terminated, own, info = self.env.step(action)
        n = self.base_env.num_envs
        truncated = torch.as_tensor(own, device=self.base_env.device).to(torch.bool).reshape(n)
        if self._max_episode_steps is not None:
            truncated = truncated | (self.base_env.elapsed_steps >= self._max_episode_steps).reshape(n)
        return observation, reward, terminated, truncated, info


def register_primitive_env(uid: str, max_episode_steps: int | None = None, **kwargs):
    """ManiSkill's ``register_env`` decorator, with :class:`PrimitiveTimeLimit` as the ``gym.make`` time limit."""
    register = register_env(uid, max_episode_steps=max_episode_steps, **kwargs)

    def decorate(cls):
        cls = register(cls)
        gym.registry[uid].additional_wrappers = (
            WrapperSpec("PrimitiveTimeLimit", entry_point=f"{__name__}:PrimitiveTimeLimit",
                        kwargs=dict(max_episode_steps=max_episode_steps)),
        )
        return cls

    return decorate


class PrimitiveStepEnv(BaseEnv):
    """A ManiSkill task whose step executes a whole primitive chosen by one Discrete action per env.

    It runs in the ``pd_joint_pos`` control mode the primitives drive; other values raise a ValueError before the
    scene is built. A task whose step runs the primitives of all envs in lockstep
    (:func:`~maniskill_pnp.planning.lockstep.drive`) sets :attr:`BATCHED`; the others run one env.
    """

    #: Whether the task runs ``num_envs > 1`` (ManiSkill's GPU simulation; its CPU simulation has one env).
    BATCHED = False

    def __init__(self, *args, **kwargs):
        name = type(self).__name__
        num_envs = kwargs.get("num_envs", 1)
        if num_envs != 1 and not self.BATCHED:
            raise ValueError(f"{name} runs one env (one whole primitive per step); got num_envs={num_envs}")
        if num_envs != 1:
            backend = kwargs.get("sim_backend", "auto")
            if backend in ("cpu", "physx_cpu") or (backend == "auto" and not torch.cuda.is_available()):
                raise ValueError(
                    f"{name} with num_envs={num_envs} needs ManiSkill's GPU simulation (sim_backend='physx_cuda' on a "
                    f"CUDA GPU; its CPU simulation runs one env); got sim_backend={backend!r}"
                    + ("" if torch.cuda.is_available() else " and no CUDA GPU")
                )
        kwargs.setdefault("control_mode", "pd_joint_pos")
        if kwargs["control_mode"] != "pd_joint_pos":
            raise ValueError(f"{name} needs control_mode='pd_joint_pos', got {kwargs['control_mode']!r}")
        # ManiSkill defines this after the first reset of its __init__, but a control step (BaseEnv._step_action,
        # which the primitives' executor takes) reads it, and a task may step inside that reset (a settling
        # clutter). The executor's actions are always batched, so a shape-() space is right until then; after it,
        # _use_discrete_actions sets the same.
        self._orig_single_action_space = spaces.Discrete(1)
        super().__init__(*args, **kwargs)

    _control_step_callback = None

    def set_control_step_callback(self, callback) -> None:
        """Call ``callback()`` after every control step the primitives execute (e.g. to film the arm's motion);
        ``None`` removes it. Takes effect at once, also in the middle of an episode."""
        if callback is not None and not callable(callback):
            raise ValueError(f"callback must be callable or None, got {type(callback).__name__}")
        self._control_step_callback = callback

    def _on_control_step(self) -> None:
        """The hook the task's :class:`~maniskill_pnp.planning.MotionPrimitives` call after every control step."""
        if self._control_step_callback is not None:
            self._control_step_callback()

    def _use_discrete_actions(self, n: int) -> None:
        """Replace the agent's low-level action space by ``Discrete(n)``; call after ``super().__init__``."""
        self.single_action_space = spaces.Discrete(n)
        self.action_space = spaces.Discrete(n)
        self._orig_single_action_space = self.single_action_space

    def reset(self, seed=None, options=None):
        """ManiSkill's reset, plus gymnasium's ``np_random`` seeded from the same seed (checkers and wrappers use it)."""
        gym.Env.reset(self, seed=None if seed is None else int(np.ravel(seed)[0]))
        return super().reset(seed=seed, options=options)
