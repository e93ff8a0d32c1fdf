"""The lockstep executor: per-env trajectories padded to a common clock, finished envs holding still.

The padding is checked on hand-made trajectories; the executor on a real CPU ManiSkill env with ``num_envs = 1``
(the code path the tasks' primitives use through ``SimExecutor``) and, where a GPU is present, on 4 GPU envs.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from maniskill_pnp.planning import LockstepExecutor, SimExecutor, pad_trajectories, panda_spec


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
