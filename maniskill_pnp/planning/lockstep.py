"""Execute the joint trajectories of every env of a batched ManiSkill env in lockstep.

ManiSkill's GPU simulation steps all ``num_envs`` scenes together, so the primitives of all envs must share control
steps: each env brings its own timed trajectory (its own plan, its own length), :func:`pad_trajectories` pads them to
the longest, and :class:`LockstepExecutor` sends one batched joint-position target per control step. An env whose
trajectory has ended, or that has none this time, holds its last target (stands still) and is marked inactive.

Each env's share of a control phase is a :class:`Motion` (a timed path, a gripper command, how long to hold, when it
has settled); :meth:`LockstepExecutor.run` executes one Motion per env together. A primitive is a *program*: a
generator that yields Motions, receives each one's final tracking error, and returns its result.
:func:`drive` advances the programs of all envs in lockstep (each env's planning runs between the shared control
phases, on its own view of its sub-scene) until every program has returned.

The same code drives one env on the CPU (``num_envs = 1``): the tasks' primitives
(:class:`~maniskill_pnp.planning.primitives.MotionPrimitives`) run their programs through :func:`drive` with one env.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from typing import Any

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


@dataclass(frozen=True)
class Motion:
    """One env's share of a lockstep control phase.

    The env tracks ``targets`` row by row (one per control step; None: it holds its current arm target), holds the
    last one for at least ``min_steps`` steps from the phase start, then settles: it holds until ``until()`` is
    true (when given) or until its joints are within ``settle_tol`` rad of the held target (when not None), for at
    most ``max_settle`` more steps.

    Attributes:
        targets: (T, dof) timed joint targets, or None.
        gripper: Gripper command for the phase (+1 open, -1 closed); None keeps the env's last command.
        min_steps: Control steps the phase lasts at least (e.g. the gripper's closing time).
        settle_tol: Joint tolerance (rad) of the settle phase; None: no joint settling.
        max_settle: Most extra steps spent settling.
        until: A test run after each settle step (e.g. "the released object is at rest"); None: none.
        stop: A test run after each control step of the tracked path (e.g. a guarded move's contact test): when it is
            true the path ends there, the arm held where it is (no settling); None: none.
    """

    targets: np.ndarray | None = None
    gripper: float | None = None
    min_steps: int = 0
    settle_tol: float | None = 0.01
    max_settle: int = 20
    until: Callable[[], bool] | None = None
    stop: Callable[[], bool] | None = None

    def __post_init__(self):
        if self.min_steps < 0 or self.max_settle < 0:
            raise ValueError(f"min_steps and max_settle must be >= 0, got {self.min_steps}, {self.max_settle}")
        if self.gripper is not None and not -1.0 <= self.gripper <= 1.0:
            raise ValueError(f"gripper command must be in [-1, 1], got {self.gripper}")


#: A primitive program: yields the Motions of its env, receives each one's final error (rad), returns its result.
Program = Generator[Motion, float, Any]


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
        self._drives = DirectDrives.of(self.env)

    def reset(self, envs: Sequence[int] | None = None) -> None:
        """Forget the last gripper commands of ``envs`` (default: all; grippers are open after an env reset); call
        after ``env.reset`` of those envs."""
        self._gripper[slice(None) if envs is None else list(envs)] = 1.0

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
        if self._drives is not None:
            self._drives.set(q, float(self._gripper[0]))
            self.env._step_action(None)  # ManiSkill's control step with the drive targets already set
        else:
            action = np.concatenate([q, self._gripper[:, None]], axis=1).astype(np.float32)
            self.env._step_action(torch.as_tensor(action, device=self.env.device))
        self.control_steps += 1
        if self.on_control_step is not None:
            self.on_control_step()

    def run(self, motions: Sequence[Motion | None]) -> np.ndarray:
        """Execute one :class:`Motion` per env (None: the env idles, holding its target) in shared control steps.

        Envs whose motion has finished hold their last target while the others go on; the phase ends when every
        env's motion (path, ``min_steps`` and settling) is done.

        Returns:
            (N,) each env's max joint error (rad) from its final target at the end (0 for an idle env).
        """
        if len(motions) != self.num_envs:
            raise ValueError(f"need one motion (or None) per env: {len(motions)} for {self.num_envs} envs")
        paths = [None if m is None else m.targets for m in motions]
        padded = pad_trajectories(paths, self.arm_targets())
        final = padded.targets[:, -1] if padded.steps else self.arm_targets()
        for i, m in enumerate(motions):
            if m is not None and m.gripper is not None:
                self._gripper[i] = m.gripper
        busy = np.array([0 if m is None else max(int(padded.lengths[i]), m.min_steps) for i, m in enumerate(motions)])
        settle_left = np.array([0 if m is None else m.max_settle for m in motions])
        done = np.array([m is None for m in motions])  # an env whose motion is done stays done, holding its target
        t = 0
        while True:
            # joint errors are read only once some env's path is over (one read per step while settling)
            err = np.max(np.abs(self.qpos() - final), axis=1) if (t >= busy[~done]).any() else None
            for i, m in enumerate(motions):
                if done[i] or t < busy[i]:
                    continue
                if settle_left[i] <= 0:
                    done[i] = True
                elif m.until is not None:
                    done[i] = m.until()
                else:
                    done[i] = m.settle_tol is None or err[i] < m.settle_tol
                settle_left[i] -= int(not done[i])
            if done.all():
                break
            self.step(padded.targets[:, t] if t < padded.steps else final)
            t += 1
            for i, m in enumerate(motions):
                if m is not None and m.stop is not None and not done[i] and t < busy[i] and m.stop():
                    q = self.qpos()[i]  # the path ends here: hold where the arm is
                    padded.targets[i, t:] = q
                    final[i] = q
                    busy[i], settle_left[i] = t, 0
        err = np.max(np.abs(self.qpos() - final), axis=1)
        err[[m is None for m in motions]] = 0.0
        return err

    def follow(self, paths: Sequence[np.ndarray | None], *, settle_tol: float = 0.01, max_settle: int = 20) -> np.ndarray:
        """Track each env's timed trajectory in lockstep (padded, see :func:`pad_trajectories`), then hold each
        env's last target until it is within ``settle_tol`` rad of it (or ``max_settle`` steps passed).

        Returns:
            (N,) the remaining max joint error (rad) of each env.
        """
        return self.run([Motion(p, settle_tol=settle_tol, max_settle=max_settle) for p in paths])

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
        commands = np.broadcast_to(np.asarray(commands, dtype=np.float64), (self.num_envs,))
        self.run([Motion(gripper=float(c), min_steps=steps, settle_tol=None) for c in commands])


class DirectDrives:
    """The arm's and gripper's joint drive targets of a one-env CPU ManiSkill env, set without the controllers' per-step
    Python work: the same float32 targets ManiSkill's ``pd_joint_pos`` controllers would set, written straight to the
    PhysX joints.

    ManiSkill's ``agent.set_action`` converts the action, runs both controllers and sets each joint's target through
    tensor wrappers: about a third of a control step on the CPU. Here the arm's targets go to the joints directly
    (and into the arm controller's ``_target_qpos``, which the controller's state and :meth:`LockstepExecutor.arm_targets`
    read), and the gripper controller runs only when the fingers' PhysX targets differ from what its command sets
    (a new command, or an env reset that changed them). The physics sees the same targets at the same steps, so
    the simulation is bit-for-bit the one ManiSkill's own ``set_action`` gives (tested).

    Use :meth:`of`, which gives None where the fast path does not apply (GPU simulation, several envs, other
    controllers); the executor then takes ManiSkill's ``set_action``.
    """

    def __init__(self, arm_controller, gripper_controller):
        self._arm, self._grip = arm_controller, gripper_controller
        self._arm_joints = [j._objs[0] for j in arm_controller.joints]
        self._grip_joints = [j._objs[0] for j in gripper_controller.joints]
        self._grip_targets: dict[float, np.ndarray] = {}  # command -> the fingers' targets it sets

    @classmethod
    def of(cls, env) -> "DirectDrives | None":
        """The direct drives of ``env`` (unwrapped), or None where ManiSkill's own ``set_action`` must run."""
        from mani_skill.agents.controllers.pd_joint_pos import PDJointPosController, PDJointPosMimicController

        controllers = getattr(getattr(env.agent, "controller", None), "controllers", {})
        arm, grip = controllers.get("arm"), controllers.get("gripper")
        if set(controllers) != {"arm", "gripper"} or env.gpu_sim_enabled or env.num_envs != 1:
            return None
        if type(arm) is not PDJointPosController or type(grip) is not PDJointPosMimicController:
            return None
        a, g = arm.config, grip.config
        if a.normalize_action or a.use_delta or a.interpolate or g.use_delta or g.interpolate:
            return None
        return cls(arm, grip)

    def set(self, q: np.ndarray, gripper: float) -> None:
        """Drive targets of the arm (``(1, dof)`` rad) and the gripper command (+1 open, -1 closed)."""
        q32 = np.ascontiguousarray(q, dtype=np.float32).reshape(1, -1)
        targets = q32[0].tolist()  # float32 values as Python floats (exact): the scalar setter takes them ~3x faster
        if any(v != v for v in targets):
            raise ValueError(f"arm targets must not be NaN, got {targets}")
        for joint, target in zip(self._arm_joints, targets):
            joint.set_drive_target(target)
        self._arm._target_qpos = torch.from_numpy(q32)
        want = self._grip_targets.get(gripper)
        if want is None or any(float(j.drive_target[0]) != w for j, w in zip(self._grip_joints, want)):
            self._grip.set_action(torch.tensor([[gripper]], dtype=torch.float32))
            self._grip_targets[gripper] = np.array([float(j.drive_target[0]) for j in self._grip_joints])


def drive(executor: LockstepExecutor, programs: Sequence[Program | None]) -> list:
    """Run one primitive program per env (None: the env idles) in lockstep until all have returned.

    Each round gathers the Motion every unfinished program is waiting on, executes them together
    (:meth:`LockstepExecutor.run`), and sends each program its env's final error; a program's planning runs
    between rounds.

    Returns:
        Each program's return value (None for an idle env).
    """
    if len(programs) != executor.num_envs:
        raise ValueError(f"need one program (or None) per env: {len(programs)} for {executor.num_envs} envs")
    results: list = [None] * len(programs)
    waiting: list[Motion | None] = [None] * len(programs)

    def advance(i: int, sent: float | None) -> None:
        try:
            waiting[i] = next(programs[i]) if sent is None else programs[i].send(sent)
        except StopIteration as done:
            waiting[i], results[i] = None, done.value

    for i, program in enumerate(programs):
        if program is not None:
            advance(i, None)
    while any(m is not None for m in waiting):
        current = list(waiting)
        errors = executor.run(current)
        for i, m in enumerate(current):
            if m is not None:
                advance(i, float(errors[i]))
    return results


__all__ = ["CONTROL_MODE", "DirectDrives", "LockstepExecutor", "Motion", "PaddedTrajectories", "Program", "drive", "pad_trajectories"]
