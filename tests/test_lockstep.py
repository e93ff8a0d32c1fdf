"""The lockstep executor: per-env trajectories padded to a common clock, finished envs holding still.

The padding is checked on hand-made trajectories. The scheduling of per-env primitive programs (:func:`drive`) is
checked on several envs of a first-order joint model standing in for the batched GPU simulation, which a CPU-only
machine cannot run; the executor and the primitive programs on a real CPU ManiSkill env with ``num_envs = 1`` (the
code path the tasks use) and, where a GPU is present, on 4 GPU envs.
"""

from __future__ import annotations

from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch

from maniskill_pnp.planning import LockstepExecutor, MotionPrimitives, SimExecutor, pad_trajectories, panda_spec
from maniskill_pnp.planning.lockstep import CONTROL_MODE, Motion, drive


def test_padding_holds_the_last_target_and_masks_finished_envs():
    hold = np.array([[9.0, 9.0], [8.0, 8.0], [7.0, 7.0]])
    short = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    long = np.arange(10.0).reshape(5, 2)
    padded = pad_trajectories([short, long, None], hold)
    assert padded.targets.shape == (3, 5, 2) and padded.steps == 5
    assert padded.lengths.tolist() == [3, 5, 0]
    np.testing.assert_array_equal(padded.targets[0, :3], short)
    np.testing.assert_array_equal(padded.targets[0, 3:], [[2.0, 2.0], [2.0, 2.0]])  # finished: holds its last target
    np.testing.assert_array_equal(padded.targets[1], long)
    np.testing.assert_array_equal(padded.targets[2], np.full((5, 2), 7.0))  # nothing to do: holds where it is
    assert padded.active.tolist() == [[True] * 3 + [False] * 2, [True] * 5, [False] * 5]


def test_padding_of_no_trajectory_at_all_is_empty():
    padded = pad_trajectories([None, np.zeros((0, 2))], np.zeros((2, 2)))
    assert padded.steps == 0 and padded.targets.shape == (2, 0, 2) and padded.lengths.tolist() == [0, 0]


@pytest.mark.parametrize("paths, hold, message", [
    ([np.zeros((3, 3))], np.zeros((1, 2)), r"trajectory of env 0 must have shape \(T, 2\), got \(3, 3\)"),
    ([np.zeros((2, 2)), np.array([[0.0, np.nan]])], np.zeros((2, 2)), "trajectory of env 1 has non-finite"),
    ([np.zeros((2, 2))], np.zeros((2, 2)), "need one trajectory per env: 1 trajectories"),
])
def test_padding_rejects_bad_trajectories(paths, hold, message):
    with pytest.raises(ValueError, match=message):
        pad_trajectories(paths, hold)


def _ramp(q0: np.ndarray, joint: int, delta: float, steps: int) -> np.ndarray:
    path = np.repeat(q0[None], steps, axis=0)
    path[:, joint] += np.linspace(0.0, delta, steps)
    return path


def test_one_cpu_env_follows_a_trajectory_through_the_lockstep_path(cube_env):
    cube_env.reset(seed=0)
    ex = LockstepExecutor(cube_env, panda_spec())
    assert ex.num_envs == 1
    q0 = ex.qpos()
    assert q0.shape == (1, 7)
    path = _ramp(q0[0], joint=0, delta=0.15, steps=25)
    err = ex.follow([path])
    assert err.shape == (1,) and err[0] < 0.01
    assert ex.control_steps >= 25 and ex.sim_steps == ex.control_steps * cube_env.unwrapped._sim_steps_per_control
    np.testing.assert_allclose(ex.qpos()[0], path[-1], atol=0.01)
    steps = ex.control_steps
    ex.follow([None])  # nothing to do: no trajectory steps, the arm is already settled
    assert ex.control_steps - steps <= 1
    open_width = ex.finger_qpos()[0].sum()
    ex.gripper(np.array([-1.0]), 15)  # per-env gripper command
    assert ex.finger_qpos()[0].sum() < open_width - 0.02
    ex.gripper(1.0, 15)


def test_a_stop_test_ends_the_path_where_the_arm_is(cube_env):
    """A Motion's ``stop`` runs after each control step of its path; once true the arm holds where it is."""
    cube_env.reset(seed=0)
    ex = LockstepExecutor(cube_env, panda_spec())
    q0 = ex.qpos()[0]
    path = _ramp(q0, joint=0, delta=0.4, steps=40)
    calls = []

    def stop() -> bool:
        calls.append(ex.control_steps)
        return len(calls) == 10

    before = ex.control_steps
    err = ex.run([Motion(path, stop=stop)])
    assert len(calls) == 10 and ex.control_steps - before == 10  # no step after the stop, no settling
    reached = ex.qpos()[0, 0] - q0[0]
    assert 0.02 < reached < 0.2  # part of the way: 0.4 rad was planned
    assert err[0] < 0.02  # the final target is where the arm stopped
    np.testing.assert_allclose(ex.arm_targets()[0], ex.qpos()[0], atol=0.02)


def test_sim_executor_is_the_one_env_view(cube_env):
    cube_env.reset(seed=0)
    ex = SimExecutor(cube_env, panda_spec())
    assert isinstance(ex.lockstep, LockstepExecutor) and ex.qpos().shape == (7,)
    path = _ramp(ex.qpos(), joint=1, delta=-0.1, steps=15)
    before = ex.control_steps
    assert ex.follow(path) < 0.01
    assert ex.control_steps == ex.lockstep.control_steps and ex.control_steps - before >= 15


@pytest.mark.gpu
def test_gpu_envs_run_different_trajectories_in_lockstep():
    env = gym.make("CubeToBin-v1", num_envs=4, obs_mode="state", control_mode="pd_joint_pos", sim_backend="physx_cuda")
    env.reset(seed=0)
    ex = LockstepExecutor(env, panda_spec())
    q0 = ex.qpos()
    paths = [_ramp(q0[0], 0, 0.2, 30), _ramp(q0[1], 0, -0.1, 10), None, _ramp(q0[3], 2, 0.1, 20)]
    err = ex.follow(paths)
    assert ex.num_envs == 4 and err.shape == (4,) and (err < 0.01).all()
    q = ex.qpos()
    for i in (0, 1, 3):
        np.testing.assert_allclose(q[i], paths[i][-1], atol=0.01)
    np.testing.assert_allclose(q[2], q0[2], atol=0.01)  # no trajectory: held still
    env.close()


class FirstOrderArms:
    """``num_envs`` arms whose joints close half the gap to their targets each control step (the attributes of a
    ManiSkill env that :class:`LockstepExecutor` reads), standing in for a batched GPU env on this CPU-only test."""

    control_mode, control_freq, _sim_steps_per_control, device = CONTROL_MODE, 20, 5, "cpu"

    def __init__(self, num_envs: int, dof: int = 7, fingers: int = 2):
        self.num_envs, self.dof, self.unwrapped = num_envs, dof, self
        self.q = torch.zeros(num_envs, dof + fingers, dtype=torch.float64)
        self.target = torch.zeros(num_envs, dof, dtype=torch.float64)
        self.grippers: list[np.ndarray] = []
        arm = SimpleNamespace(_target_qpos=self.target)
        self.agent = SimpleNamespace(robot=SimpleNamespace(get_qpos=lambda: self.q.clone()),
                                     controller=SimpleNamespace(controllers={"arm": arm}))

    def _step_action(self, action: torch.Tensor) -> None:
        self.target[:] = action[:, : self.dof].double()
        self.grippers.append(action[:, self.dof].numpy().copy())
        self.q[:, : self.dof] += 0.5 * (self.target - self.q[:, : self.dof])


def _program(log: list, q0: np.ndarray, moves: list[float], name: str):
    """A primitive program: one ramp of joint 0 per entry of ``moves`` (of ``len`` steps ~ its size), logging the
    error it receives after each; then a gripper close; returns ``name``."""
    q = q0.copy()
    for delta in moves:
        path = _ramp(q, joint=0, delta=delta, steps=int(abs(delta) * 100))
        q = path[-1]
        err = yield Motion(path)
        log.append((name, err))
    yield Motion(gripper=-1.0, min_steps=3, settle_tol=None)
    return name


def test_drive_runs_per_env_programs_in_shared_control_steps():
    env = FirstOrderArms(num_envs=3)
    ex = LockstepExecutor(env, panda_spec())
    log: list = []
    q0 = ex.qpos()
    programs = [_program(log, q0[0], [0.3, -0.1], "a"), None, _program(log, q0[2], [0.05], "c")]
    results = drive(ex, programs)
    assert results == ["a", None, "c"]
    # round 1: env 0 ramps 30 steps, env 2 ramps 5 then holds; both settle; round 2: env 0 ramps 10 steps while
    # env 2 closes its gripper (3 steps); round 3: env 0 closes its gripper
    q = ex.qpos()
    np.testing.assert_allclose(q[0, 0], 0.2, atol=0.01)
    np.testing.assert_allclose(q[2, 0], 0.05, atol=0.01)
    np.testing.assert_allclose(q[1], 0.0)  # the idle env never moved
    assert [name for name, _ in log] == ["a", "c", "a"] and all(err < 0.01 for _, err in log)
    grippers = np.stack(env.grippers)
    assert (grippers[:, 1] == 1.0).all()  # idle: open throughout
    assert grippers[-1, 0] == -1.0 and grippers[-1, 2] == -1.0
    assert ex.control_steps < 30 + 10 + 3 + 3 * 20  # shared steps: far fewer than the programs run one by one
    assert ex.control_steps >= 30 + 10 + 3


def test_motion_phases_hold_settle_and_wait():
    env = FirstOrderArms(num_envs=2)
    ex = LockstepExecutor(env, panda_spec())
    calls = []

    def at_rest() -> bool:
        calls.append(ex.control_steps)
        return len(calls) >= 4

    err = ex.run([Motion(gripper=-1.0, min_steps=6, settle_tol=None),
                  Motion(np.full((1, 7), 0.1), settle_tol=None, until=at_rest, max_settle=10)])
    assert ex.control_steps == 6  # the gripper's 6 steps outlast the 4 checks (1 step + 3 settle steps) of env 1
    assert calls == [1, 2, 3, 4] and err.shape == (2,)
    steps = ex.control_steps
    ex.run([None, None])
    assert ex.control_steps == steps  # nothing to do takes no step
    with pytest.raises(ValueError, match="one motion"):
        ex.run([None])
    with pytest.raises(ValueError, match="gripper command"):
        Motion(gripper=2.0)
    with pytest.raises(ValueError, match="one program"):
        drive(ex, [None])


def test_primitive_programs_run_through_drive_on_one_cpu_env(cube_env):
    cube_env.reset(seed=3)
    prims = MotionPrimitives(cube_env, static_actors={"table-workspace", "ground", "bin"}, seed=3)
    cube = cube_env.unwrapped.cube
    cube.set_pose(sapien.Pose(p=[0.0, -0.05, 0.02]))
    before = cube.pose.p[0].numpy().copy()
    program = prims.program("slide", np.array([-0.045, -0.05, 0.015]), np.array([1.0, 0.0]), 0.08, target="cube")
    assert cube.pose.p[0].numpy()[0] == before[0]  # built, not run
    steps = prims.executor.control_steps
    (res,) = drive(prims.executor.lockstep, [program])
    assert res.ok, res.reason
    assert res.moved >= 0.05 and cube.pose.p[0].numpy()[0] - before[0] >= 0.05
    assert res.sim_steps == (prims.executor.control_steps - steps) * cube_env.unwrapped._sim_steps_per_control
    with pytest.raises(ValueError, match="unknown primitive"):
        prims.program("throw", np.zeros(3))
    with pytest.raises(ValueError, match="env_idx"):
        MotionPrimitives(cube_env, env_idx=1)


@pytest.mark.gpu
def test_gpu_envs_slide_their_cubes_in_lockstep():
    env = gym.make("CubeToBin-v1", num_envs=4, obs_mode="state", control_mode="pd_joint_pos", sim_backend="physx_cuda")
    env.reset(seed=0)
    lockstep = LockstepExecutor(env, panda_spec())
    per_env = [MotionPrimitives(env, static_actors={"table-workspace", "ground", "bin"}, lockstep=lockstep, env_idx=i)
               for i in range(4)]
    cube = env.unwrapped.cube
    pose = cube.pose.raw_pose.clone()
    pose[:, :3] = torch.tensor([0.0, -0.05, 0.02], device=pose.device)
    cube.pose = pose
    before = cube.pose.p.cpu().numpy().copy()
    start = np.array([-0.045, -0.05, 0.015])
    programs = [p.program("slide", start, np.array([1.0, 0.0]), 0.08, target="cube") if i != 2 else None
                for i, p in enumerate(per_env)]
    results = drive(lockstep, programs)
    after = cube.pose.p.cpu().numpy()
    assert results[2] is None
    for i in (0, 1, 3):
        assert results[i].ok, results[i].reason
        assert after[i, 0] - before[i, 0] >= 0.05
    assert abs(after[2, 0] - before[2, 0]) < 0.005  # the idle env's arm held still
    env.close()
