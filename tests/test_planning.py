"""The OMPL motion layer on a real ManiSkill scene: collision world, IK, plans, cache, primitives."""

from __future__ import annotations

import numpy as np
import pytest
import sapien

from maniskill_pnp.planning import MotionPrimitives, PlanCache, SegmentResult, grasp_pose
from maniskill_pnp.planning.primitives import PlaceRegion
from maniskill_pnp.cell.bin import BinSpec
from maniskill_pnp.scenes.clutter import object_status
from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.planning.trajectory import densify, time_parameterize

STATIC = {"table-workspace", "ground", "bin"}


def _prims(env, seed=0, **kw):
    env.reset(seed=seed)
    return MotionPrimitives(env, static_actors=STATIC, seed=seed, **kw)


def _cube_grasp(env):
    cube = env.unwrapped.cube.pose
    p, q = cube.p[0].numpy(), cube.q[0].numpy()
    return grasp_pose(p, yaw=2 * np.arctan2(q[3], q[0]))


def test_collision_world_mirrors_scene(cube_env):
    prims = _prims(cube_env)
    world = prims.world
    world.sync_scene(cube_env.unwrapped.scene)
    kinds = {name: {ob.kind for ob in obs} for name, obs in world.obstacles.items()}
    assert kinds["table-workspace"] == {"box"} and kinds["cube"] == {"box"} and kinds["bin"] == {"box"}
    assert len(world.obstacles["bin"]) == 5  # floor and four walls
    assert world.is_valid(prims.executor.qpos())
    before = world.fingerprint()
    cube = cube_env.unwrapped.cube
    cube.set_pose(sapien.Pose(p=[0.1, 0.1, 0.02]))
    world.sync_scene(cube_env.unwrapped.scene)
    assert world.fingerprint() != before
    # Reaching down through the table is a collision with the table, named as such.
    q = prims.executor.qpos().copy()
    q[1] += 1.2
    assert not world.is_valid(q)
    assert any(other == "table-workspace" for _, other in world.collisions(q))


def test_ik_prefers_current_configuration(cube_env):
    prims = _prims(cube_env)
    q0 = prims.executor.qpos()
    res = prims.kin.ik(prims.kin.fk(q0), q0)
    assert res.ok and np.max(np.abs(res.q - q0)) < 1e-2
    far = prims.kin.ik(sapien.Pose(p=[1.5, 0.0, 0.05], q=prims.kin.fk(q0).q), q0)
    assert not far.ok and "IK" in far.reason


def test_plan_around_wall_is_collision_free_in_checker_and_simulator(wall_env):
    prims = _prims(wall_env)
    prims.world.sync_scene(wall_env.unwrapped.scene)
    q_home = prims.executor.qpos()
    down = prims.kin.fk(q_home).q
    a = prims.kin.ik(sapien.Pose(p=[0.15, -0.2, 0.08], q=down), q_home)
    b = prims.kin.ik(sapien.Pose(p=[0.15, 0.2, 0.08], q=down), q_home)
    assert a.ok and b.ok
    assert not prims.world.segment_valid(a.q, b.q), "the wall must block the straight joint-space segment"
    assert prims.planner.plan(q_home, a.q).ok
    res = prims.planner.plan(a.q, b.q)
    assert res.ok and not res.cached, res.reason
    dense = densify(res.path, max_step=0.01)
    assert all(prims.world.is_valid(q) for q in dense)
    assert np.allclose(res.path[0], a.q) and np.allclose(res.path[-1], b.q)

    # Execute start → a → b in the simulator and watch the wall's contacts with every robot link.
    scene, wall = wall_env.unwrapped.scene, wall_env.unwrapped.obstacles[0]
    links = wall_env.unwrapped.agent.robot.get_links()
    touches = []

    def watch():
        for link in links:
            force = float(scene.get_pairwise_contact_forces(link, wall).norm())
            if force > 0:
                touches.append((prims.executor.control_steps, link.name, force, prims.executor.qpos().round(3).tolist()))

    prims.executor.on_control_step = watch
    go_a = prims.move_to(a.q)
    go_b = prims.move_to(b.q)
    assert go_a.ok and go_b.ok, (go_a.reason, go_b.reason)
    assert not touches, f"the arm touched the wall in simulation: {touches[:3]}; stages {go_a.stages} {go_b.stages}"
    assert np.max(np.abs(prims.executor.qpos() - b.q)) < 0.02


def _either_side_of_the_wall(env):
    """Primitives synced to the wall scene, and IK goals in front of the wall's two sides."""
    prims = _prims(env)
    prims.world.sync_scene(env.unwrapped.scene)
    q_home = prims.executor.qpos()
    down = prims.kin.fk(q_home).q
    a = prims.kin.ik(sapien.Pose(p=[0.15, -0.2, 0.08], q=down), q_home).q
    b = prims.kin.ik(sapien.Pose(p=[0.15, 0.2, 0.08], q=down), q_home).q
    return prims, a, b


def test_plan_cache_reuses_only_in_the_same_scene(wall_env):
    prims, a, b = _either_side_of_the_wall(wall_env)
    first = prims.planner.plan(a, b)
    again = prims.planner.plan(a, b)
    assert first.ok and again.cached and np.array_equal(first.path, again.path)
    # Move the cube: the scene fingerprint changes, so the saved plan is not looked up under the new key.
    wall_env.unwrapped.cube.set_pose(sapien.Pose(p=[0.15, -0.15, 0.02]))
    prims.world.sync_scene(wall_env.unwrapped.scene)
    moved = prims.planner.plan(a, b)
    assert moved.ok and not moved.cached


def test_a_query_gives_the_same_plan_whatever_was_planned_before(wall_env):
    # OMPL's generators are process-wide; each query reseeds them from its own start, goal and scene, so a search
    # does not depend on how many were run before it (what a reproducible episode needs).
    prims, a, b = _either_side_of_the_wall(wall_env)
    prims.planner.cache = None
    first = prims.planner.plan(a, b)
    for _ in range(3):
        assert prims.planner.plan(b, a).ok
    again = prims.planner.plan(a, b)
    assert first.ok and len(first.path) >= 2 and np.array_equal(first.path, again.path)
    other_seed = MotionPrimitives(wall_env, static_actors=STATIC, seed=1)
    other_seed.world.sync_scene(wall_env.unwrapped.scene)
    other_seed.planner.cache = None
    assert other_seed.planner.plan(a, b).ok


def test_planner_falls_back_to_the_raw_path_when_the_simplified_one_fails_the_final_check(wall_env, monkeypatch):
    # About one simplified path in ten hugs the wall so closely that the final dense check, which samples the
    # motion at other points than OMPL did, finds a contact. Reject the first (simplified) path to force that case.
    prims, a, b = _either_side_of_the_wall(wall_env)
    prims.planner.cache = None
    world = prims.world
    checked, real_check = [], world.path_valid

    def first_path_grazes(path, *args, **kwargs):
        checked.append(len(path))
        return len(checked) > 1 and real_check(path, *args, **kwargs)

    monkeypatch.setattr(world, "path_valid", first_path_grazes)
    res = prims.planner.plan(a, b)
    assert res.ok, res.reason
    assert len(checked) == 2 and checked[1] >= checked[0], "the second path checked is the raw, unsimplified one"
    assert len(res.path) == checked[1] and real_check(res.path)


def test_plan_cache_is_bounded():
    cache = PlanCache(capacity=2)
    for i in range(3):
        cache.put(cache.key(np.zeros(7) + i, np.ones(7), "scene"), np.zeros((2, 7)))
    assert len(cache) == 2
    assert cache.get(cache.key(np.zeros(7), np.ones(7), "scene")) is None
    with pytest.raises(ValueError, match="capacity"):
        PlanCache(capacity=0)


def test_pick_and_place_succeeds_in_9_of_10_seeds(cube_env):
    successes, steps = 0, []
    for seed in range(10):
        prims = _prims(cube_env, seed=seed)
        pick = prims.pick(_cube_grasp(cube_env), target="cube")
        if pick.ok:
            assert pick.grasped and pick.held == "cube"
            place = prims.place(cube_env.unwrapped.bin_spec.region())
            assert place.held_at_release is True  # the jaws still felt the cube when they opened over the bin
            home = prims.go_home()
            steps.append(pick.sim_steps + place.sim_steps + home.sim_steps)
            successes += int(place.ok and bool(cube_env.unwrapped.evaluate()["success"].item()))
    assert successes >= 9, f"{successes}/10 pick-and-place successes"


def test_a_gripper_command_ends_once_the_fingers_stop(cube_env):
    """Closing on the cube, the fingers stall within a few control steps and the command ends there (not after all
    12), the cube held; opening over the bin ends when the fingers are nearly open; closing on nothing ends when the
    fingers meet."""
    prims = _prims(cube_env)
    lock = prims.executor.lockstep
    run, steps = lock.run, {}

    def counted(motions):
        m, c0 = motions[0], lock.control_steps
        out = run(motions)
        if m is not None and m.targets is None and m.gripper is not None and m.min_steps:
            steps.setdefault(m.gripper, []).append(lock.control_steps - c0)
        return out

    lock.run = counted
    most = MotionPrimitives.GRIPPER_STEPS
    pick = prims.pick(_cube_grasp(cube_env), target="cube")
    assert pick.ok and pick.grasped and 3 <= steps[-1.0][0] < most, (pick.reason, steps)
    assert prims.jaws_on_something()
    place = prims.place(cube_env.unwrapped.bin_spec.region())
    assert place.ok and steps[1.0][0] < most, steps
    assert np.min(prims.executor.finger_qpos()) >= prims.arm.gripper_open - MotionPrimitives.OPEN_ENOUGH
    prims.slide(np.array([0.0, 0.1, 0.015]), direction=np.array([1.0, 0.0]), length=0.02)  # closes the jaws on nothing
    assert steps[-1.0][-1] < most and np.max(prims.executor.finger_qpos()) < 0.001, steps


def test_grasp_sensor_reports_an_empty_grasp(cube_env):
    prims = _prims(cube_env)
    pose = _cube_grasp(cube_env)
    empty = grasp_pose(pose.p + np.array([0.0, 0.12, 0.0]), 0.0)  # 12 cm beside the cube: nothing to grasp
    res = prims.pick(empty)
    assert not res.ok and not res.grasped and res.stage == "grasp_check"
    assert "nothing" in res.reason


def test_slide_pushes_cube_along_direction(cube_env):
    prims = _prims(cube_env, seed=3)
    cube = cube_env.unwrapped.cube
    cube.set_pose(sapien.Pose(p=[0.0, -0.05, 0.02]))
    start = np.array([-0.045, -0.05, 0.015])
    before = cube.pose.p[0].numpy().copy()
    res = prims.slide(start, direction=np.array([1.0, 0.0]), length=0.08, target="cube")
    assert res.ok, res.reason
    delta = cube.pose.p[0].numpy() - before
    assert res.moved >= 0.05 and delta[0] >= 0.05 and abs(delta[1]) < 0.02


def test_unreachable_target_is_a_failure_result_not_an_exception(cube_env):
    prims = _prims(cube_env)
    res = prims.pick(grasp_pose(np.array([1.6, 0.0, 0.02]), 0.0), target="cube")
    assert not res.ok and res.stage == "pregrasp_ik" and res.reason
    res = prims.slide(np.array([1.6, 0.0, 0.02]), np.array([0.0, 1.0]))
    assert not res.ok and res.stage == "preslide_ik"
    res = prims.place(cube_env.unwrapped.bin_spec.region())
    assert not res.ok and res.stage == "input" and "nothing is held" in res.reason
    res = prims.pick(_cube_grasp(cube_env), target="no_such_object")
    assert not res.ok and res.stage == "input" and "no_such_object" in res.reason


def test_time_parameterization_falls_back_to_constant_speed_when_toppra_fails(monkeypatch):
    from maniskill_pnp.planning import trajectory

    def fails(*args):  # as TOPP-RA does on some paths
        raise RuntimeError("Fail to parameterize path")

    monkeypatch.setattr(trajectory, "toppra_samples", fails)
    path = np.array([[0.0, 0.0], [0.3, -0.1], [0.3, 0.5]])
    qs = time_parameterize(path, dt=0.05, max_velocity=1.0, max_acceleration=2.0)
    steps = np.abs(np.diff(np.vstack([path[:1], qs]), axis=0)).max(axis=1)
    assert np.allclose(qs[-1], path[-1]) and steps.max() <= 1.0 * 0.05 + 1e-9
    assert len(qs) == int(np.ceil(0.3 / 0.05)) + int(np.ceil(0.6 / 0.05))  # the fastest joint at full speed throughout


def test_a_straight_joint_segment_takes_toppras_profile_in_closed_form(cube_env):
    from maniskill_pnp.planning.trajectory import straight_segment

    prims = _prims(cube_env)
    arm = prims.arm
    rng = np.random.default_rng(0)
    for _ in range(6):  # long (cruising) and short (triangular) moves between random configurations
        q0 = rng.uniform(arm.lower, arm.upper)
        q1 = q0 + (q0 - rng.uniform(arm.lower, arm.upper)) * rng.choice([0.05, 0.6])
        q1 = arm.clip(q1)
        fast = time_parameterize(np.stack([q0, q1]), 0.05, arm.max_velocity, arm.max_acceleration)
        slow = time_parameterize(np.stack([q0, (q0 + q1) / 2, q1]), 0.05, arm.max_velocity, arm.max_acceleration)
        assert len(fast) == len(slow) and np.abs(fast - slow).max() < 2e-4
        np.testing.assert_array_equal(fast[-1], q1)
    assert straight_segment(q0, q0 + 1e-8, 0.05, 1.5, 2.0).shape == (1, arm.arm_joints)  # no motion: the end
    with pytest.raises(ValueError, match="must be > 0"):
        straight_segment(q0, q1, 0.05, 0.0, 2.0)


def test_toppra_samples_are_mplibs_to_the_bit(cube_env):
    """toppra called directly (constraints built once per limits, gridpoints a pass at a time, TOPP-RA's two passes
    run by path_velocities) samples the trajectory of mplib's TOPP, at both arm limits."""
    from maniskill_pnp.planning.trajectory import densify, toppra_samples

    prims = _prims(cube_env)
    arm, planner = prims.arm, prims.world.mplib_planner
    planner.joint_vel_limits, planner.joint_acc_limits = np.full(7, arm.max_velocity), np.full(7, arm.max_acceleration)
    rng = np.random.default_rng(1)
    for scale in (0.01, 0.05, 0.2, 0.05):  # a bent path of 12 waypoints at each scale; the limits' constraints reused
        q0 = rng.uniform(arm.lower, arm.upper) * 0.5
        path = densify(np.vstack([q0, q0 + np.cumsum(rng.normal(0.0, scale, (11, 7)), axis=0)]))
        for v, a in ((arm.max_velocity, arm.max_acceleration), (arm.free_velocity, arm.free_acceleration)):
            planner.joint_vel_limits, planner.joint_acc_limits = np.full(7, v), np.full(7, a)
            _, ref, _, _, _ = planner.TOPP(path, step=0.05)
            np.testing.assert_array_equal(toppra_samples(path, 0.05, v, a), ref)


def test_gridpoints_are_toppras_own_to_the_bit():
    """The gridpoints checked a pass at a time are those toppra proposes one segment at a time (with TOPP-RA's
    defaults), for smooth and rough paths of 2 to 60 waypoints, some long enough to be split for length alone."""
    import toppra
    from toppra.interpolator import propose_gridpoints

    from maniskill_pnp.planning.trajectory import gridpoints

    rng = np.random.default_rng(4)
    sizes = set()
    for k in range(40):
        n = int(rng.integers(2, 61))
        path = np.cumsum(rng.normal(0.0, (0.005, 0.05, 0.3)[k % 3], (n, 7)), axis=0)
        spline = toppra.SplineInterpolator(np.linspace(0, 1, n), path)
        ours = gridpoints(spline)
        np.testing.assert_array_equal(ours, np.array(propose_gridpoints(spline, max_err_threshold=1e-3, min_nb_points=100)))
        sizes.add(len(ours))
    assert min(sizes) < 200 < max(sizes)  # refined by curvature, not only halved to the minimum count


def test_a_free_motion_starting_against_a_movable_object_moves_away_from_it(cube_env):
    """A failed lift or retract can leave the fingers touching an object; the next free-space motion (e.g. the way
    home) must not fail on its start configuration: the objects the arm touches at the start are no obstacles."""
    prims = _prims(cube_env)
    q_start = prims.executor.qpos()
    finger = cube_env.unwrapped.agent.finger1_link.pose.p[0].numpy()
    cube_env.unwrapped.cube.set_pose(sapien.Pose(p=finger))  # the cube inside the finger: the start collides
    prims.world.sync_scene(cube_env.unwrapped.scene)
    assert ("panda_leftfinger", "cube") in prims.world.collisions(q_start)
    goal = q_start.copy()
    goal[0] += 0.6
    res = prims.move_to(goal)
    assert res.ok, res.reason
    assert "leaving ['cube'] that the arm touched at the start" in res.stages[-1][2]
    assert np.abs(prims.executor.qpos() - goal).max() < 0.05


def test_place_releases_higher_when_the_drop_pose_collides(cube_env):
    """A drop height at the bin's floor puts the held cube into the floor: the place releases it higher instead."""
    prims = _prims(cube_env, seed=0)
    pick = prims.pick(_cube_grasp(cube_env), target="cube")
    assert pick.ok, pick.reason
    region = cube_env.unwrapped.bin_spec.region()
    low = PlaceRegion(center=region.center, half_size=region.half_size, drop_height=0.0)
    place = prims.place(low)
    assert place.ok, place.reason
    assert bool(cube_env.unwrapped.evaluate()["success"].item())
    prims = _prims(cube_env, seed=0)
    prims.PLACE_LIFTS = (0.0,)  # without the higher poses the same place fails at its IK
    assert prims.pick(_cube_grasp(cube_env), target="cube").ok
    place = prims.place(low)
    assert not place.ok and place.stage == "place_ik" and "collides" in place.reason


def _no_straight_line_up_past(prims, rise):
    """Make every straight line that rises more than ``rise`` (m) invalid, as a singularity would."""
    straight = prims.kin.straight_line

    def limited(q_start, goal, **kw):
        if goal.p[2] - prims.kin.fk(q_start).p[2] > rise:
            return SegmentResult(None, "straight line passes a singularity (joint jump) at 90%")
        return straight(q_start, goal, **kw)

    prims.kin.straight_line = limited


def test_a_lift_without_a_straight_line_lifts_lower(cube_env):
    """A grasp whose full lift meets a singularity lifts by the first fallback height instead and still places."""
    prims = _prims(cube_env, seed=0)
    _no_straight_line_up_past(prims, 0.12)
    pick = prims.pick(_cube_grasp(cube_env), target="cube")
    assert pick.ok and pick.grasped, pick.reason
    lift = [s for s in pick.stages if s[0] == "lift"]
    assert lift and lift[0][1] and lift[0][2].startswith(f"{prims.LIFT_FALLBACKS[0]:.2f} m up")
    assert prims.place(cube_env.unwrapped.bin_spec.region()).ok
    assert bool(cube_env.unwrapped.evaluate()["success"].item())


def test_a_grasp_that_cannot_lift_opens_the_jaws_where_they_are(cube_env):
    """With no straight lift at all the jaws open before the failure, so the way home carries nothing away."""
    prims = _prims(cube_env, seed=0)
    _no_straight_line_up_past(prims, 0.02)
    z0 = float(cube_env.unwrapped.cube.pose.p[0, 2])
    pick = prims.pick(_cube_grasp(cube_env), target="cube")
    assert not pick.ok and pick.stage == "lift" and "the jaws opened where they were" in pick.reason
    assert prims.held is None and np.min(prims.executor.finger_qpos()) > 0.03
    assert prims.go_home().ok
    assert abs(float(cube_env.unwrapped.cube.pose.p[0, 2]) - z0) < 0.01  # still on the table


def test_the_bin_region_holds_the_pile_over_its_footprint():
    """An object resting on other objects in a filling bin is in the bin, up to 5 cm over the release height; one
    beside the bin at the same height, or one that was never released, is not."""
    spec = BinSpec()
    region = spec.region()
    cx, cy, cz = spec.center
    on_pile = np.array([cx + 0.05, cy - 0.05, cz + spec.wall_height + 0.1])
    assert region.contains(on_pile)
    assert not region.contains(on_pile + [2 * spec.inner_half_size[0], 0.0, 0.0])
    assert not region.contains(np.array([cx, cy, cz + region.drop_height + 0.1]))
    statuses = object_status(np.stack([on_pile, [cx, cy, cz + region.drop_height + 0.1]]), WorkspaceSpec(bin=spec))
    assert statuses == ["bin", "lost"]


def _pick_and_place_trace(direct: bool) -> tuple[np.ndarray, list]:
    """A pick, place and home of the cube in a new CubeToBin-v1 (its PhysX scene carries state across resets)."""
    import gymnasium as gym
    from conftest import CPU

    env = gym.make("CubeToBin-v1", obs_mode="state", control_mode="pd_joint_pos", **CPU)
    prims = _prims(env, seed=1)
    if not direct:
        prims.executor.lockstep._drives = None  # ManiSkill's agent.set_action every control step
    results = [prims.pick(_cube_grasp(env), target="cube"), prims.place(env.unwrapped.bin_spec.region()), prims.go_home()]
    state = np.concatenate([env.unwrapped.cube.pose.raw_pose[0].numpy(), env.unwrapped.agent.robot.get_qpos()[0].numpy()])
    env.close()
    return state, [(r.ok, r.stage, r.sim_steps) for r in results]


def test_direct_drive_targets_give_the_simulation_of_maniskills_set_action_bit_for_bit(cube_env):
    assert _prims(cube_env).executor.lockstep._drives is not None  # the CPU env takes the direct path
    direct, slow = _pick_and_place_trace(True), _pick_and_place_trace(False)
    assert direct[1] == slow[1] and direct[1][1][0], direct[1]  # the same stages, steps, and the cube placed
    np.testing.assert_array_equal(direct[0], slow[0])


def test_direct_drives_follow_a_reset_gripper(cube_env):
    prims = _prims(cube_env)
    prims.executor.gripper(-1.0, 10)
    assert np.max(prims.executor.finger_qpos()) < 0.03  # closed
    cube_env.reset(seed=0)  # ManiSkill's reset opens the fingers and resets the controllers; the executor is told
    prims.reset()
    prims.executor.gripper(-1.0, 10)  # the same command as before the reset must close them again
    assert np.max(prims.executor.finger_qpos()) < 0.03


def test_a_sync_reuses_the_shapes_of_unmoved_actors_and_places_moved_ones_anew(cube_env):
    """After syncs at both margins and a moved cube, the world answers as a fresh one synced once: the same
    obstacles, boxes and collisions."""
    import sapien

    from maniskill_pnp.planning.collision import CollisionWorld

    cube_env.reset(seed=0)
    prims = _prims(cube_env)
    world, cube, scene = prims.world, cube_env.unwrapped.cube, cube_env.unwrapped.scene
    rng = np.random.default_rng(3)
    qs = [world.arm.clip(prims.home + rng.normal(0.0, 0.8, world.arm.arm_joints)) for _ in range(60)]
    for margin in (0.0, 0.015, 0.0):
        world.sync_scene(scene, margin=margin)
    cube.set_pose(sapien.Pose(p=[0.05, -0.1, 0.02]))
    for margin in (0.015, 0.0, 0.015):
        world.sync_scene(scene, margin=margin)
        fresh = CollisionWorld(world.arm, base_pose=world.base_pose)
        fresh.sync_scene(scene, margin=margin)
        assert world.fingerprint() == fresh.fingerprint()
        np.testing.assert_array_equal(world._boxes, fresh._boxes)
        assert [world.is_valid(q) for q in qs] == [fresh.is_valid(q) for q in qs]
    assert len({world.is_valid(q) for q in qs}) == 2


def test_obstacles_out_of_the_arms_reach_stay_out_of_the_checks_but_in_the_fingerprint(cube_env):
    from maniskill_pnp.planning.robot import urdf_reach

    prims = _prims(cube_env)
    world, cube = prims.world, cube_env.unwrapped.cube
    arm = world.arm
    assert 1.2 < urdf_reach(arm.urdf) < 1.8 and urdf_reach(arm.urdf, arm.tcp_link) < urdf_reach(arm.urdf)
    cube.set_pose(sapien.Pose(p=[3.0, 0.0, 0.02]))  # 3.6 m from the base
    world.sync_scene(cube_env.unwrapped.scene)
    far = world.fingerprint()
    assert "cube" in world.obstacles and "cube#0" not in world._world.get_normal_object_names()
    cube.set_pose(sapien.Pose(p=[3.0, 0.1, 0.02]))
    world.sync_scene(cube_env.unwrapped.scene)
    assert world.fingerprint() != far  # a moved parked object is another scene for the plan cache
    cube.set_pose(sapien.Pose(p=[0.1, 0.1, 0.02]))  # within reach: checked again
    world.sync_scene(cube_env.unwrapped.scene)
    assert "cube#0" in world._world.get_normal_object_names()
    q = prims.executor.qpos().copy()
    assert world.is_valid(q)
    # A held object larger than the allowance brings every shape back into the checks.
    cube.set_pose(sapien.Pose(p=[3.0, 0.0, 0.02]))
    world.sync_scene(cube_env.unwrapped.scene)
    world.attach_box(np.array([0.2, 0.2, 0.2]), np.array([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0]))
    assert "cube#0" in world._world.get_normal_object_names()
    world.detach()


def test_segment_checks_answer_as_a_check_of_every_configuration(cube_env):
    """Stretches certified clear of the scene skip its test, and those certified clear of self-collision (nothing held)
    the self test; the answers are those of is_valid at every configuration, at both margins, with and without a held
    object, and some stretches are certified, and some not, either way."""
    from maniskill_pnp.planning.collision import bisection_order

    prims = _prims(cube_env)
    world = prims.world
    rng = np.random.default_rng(1)
    certified = []
    clear = world._sweep.clear
    world._sweep.clear = lambda *a: certified.append(clear(*a)) or certified[-1]
    answers = []
    try:
        for margin in (0.0, 0.015):
            for held in (False, True):
                world.sync_scene(cube_env.unwrapped.scene, margin=margin)
                if held:
                    world.attach_box(np.array([0.03, 0.02, 0.04]), np.array([0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0]))
                for k in range(12):
                    a = prims.home if k % 2 else rng.uniform(world.arm.lower, world.arm.upper)
                    b = world.arm.clip(prims.home + rng.normal(0.0, 0.6, world.arm.arm_joints))
                    n = max(1, int(np.ceil(np.max(np.abs(b - a)) / 0.005)))
                    every = all(world.is_valid(a + (b - a) * (i / n)) for i in bisection_order(n))
                    answers.append((world.segment_valid(a, b), every))
                world.detach()
    finally:
        world._sweep.clear = clear
    assert all(fast == every for fast, every in answers), answers
    assert any(v for v, _ in answers) and not all(v for v, _ in answers)
    scene, own = (np.array([c[k] for c in certified]) for k in (0, 1))
    assert scene.any() and not scene.all()
    assert own.any() and not own.all()


def test_mplibs_collision_test_is_its_self_test_or_its_scene_test(cube_env):
    """What the segment checks rely on to skip one of the two tests: at any configuration, with or without a held
    object, mplib's ``collide`` is true exactly when ``self_collide`` or ``collide_with_others`` finds a contact (both
    ways seen)."""
    world = _prims(cube_env).world
    rng = np.random.default_rng(2)
    seen = set()
    for held in (False, True):
        world.sync_scene(cube_env.unwrapped.scene)
        if held:
            world.attach_box(np.array([0.03, 0.02, 0.04]), np.array([0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0]))
        for _ in range(200):
            world._set(rng.uniform(world.arm.lower, world.arm.upper))
            own, others = bool(world._world.self_collide()), bool(world._world.collide_with_others())
            assert world._world.collide() == (own or others)
            seen |= {name for name, hit in (("self", own), ("scene", others)) if hit}
        world.detach()
    assert seen == {"self", "scene"}


def test_ompl_motions_get_the_answers_of_ompls_own_validator(wall_env):
    """The swept motion validator answers OMPL's motion checks as OMPL's DiscreteMotionValidator does (motions from
    the wall's one side and from random states; some pass, some do not), and RRT-Connect around the wall plans the
    same path with either."""
    from maniskill_pnp.planning.rrt import JointSpacePlanner

    prims, a, b = _either_side_of_the_wall(wall_env)
    world = prims.world
    swept, plain = (JointSpacePlanner(world, swept_motions=s, cache=None) for s in (True, False))
    rng = np.random.default_rng(3)
    answers = []
    for k in range(40):
        q0 = a if k % 2 else rng.uniform(world.arm.lower, world.arm.upper)
        q1 = world.arm.clip(q0 + rng.normal(0.0, 0.5, world.arm.arm_joints))
        s0, s1 = plain._state(q0), plain._state(q1)
        answers.append((swept._setup.getSpaceInformation().checkMotion(s0, s1),
                        plain._setup.getSpaceInformation().checkMotion(s0, s1)))
    assert all(fast == ompl for fast, ompl in answers), answers
    assert any(v for v, _ in answers) and not all(v for v, _ in answers)
    assert not world.segment_valid(a, b)  # the wall is in the way: the query needs RRT-Connect
    fast, ompl = swept.plan(a, b), plain.plan(a, b)
    assert fast.ok and len(fast.path) > 2 and np.array_equal(fast.path, ompl.path)


def test_free_motions_take_the_free_limits_and_straight_moves_the_contact_ones(cube_env):
    """Slower free-space limits stretch the planned motion to the pre-grasp, not the straight descent."""
    import re
    from dataclasses import replace

    from maniskill_pnp.planning import panda_spec

    steps = {}
    for free in (panda_spec().free_velocity, 0.5):
        prims = _prims(cube_env, arm=replace(panda_spec(), free_velocity=free))
        pick = prims.pick(_cube_grasp(cube_env), target="cube")
        assert pick.ok, pick.reason
        steps[free] = {stage: int(re.search(r"(\d+) control steps", detail).group(1))
                       for stage, _, detail in pick.stages if "control steps" in detail}
    fast, slow = steps[panda_spec().free_velocity], steps[0.5]
    assert slow["move_to_pregrasp"] > fast["move_to_pregrasp"]
    assert slow["descend"] == fast["descend"] and slow["lift"] == fast["lift"]


def test_covering_balls_hold_the_convex_hull_of_a_link_and_are_smaller_than_its_one_ball():
    """Every point of the hull (points mixed at random, and the hull's vertices) lies in one of the balls, for random
    clouds and the Panda's own links; the balls of the forearm and the hand are about half the one ball's size."""
    from maniskill_pnp.planning.robot import covering_balls, panda_spec, urdf_link_bounds

    rng = np.random.default_rng(5)
    clouds = [rng.normal(0.0, (0.2, 0.05, 0.03), (40, 3)), rng.uniform(-0.1, 0.1, (8, 3)), rng.normal(0.0, 0.1, (3, 3))]
    for points in clouds:
        balls = covering_balls(points)
        weights = rng.dirichlet(np.full(len(points), 0.3), size=3000)
        inside = np.vstack([points, weights @ points])
        gaps = np.stack([np.linalg.norm(inside - c, axis=1) - r for c, r in balls])
        assert (gaps.min(axis=0) <= 1e-12).all()
    bounds = urdf_link_bounds(panda_spec().urdf)
    for name in ("panda_link5", "panda_hand"):
        assert max(r for _, r in bounds[name].balls) < 0.6 * bounds[name].radius


def test_actor_pose_reads_manisklls_own_pose_without_tensors(cube_env):
    """On the CPU the entity's pose is what ``actor.pose`` copies into tensors: the same float32 values."""
    from maniskill_pnp.planning.collision import actor_pose

    cube_env.reset(seed=1)
    for actor in cube_env.unwrapped.scene.actors.values():
        pose = actor_pose(actor)
        np.testing.assert_array_equal(np.concatenate([pose.p, pose.q]), actor.pose.raw_pose[0].numpy())
