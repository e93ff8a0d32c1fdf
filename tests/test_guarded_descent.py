"""Guarded descents: a grasp whose fingers strike a neighbour stops on the contact force instead of shoving it aside.

On the ``square_of_four`` locking layout (four 4.5 cm cubes 1 mm apart) a grasp across a cube's centre lands the
open fingers on its neighbours. Unguarded, the descent goes to grasp depth and pushes a neighbour by centimetres;
guarded (``guard_force``), it stops at the first contact, the primitive fails at its ``descend`` stage with the force
in its reason, and the neighbours stay nearly where they were.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from maniskill_pnp.planning.primitives import MotionPrimitives, grasp_pose
from maniskill_pnp.scenes.complicated_layouts import complicated_layout_files

from conftest import CPU

GUARD_N = 20.0


@pytest.fixture(scope="module")
def square_env():
    path = next(p for p in complicated_layout_files() if p.stem == "square_of_four")
    env = gym.make("ClutterGrasp-v1", layout_file=str(path), **CPU)
    yield env
    env.close()


def _grasp_across_a_cube(env, guard: float | None) -> tuple[object, float]:
    """Grasp across cube 2's centre with the jaws closing along x; returns the pick result and the farthest (m) a
    neighbour moved."""
    env.reset(seed=0)
    u = env.unwrapped
    names = [u.clutter.names[i] for i in u.clutter.active_index[0]]
    before = {n: u.scene.actors[n].pose.p[0].numpy().copy() for n in names}
    xyz = before[names[2]].copy()
    xyz[2] = u.workspace.grasp_tcp_height(0.04)
    prims = u._primitives()[0]
    prims.guard_force = guard
    result = prims.pick(grasp_pose(xyz, 0.0), target=None)
    moved = max(float(np.linalg.norm((u.scene.actors[n].pose.p[0].numpy() - before[n])[:2])) for n in names[:2] + names[3:])
    prims.go_home()
    return result, moved


#: How far a neighbour must move for a failed grasp to count as a push (m): ten times the layout's 1 mm gap, far
#: beyond contact jitter; a shove moved cubes by 26-77 mm where it was measured.
PUSHED_M = 0.01


def test_a_guarded_descent_stops_on_the_neighbour_an_unguarded_one_shoves(square_env):
    """The same grasp from the same scene, unguarded and then guarded: both references come from this run."""
    result, shoved = _grasp_across_a_cube(square_env, None)
    assert result.stage != "descend" and not result.grasped
    assert shoved > PUSHED_M  # the failed grasp acted as a push
    result, moved = _grasp_across_a_cube(square_env, GUARD_N)
    assert result.stage == "descend" and not result.grasped
    assert "guarded move stopped on contact" in result.reason and f"limit {GUARD_N:g} N" in result.reason
    assert moved < min(PUSHED_M, shoved / 3)  # stopped at the first contact: at most a nudge


def test_guard_force_must_be_positive(square_env):
    with pytest.raises(ValueError, match="guard_force must be a positive force"):
        MotionPrimitives(square_env, guard_force=0.0)
    with pytest.raises(ValueError, match="guard_force must be a positive force"):
        gym.make("ClutterGrasp-v1", guard_force=-1.0, num_objects=2)
