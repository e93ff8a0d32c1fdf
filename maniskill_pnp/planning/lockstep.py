"""Execute the joint trajectories of every env of a batched ManiSkill env in lockstep.

ManiSkill's GPU simulation steps all ``num_envs`` scenes together, so the primitives of all envs must share control
steps: each env brings its own timed trajectory (its own plan, its own length), :func:`pad_trajectories` pads them to
the longest, and :class:`LockstepExecutor` sends one batched joint-position target per control step. An env whose
trajectory has ended, or that has none this time, holds its last target (stands still) and is marked inactive.

The same code drives one env on the CPU (``num_envs = 1``): :class:`~maniskill_pnp.planning.executor.SimExecutor`,
which the tasks' primitives use, is a one-env view of a :class:`LockstepExecutor`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from maniskill_pnp.planning.robot import ArmSpec

CONTROL_MODE = "pd_joint_pos"


@dataclass(frozen=True)
class PaddedTrajectories:
    """Trajectories of ``N`` envs on a common clock of ``T`` control steps.

    Attributes:
        targets: (N, T, dof) joint targets; past its own length an env repeats its last target.
        active: (N, T) bool, True while the env is on its own trajectory.
        lengths: (N,) the original lengths (0 for an env without a trajectory).
    """

    targets: np.ndarray
    active: np.ndarray
    lengths: np.ndarray

    @property
    def steps(self) -> int:
        return self.targets.shape[1]


def pad_trajectories(paths: Sequence[np.ndarray | None], hold: np.ndarray) -> PaddedTrajectories:
    """Pad per-env timed trajectories (``T_i × dof``, one row per control step) to the longest.

    Args:
        paths: One entry per env; None or an empty array: the env has nothing to execute.
        hold: (N, dof) the current target of each env, held by an env without a trajectory.

    Raises:
        ValueError: naming the env whose trajectory has the wrong width or non-finite values, or when ``paths`` and
            ``hold`` disagree on the number of envs.
    """
    hold = np.asarray(hold, dtype=np.float64)
    if hold.ndim != 2 or len(paths) != hold.shape[0]:
        raise ValueError(f"need one trajectory per env: {len(paths)} trajectories for hold of shape {hold.shape}")
    n, dof = hold.shape
    rows = []
    for i, p in enumerate(paths):
        p = np.zeros((0, dof)) if p is None else np.asarray(p, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != dof:
            raise ValueError(f"trajectory of env {i} must have shape (T, {dof}), got {p.shape}")
        if not np.isfinite(p).all():
            raise ValueError(f"trajectory of env {i} has non-finite joint targets")
        rows.append(p)
    lengths = np.array([len(p) for p in rows], dtype=np.int64)
    steps = int(lengths.max(initial=0))
    targets = np.empty((n, steps, dof))
    for i, p in enumerate(rows):
        last = p[-1] if len(p) else hold[i]
        targets[i, : len(p)] = p
        targets[i, len(p):] = last
    active = np.arange(steps)[None, :] < lengths[:, None]
    return PaddedTrajectories(targets, active, lengths)


class LockstepExecutor:
    """Drives the arms and grippers of all envs of ``env`` (a ManiSkill ``BaseEnv``) with joint-position targets.

    Each control step is ManiSkill's own (``BaseEnv._step_action``: controller targets, PhysX sub-steps, hooks),
    without the observation and reward work of ``env.step``.

    Args:
        env: The ManiSkill env (wrapped or not), any ``num_envs``, in the ``pd_joint_pos`` control mode.
        arm: The arm's description.
        on_control_step: Optional callback run after every control step (e.g. to grab video frames).

    Attributes:
        control_steps: Control steps executed since construction (all envs step together).
    """

    def __init__(self, env, arm: ArmSpec, on_control_step: Callable[[], None] | None = None):
        self.env = env.unwrapped
        if self.env.control_mode != CONTROL_MODE:
            raise ValueError(
                f"motion primitives need control_mode={CONTROL_MODE!r}, the env uses {self.env.control_mode!r}"
            )
        self.arm = arm
        self.on_control_step = on_control_step
        self.num_envs = int(self.env.num_envs)
        self.control_steps = 0
        self.dt = 1.0 / self.env.control_freq
        self._robot = self.env.agent.robot
        self._gripper = np.ones(self.num_envs)  # normalized gripper actions: +1 open, -1 closed

    def reset(self) -> None:
        """Forget the last gripper commands (grippers are open after an env reset); call after ``env.reset``."""
        self._gripper[:] = 1.0

    @property
    def sim_steps(self) -> int:
        """Physics steps executed since construction."""
        return self.control_steps * self.env._sim_steps_per_control

    def qpos(self) -> np.ndarray:
        """(N, dof) current arm joint positions."""
        return self._robot.get_qpos()[:, : self.arm.arm_joints].cpu().numpy().astype(np.float64)

    def finger_qpos(self) -> np.ndarray:
        """(N, fingers) current finger joint positions (m)."""
        return self._robot.get_qpos()[:, self.arm.arm_joints :].cpu().numpy().astype(np.float64)

    def arm_targets(self) -> np.ndarray:
        """(N, dof) the arm controller's current joint targets."""
        target = self.env.agent.controller.controllers["arm"]._target_qpos
        return target.cpu().numpy().astype(np.float64).reshape(self.num_envs, -1)

    def step(self, q_targets: np.ndarray, gripper: np.ndarray | float | None = None) -> None:
        """One control step of every env toward its arm target (``(N, dof)``) with its gripper command (+1 open,
        -1 closed; a scalar applies to all, None keeps each env's last command)."""
        if gripper is not None:
            self._gripper[:] = np.broadcast_to(np.asarray(gripper, dtype=np.float64), (self.num_envs,))
        q = np.asarray(q_targets, dtype=np.float64).reshape(self.num_envs, -1)
        action = np.concatenate([q, self._gripper[:, None]], axis=1).astype(np.float32)
        self.env._step_action(torch.as_tensor(action, device=self.env.device))
        self.control_steps += 1
        if self.on_control_step is not None:
            self.on_control_step()

    def follow(self, paths: Sequence[np.ndarray | None], *, settle_tol: float = 0.01, max_settle: int = 20) -> np.ndarray:
        """Track each env's timed trajectory in lockstep (padded, see :func:`pad_trajectories`), then hold every
        env's last target until all are within ``settle_tol`` rad of it (or ``max_settle`` steps passed).

        Returns:
            (N,) the remaining max joint error (rad) of each env.
        """
        padded = pad_trajectories(paths, self.arm_targets())
        for t in range(padded.steps):
            self.step(padded.targets[:, t])
        final = padded.targets[:, -1] if padded.steps else self.arm_targets()
        return self.settle(final, tol=settle_tol, max_steps=max_settle)

    def settle(self, q_targets: np.ndarray, *, tol: float = 0.01, max_steps: int = 20) -> np.ndarray:
        """Hold ``q_targets`` (N, dof) until every env is within ``tol`` rad of its target; returns (N,) errors."""
        q_targets = np.asarray(q_targets, dtype=np.float64).reshape(self.num_envs, -1)
        err = np.max(np.abs(self.qpos() - q_targets), axis=1)
        for _ in range(max_steps):
            if (err < tol).all():
                break
            self.step(q_targets)
            err = np.max(np.abs(self.qpos() - q_targets), axis=1)
        return err

    def gripper(self, commands: np.ndarray | float, steps: int) -> None:
        """Command the grippers (+1 open, -1 closed; one per env or one for all) for ``steps`` control steps, arms
        held at their current targets."""
        hold = self.arm_targets()
        for _ in range(steps):
            self.step(hold, gripper=commands)


__all__ = ["CONTROL_MODE", "LockstepExecutor", "PaddedTrajectories", "pad_trajectories"]
