"""Execute joint trajectories on a ManiSkill env through the Panda's joint-position controller.

The executor advances the simulation one control period at a time with ManiSkill's own control step
(``BaseEnv._step_action``: controller targets, PhysX sub-steps, hooks), without the observation and reward
work of ``env.step``. A task that executes a whole primitive inside one of its own ``step`` calls uses it, and
so can a script that drives a plain ManiSkill env.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from maniskill_pnp.planning.robot import ArmSpec

CONTROL_MODE = "pd_joint_pos"


class SimExecutor:
    """Drives the arm and gripper of ``env`` (a ManiSkill ``BaseEnv``) with joint-position targets.

    Args:
        env: The ManiSkill env (wrapped or not); it must use the ``pd_joint_pos`` control mode.
        arm: The arm's description (gripper open/closed values).
        on_control_step: Optional callback run after every control step (e.g. to grab video frames).

    Attributes:
        control_steps: Control steps executed since construction.
    """

    def __init__(self, env, arm: ArmSpec, on_control_step: Callable[[], None] | None = None):
        self.env = env.unwrapped
        if self.env.control_mode != CONTROL_MODE:
            raise ValueError(
                f"motion primitives need control_mode={CONTROL_MODE!r}, the env uses {self.env.control_mode!r}"
            )
        if self.env.num_envs != 1:
            raise ValueError(f"SimExecutor drives one env; got num_envs={self.env.num_envs}")
        self.arm = arm
        self.on_control_step = on_control_step
        self.control_steps = 0
        self.dt = 1.0 / self.env.control_freq
        self._robot = self.env.agent.robot
        self._gripper_cmd = 1.0  # normalized gripper action: +1 open, -1 closed

    def reset(self) -> None:
        """Forget the last gripper command (the gripper is open after an env reset); call after ``env.reset``."""
        self._gripper_cmd = 1.0

    @property
    def sim_steps(self) -> int:
        """Physics steps executed since construction."""
        return self.control_steps * self.env._sim_steps_per_control

    def qpos(self) -> np.ndarray:
        """Current arm joint positions."""
        return self._robot.get_qpos()[0, : self.arm.arm_joints].cpu().numpy().astype(np.float64)

    def finger_qpos(self) -> np.ndarray:
        """Current finger joint positions (m)."""
        return self._robot.get_qpos()[0, self.arm.arm_joints :].cpu().numpy().astype(np.float64)

    def step(self, q_target: np.ndarray, gripper: float | None = None) -> None:
        """One control step toward arm target ``q_target`` with the gripper command (+1 open, -1 closed)."""
        if gripper is not None:
            self._gripper_cmd = float(gripper)
        action = np.concatenate([np.asarray(q_target, dtype=np.float32), [self._gripper_cmd]]).astype(np.float32)
        self.env._step_action(torch.as_tensor(action, device=self.env.device)[None])
        self.control_steps += 1
        if self.on_control_step is not None:
            self.on_control_step()

    def follow(self, positions: np.ndarray, *, settle_tol: float = 0.01, max_settle: int = 20) -> float:
        """Track timed joint positions (M×dof, one per control step), then hold the last until settled.

        Returns:
            The remaining max joint error (rad) at the end.
        """
        for q in positions:
            self.step(q)
        return self.settle(positions[-1], tol=settle_tol, max_steps=max_settle)

    def settle(self, q_target: np.ndarray, *, tol: float = 0.01, max_steps: int = 20) -> float:
        """Hold ``q_target`` until every joint is within ``tol`` rad of it (or ``max_steps`` passed)."""
        err = float(np.max(np.abs(self.qpos() - q_target)))
        for _ in range(max_steps):
            if err < tol:
                break
            self.step(q_target)
            err = float(np.max(np.abs(self.qpos() - q_target)))
        return err

    def gripper(self, command: float, steps: int) -> None:
        """Command the gripper (+1 open, -1 closed) for ``steps`` control steps, arm held in place."""
        hold = self._arm_target()
        for _ in range(steps):
            self.step(hold, gripper=command)

    def _arm_target(self) -> np.ndarray:
        target = self.env.agent.controller.controllers["arm"]._target_qpos
        return target[0].cpu().numpy().astype(np.float64)
