"""Rolling resistance: Coulomb's rolling friction of spheres on the table (which PhysX leaves out) stops a rolling
sphere where the law says, in a bare physics scene and in the clutter tasks; cylinders collide as prisms, which do
not gain speed as they roll."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.objects import CYLINDER_SIDES, ObjectSpec, add_collisions
from maniskill_pnp.scenes.rolling import LEVER_ARM, RollingResistance, stopping_distance

FREQ = 100  # the tasks' physics rate
CPU = dict(sim_backend="physx_cpu", render_backend="cpu")


def _roll(spec: ObjectSpec, speed: float, model: RollingResistance | None, seconds: float = 4.0, lying: bool = False):
    """Distance (m) ``spec`` rolls along x on a table from ``speed`` (rolling without slipping), and its top speed."""
    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
    scene.set_timestep(1.0 / FREQ)
    material = sapien.physx.PhysxMaterial(0.3, 0.3, 0.0)  # ManiSkill's default material
    table = scene.create_actor_builder()
    table.add_box_collision(pose=sapien.Pose(p=[0, 0, -0.05]), half_size=[5, 5, 0.05], material=material)
    table.build_static(name="table")
    builder = scene.create_actor_builder()
    add_collisions(builder, spec, material=material)
    radius = spec.size[0]
    turn = [math.cos(math.pi / 4), math.sin(math.pi / 4), 0, 0] if lying else [1, 0, 0, 0]  # a cylinder's axis along y
    builder.initial_pose = sapien.Pose(p=[0, 0, radius + 1e-3], q=turn)
    body = builder.build(name="object").find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
    bodies = [(body, radius)]
    for _ in range(30):  # come to rest on the table
        model and model.apply(bodies, 1.0 / FREQ)
        scene.step()
    body.set_linear_velocity([speed, 0, 0])
    body.set_angular_velocity([0, speed / radius, 0])
    x0, top = body.entity.pose.p[0], 0.0
    for _ in range(int(seconds * FREQ)):
        model and model.apply(bodies, 1.0 / FREQ)
        scene.step()
        top = max(top, float(np.linalg.norm(body.linear_velocity)))
    return float(body.entity.pose.p[0] - x0), top, float(np.linalg.norm(body.linear_velocity))


@pytest.mark.parametrize("radius, speed", [(0.015, 0.3), (0.025, 0.2)])
def test_a_sphere_stops_where_coulombs_rolling_friction_says(radius, speed):
    sphere = ObjectSpec("sphere", (radius,))
    distance, _, final = _roll(sphere, speed, RollingResistance(table_z=0.0))
    expected = stopping_distance(speed, radius)
    assert final < 1e-3 and distance == pytest.approx(expected, rel=0.1)  # SAPIEN's angular damping adds a little
    free, _, still = _roll(sphere, speed, None)  # PhysX alone: it keeps rolling
    assert free > 10 * expected and still > 0.8 * speed


def test_the_model_is_a_bounded_torque_against_the_horizontal_spin_on_the_table_only():
    model = RollingResistance(table_z=0.0)
    m, r, inertia, dt = 0.03, 0.02, 0.4 * 0.03 * 0.02**2, 0.01
    tau = model.torque(np.array([0, 0, r]), np.array([0.0, 10.0, 3.0]), r, m, inertia, dt)
    assert tau == pytest.approx([0.0, -LEVER_ARM * m * 9.81, 0.0])  # against the spin about y; none about z
    slow = model.torque(np.array([0, 0, r]), np.array([1e-4, 0.0, 0.0]), r, m, inertia, dt)
    assert slow == pytest.approx([-inertia * 1e-4 / dt, 0.0, 0.0])  # stops the spin within the step, no further
    assert not model.torque(np.array([0, 0, r + 0.01]), np.array([0.0, 10.0, 0.0]), r, m, inertia, dt).any()
    assert not RollingResistance(0.0, lever_arm=0.0).torque(np.array([0, 0, r]), np.array([0, 10.0, 0]), r, m, inertia, dt).any()
    with pytest.raises(ValueError, match="rolling lever arm"):
        RollingResistance(0.0, lever_arm=-1e-3)


def test_a_lying_cylinder_collides_as_a_prism_and_does_not_gain_speed():
    cylinder = ObjectSpec("cylinder", (0.02, 0.03))
    assert len(cylinder.mesh_vertices()) == 2 * CYLINDER_SIDES
    distance, top, final = _roll(cylinder, 0.1, None, lying=True)
    assert top < 0.15 and final < 0.01 and distance < 0.3  # SAPIEN's own cylinder shape runs at 0.5 m/s by now


@pytest.mark.parametrize("lever_arm", [LEVER_ARM, 0.0])
def test_the_clutter_tasks_apply_it_to_their_spheres(lever_arm):
    ws = WorkspaceSpec(heightmap_size=32, pixel_size=0.448 / 32, num_rotations=2)
    radius, speed = 0.02, 0.2
    centre = (*ws.center, radius)
    e = gym.make("ClutterGrasp-v1", workspace=ws, layout=[(ObjectSpec("sphere", (radius,)), centre)],
                 rolling_lever_arm=lever_arm, **CPU)
    try:
        u = e.unwrapped
        e.reset(seed=0)
        (actor,) = u.clutter.active_actors[0]
        x0 = float(actor.pose.p[0, 0])
        actor.set_linear_velocity(torch.tensor([[speed, 0.0, 0.0]]))
        actor.set_angular_velocity(torch.tensor([[0.0, speed / radius, 0.0]]))
        for _ in range(40):  # 2 s of control steps, the arm holding still
            u._step_action(None)
        rolled = float(actor.pose.p[0, 0]) - x0
    finally:
        e.close()
    if lever_arm:
        assert rolled == pytest.approx(stopping_distance(speed, radius), rel=0.15)
    else:
        assert rolled > 0.3  # PhysX alone
    with pytest.raises(ValueError, match="rolling_lever_arm"):
        gym.make("ClutterGrasp-v1", rolling_lever_arm="wood", **CPU)
