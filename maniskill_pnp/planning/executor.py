"""Execute joint trajectories on one env of a ManiSkill env through the Panda's joint-position controller.

:class:`SimExecutor` is the one-env view of :class:`~maniskill_pnp.planning.lockstep.LockstepExecutor` that the
primitives use: it reads env ``env_idx``'s joints, and on a one-env ManiSkill env it also drives it directly, with
1-D joint vectors in and out. The envs of a batched env are driven together by
:func:`~maniskill_pnp.planning.lockstep.drive`. Each control step is ManiSkill's own (``BaseEnv._step_action``:
controller targets, PhysX sub-steps, hooks), without the observation and reward work of ``env.step``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from maniskill_pnp.planning.lockstep import CONTROL_MODE, LockstepExecutor
from maniskill_pnp.planning.robot import ArmSpec


class SimExecutor:
    """Reads, and on a one-env ManiSkill env drives, the arm and gripper of env ``env_idx`` of ``env``.

    Args:
        env: The ManiSkill env (wrapped or not); it must use the ``pd_joint_pos`` control mode.
        arm: The arm's description (gripper open/closed values).
        on_control_step: Optional callback run after every control step (e.g. to grab video frames).
        lockstep: The executor of all envs to share (a new one by default).
        env_idx: Which env this view reads.
    """

    def __init__(self, env, arm: ArmSpec, on_control_step: Callable[[], None] | None = None, *,
                 lockstep: LockstepExecutor | None = None, env_idx: int = 0):
        self.lockstep = lockstep or LockstepExecutor(env, arm, on_control_step)
        if not 0 <= env_idx < self.lockstep.num_envs:
            raise ValueError(f"env_idx {env_idx} out of range for {self.lockstep.num_envs} envs")
        self.env, self.arm, self.dt, self.env_idx = self.lockstep.env, arm, self.lockstep.dt, env_idx

    def _one_env(self) -> LockstepExecutor:
        if self.lockstep.num_envs != 1:
            raise RuntimeError(
                f"SimExecutor drives a one-env ManiSkill env; this one has {self.lockstep.num_envs} envs, whose "
                "primitive programs run together through maniskill_pnp.planning.lockstep.drive"
            )
        return self.lockstep

    @property
    def on_control_step(self) -> Callable[[], None] | None:
        return self.lockstep.on_control_step

    @on_control_step.setter
    def on_control_step(self, callback: Callable[[], None] | None) -> None:
        self.lockstep.on_control_step = callback

    @property
    def control_steps(self) -> int:
        """Control steps executed since construction."""
        return self.lockstep.control_steps

    @property
    def sim_steps(self) -> int:
        """Physics steps executed since construction."""
        return self.lockstep.sim_steps

    def reset(self) -> None:
        """Forget this env's last gripper command (the gripper is open after an env reset); call after ``env.reset``."""
        self.lockstep.reset([self.env_idx])

    def qpos(self) -> np.ndarray:
        """Current arm joint positions."""
        return self.lockstep.qpos()[self.env_idx]

    def finger_qpos(self) -> np.ndarray:
        """Current finger joint positions (m)."""
        return self.lockstep.finger_qpos()[self.env_idx]

    def step(self, q_target: np.ndarray, gripper: float | None = None) -> None:
        """One control step toward arm target ``q_target`` with the gripper command (+1 open, -1 closed)."""
        self._one_env().step(np.asarray(q_target)[None], gripper)

    def follow(self, positions: np.ndarray, *, settle_tol: float = 0.01, max_settle: int = 20) -> float:
        """Track timed joint positions (M×dof, one per control step), then hold the last until settled.

        Returns:
            The remaining max joint error (rad) at the end.
        """
        return float(self._one_env().follow([positions], settle_tol=settle_tol, max_settle=max_settle)[0])

    def settle(self, q_target: np.ndarray, *, tol: float = 0.01, max_steps: int = 20) -> float:
        """Hold ``q_target`` until every joint is within ``tol`` rad of it (or ``max_steps`` passed)."""
        return float(self._one_env().settle(np.asarray(q_target)[None], tol=tol, max_steps=max_steps)[0])

    def gripper(self, command: float, steps: int) -> None:
        """Command the gripper (+1 open, -1 closed) for ``steps`` control steps, arm held in place."""
        self._one_env().gripper(command, steps)


__all__ = ["CONTROL_MODE", "SimExecutor"]
