"""ClutterGrasp-v1: registration, spaces, seeded resets, bad actions and options, and the oracle clearing a scene."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.tasks import LOSS_CAUSES, OUTCOME_KEYS, TASK_IDS, ClutterGraspEnv
from maniskill_pnp.tasks.clutter_grasp import loss_causes
from maniskill_pnp.agents.scripted.clutter_oracle import HeightmapGraspOracle
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.cell.workspace import WorkspaceSpec

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
N = 16 * 224 * 224


@pytest.fixture(scope="module")
def env():
    """A loosely packed clutter of 4 objects."""
    e = gym.make("ClutterGrasp-v1", num_objects=4, **CPU)
    yield e
    e.close()


def test_id_resolves_to_our_class(env):
    assert "ClutterGrasp-v1" in TASK_IDS
    assert isinstance(env.unwrapped, ClutterGraspEnv)
    assert env.unwrapped.single_action_space == gym.spaces.Discrete(N)


def test_reset_gives_heightmaps_and_is_reproducible(env):
    obs, info = env.reset(seed=3)
    assert obs["color_heightmap"].shape == (1, 224, 224, 3) and obs["color_heightmap"].dtype == torch.uint8
    assert obs["depth_heightmap"].shape == (1, 224, 224) and obs["depth_heightmap"].dtype == torch.float32
    assert env.unwrapped.single_observation_space["depth_heightmap"].shape == (224, 224)
    assert info["objects_remaining"] == 4 and info["lost_objects"] == 0 and info["num_actions"] == 0
    names = list(env.unwrapped.clutter.active[0])
    other, _ = env.reset(seed=4)
    again, _ = env.reset(seed=3)
    assert env.unwrapped.clutter.active[0] == names
    assert not torch.equal(other["depth_heightmap"], obs["depth_heightmap"])
    assert torch.allclose(again["depth_heightmap"], obs["depth_heightmap"], atol=1e-3)
    assert (again["color_heightmap"].int() - obs["color_heightmap"].int()).abs().float().mean() < 1.0


@pytest.mark.parametrize(
    "action",
    [-1, N, 3.0, float("nan"), np.array([1, 2]), np.zeros((1, 1, 1), dtype=np.int64), torch.tensor(0.5), True, "7"],
)
def test_bad_actions_raise_before_moving(env, action):
    env.reset(seed=0)
    q0 = env.unwrapped.agent.robot.get_qpos().clone()
    with pytest.raises(ValueError, match=f"0..{N - 1}"):
        env.step(action)
    assert torch.equal(env.unwrapped.agent.robot.get_qpos(), q0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(num_objects=0), "num_objects"),
        (dict(num_objects=(5, 3)), "num_objects"),
        (dict(num_objects="crowded"), "density preset"),
        (dict(num_envs=2), "num_envs=2 needs ManiSkill.s GPU simulation"),  # CPU pins the CPU backend
        (dict(object_kinds=("torus",)), "object_kinds"),
        (dict(control_mode="pd_ee_delta_pose"), "pd_joint_pos"),
        (dict(obs_mode="state"), "obs_mode"),
        (dict(loss_cost=-1.0), "loss_cost must be a finite number >= 0"),
        (dict(loss_cost=float("nan")), "loss_cost must be a finite number >= 0"),
        (dict(layout=[(ObjectSpec("cuboid", (0.02, 0.02, 0.02)), (-0.06, -0.1, 0.02))] * 2), "overlap"),
    ],
)
def test_bad_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("ClutterGrasp-v1", **kwargs, **CPU)


def test_bad_workspace_options_raise():
    with pytest.raises(ValueError, match="num_rotations"):
        WorkspaceSpec(num_rotations=7)
    with pytest.raises(ValueError, match="heightmap_size"):
        WorkspaceSpec(heightmap_size=0)


def test_oracle_clears_a_loose_scene(env):
    """The heightmap-only oracle empties a 4-object loosely packed clutter into the bin."""
    oracle = HeightmapGraspOracle(env.unwrapped.workspace)
    obs, info = env.reset(seed=1)
    grasps, steps = 0, 0
    terminated = truncated = False
    while not (terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(oracle(obs["depth_heightmap"][0]))
        steps += 1
        grasps += int(info["grasp_success"].item())
        for key in OUTCOME_KEYS:
            assert info[key].shape == (1,), key
        assert reward.item() == (1.0 if info["place_success"] else 0.5 if info["grasp_success"] else 0.0)
        assert {"objects_remaining", "num_actions", "consecutive_failures", "lost_objects", "stage", "reason"} <= set(info)
    assert terminated and info["objects_remaining"] == 0
    assert info["objects_in_bin"] >= 3 and info["lost_objects"] <= 1
    assert grasps / steps >= 0.6  # two misses in five at most: the oracle grasped 97.6% in random clutter (experiments.md)


def test_consecutive_failures_truncate_through_gym_make(env):
    """The task's own truncation survives ``gym.make``'s time-limit wrapper (ManiSkill's would overwrite it)."""
    base = env.unwrapped
    obs, _ = env.reset(seed=5)
    empty = np.argwhere(obs["depth_heightmap"][0].numpy() < 0.002)
    row, col = empty[0]
    action = int(row) * base.workspace.heightmap_size + int(col)  # rotation 0, a pixel with nothing on it
    saved, base.max_consecutive_failures = base.max_consecutive_failures, 2
    try:
        flags = [env.step(action)[2:4] for _ in range(2)]
    finally:
        base.max_consecutive_failures = saved
    (term1, trunc1), (term2, trunc2) = flags
    assert not trunc1.item() and not term1.item()
    assert trunc2.item() and not term2.item()


def test_faults_are_detected_and_truncate(env):
    """A blown-up object and an object resting on the gripper are named by detect_faults; step truncates on a fault
    and reports it in info."""
    import sapien

    base = env.unwrapped
    env.reset(seed=2)
    assert base.detect_faults()[0] == ""
    fast = base.clutter.active_actors[0][0]
    fast.set_linear_velocity(torch.tensor([[50.0, 0.0, 0.0]]))
    assert base.detect_faults()[0].startswith(f"physics blow-up: {base.clutter.active[0][0]}")

    env.reset(seed=2)
    finger = base.agent.finger1_link.pose.p[0].numpy()
    base.clutter.active_actors[0][1].set_pose(sapien.Pose(p=finger))
    for _ in range(2):
        base.scene.step()
    assert base.detect_faults()[0] == f"{base.clutter.active[0][1]} rests on the gripper (panda_leftfinger) at the home pose"
    # the forces it judges by (the contacts fetched once) are ManiSkill's own pairwise forces, bit for bit
    links = (base.agent.finger1_link, base.agent.finger2_link, base.agent.robot.links_map["panda_hand"])
    forces = base._gripper_contact_forces(links)
    pairs = [(link, actor) for link in links for actor in base.clutter.active_actors[0]]
    ours = torch.stack([forces(link, actor) for link, actor in pairs])
    assert torch.equal(ours, torch.stack([base.scene.get_pairwise_contact_forces(link, actor) for link, actor in pairs]))
    assert (ours.norm(dim=-1) > 0).any()

    env.reset(seed=2)
    base.detect_faults = lambda: ["a fault found after the step"]  # whatever the action did, the episode ends
    try:
        obs, reward, terminated, truncated, info = env.step(0)
    finally:
        del base.detect_faults
    assert truncated.item() and not terminated.item() and info["fault"].tolist() == [True]
    assert info["fault_reason"] == "a fault found after the step"
    _, info = env.reset(seed=2)
    assert base.detect_faults()[0] == "" and info["fault"].tolist() == [False] and info["fault_reason"] == ""


def test_a_grasp_that_carries_two_objects_places_two():
    """Two 3.5 cm cubes side by side, touching: jaws closing along the pair (7 cm, the hand opens to 8) lift both,
    and both land in the bin: ``placed_objects`` counts 2 for the one grasp."""
    ws = WorkspaceSpec()
    cx, cy = ws.center
    half = 0.0175
    cube = ObjectSpec("cuboid", (half,) * 3)  # half sizes
    layout = [(cube, (cx - half, cy, ws.table_z + half)), (cube, (cx + half, cy, ws.table_z + half))]
    e = gym.make("ClutterGrasp-v1", layout=layout, **CPU)
    try:
        e.reset(seed=0)
        u = e.unwrapped
        row, col = ws.world_to_pixel([cx, cy, 0.0])
        _, reward, terminated, _, info = e.step(u.action_layout.encode(0, 0, int(row), int(col)))  # rotation 0: jaws along x
        assert info["grasp_success"].item() and info["place_success"].item(), info["reason"]
        assert info["placed_objects"].tolist() == [2] and info["objects_in_bin"].item() == 2
        assert reward.item() == 1.0 and terminated.item()
        # the bin is emptied after the step: both cubes are parked on the floor, and still count as in the bin
        assert all(float(a.pose.p[0, 2]) < ws.table_z - 0.5 for a in u.clutter.active_actors[0])
        assert u.clutter.status(0) == ["bin", "bin"]
    finally:
        e.close()


def _obs_with_everything_drawn(base) -> dict:
    """The observation of the current state with every body in the sensor render."""
    base.include_camera_data = True  # raw camera data always show everything
    try:
        obs = base.get_obs()
    finally:
        base.include_camera_data = False
    return obs


def _hidden_names(base) -> set[str]:
    names = set()
    with base._unseen_bodies_hidden():
        names = {b.entity.name for b in base._body_boxes.bodies if b.visibility == 0.0}
    assert all(b.visibility == 1.0 for b in base._body_boxes.bodies)  # drawn again after the render
    return names


@pytest.mark.parametrize("size", [64, None])  # None: the task's default heightmap size
def test_bodies_out_of_every_view_are_left_out_of_the_render_and_the_heightmaps_are_the_same(size):
    """The robot at home, the parked pool objects and the floor are not drawn for the sensors, and the heightmaps are
    bit-for-bit those of a render that draws everything; an arm over the workspace is drawn."""
    env = gym.make("ClutterGraspSlide-v1", **({} if size is None else dict(workspace=WorkspaceSpec(heightmap_size=size))), **CPU)
    base = env.unwrapped
    for seed in (4, 5):
        env.reset(seed=seed)
        hidden = _hidden_names(base)
        links = {b.entity.name for b in base._body_boxes.bodies if b.entity.name.startswith("panda_")}
        active = {f"scene-0_{name}" for name in base.clutter.active[0]}
        on_table = {f"scene-0_{name}" for name, where in zip(base.clutter.active[0], base.clutter.status(0)) if where == "workspace"}
        parked = {b.entity.name for b in base._body_boxes.bodies if b.entity.name.startswith("scene-0_obj_")} - active
        assert links <= hidden and parked <= hidden and "scene-0_ground" in hidden, hidden
        assert on_table and not (on_table & hidden) and "scene-0_table-workspace" not in hidden
        obs, drawn = base.get_obs(), _obs_with_everything_drawn(base)
        for key in ("color_heightmap", "depth_heightmap"):
            assert torch.equal(obs[key], drawn[key]), key
    # The arm over the workspace: inside the top camera's view, drawn.
    q = base.agent.robot.get_qpos().clone()
    q[0, :7] = torch.tensor([0.0, 0.6, 0.0, -1.6, 0.0, 2.2, 0.785])  # facing the table, the hand over the workspace
    base.agent.robot.set_qpos(q)
    base.scene.step()  # the links' poses follow the joints at a physics step
    base.scene.update_render(update_sensors=True, update_human_render_cameras=False)
    assert "panda_hand" not in _hidden_names(base)
    obs, drawn = base.get_obs(), _obs_with_everything_drawn(base)
    assert torch.equal(obs["depth_heightmap"], drawn["depth_heightmap"])
    # The boxes the test reads are SAPIEN's own (local boxes moved), for every kind of body: links, table, bin, objects.
    lo, hi = base._body_boxes.world()
    sapien_boxes = np.array([b.get_global_aabb_fast() for b in base._body_boxes.bodies])
    np.testing.assert_allclose(lo, sapien_boxes[:, 0], atol=1e-5)
    np.testing.assert_allclose(hi, sapien_boxes[:, 1], atol=1e-5)
    env.close()


def test_view_volumes_separate_boxes_only_outside_every_camera():
    from maniskill_pnp.cell.view_volume import ViewVolumes

    spec = WorkspaceSpec()
    views = ViewVolumes(spec)
    b = spec.bounds
    centre = b.mean(axis=1)
    assert not views.clear_of(centre - 0.01, centre + 0.01)  # in the workspace
    eye = np.asarray(spec.cameras[1].eye)
    assert not views.clear_of(eye - 0.01, eye + 0.01)  # at a camera's eye
    far = centre + [0.0, 0.0, -1.0]  # under the table
    assert views.clear_of(far - 0.05, far + 0.05)
    assert not views.clear_of(np.stack([far - 0.05, centre]), np.stack([far + 0.05, centre + 0.01]))  # one box inside
    with pytest.raises(ValueError, match="must both be"):
        views.clear_of(np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="margin"):
        ViewVolumes(spec, margin=-1.0)


def test_each_lost_object_gets_one_cause():
    """Only objects that became lost count; a slide's are the slide's; a grasp's are the neighbours' unless it is the
    held object, which was dropped in transit when the jaws felt nothing as they opened, else lost at release."""
    names = ["a", "b", "c", "d"]
    before = ["workspace", "workspace", "lost", "workspace"]
    after = ["lost", "bin", "lost", "lost"]  # a and d newly lost; c was lost already; b placed
    assert loss_causes(before, after, names, "left_slide") == dict(dict.fromkeys(LOSS_CAUSES, 0), lost_by_slide=2)
    assert loss_causes(before, after, names, "grasp") == dict(dict.fromkeys(LOSS_CAUSES, 0), lost_by_grasp=2)
    for held_at_release, cause in ((False, "lost_in_transit"), (True, "lost_at_release"), (None, "lost_at_release")):
        counts = loss_causes(before, after, names, "grasp", held="d", held_at_release=held_at_release)
        assert counts == dict(dict.fromkeys(LOSS_CAUSES, 0), lost_by_grasp=1, **{cause: 1}), held_at_release
    assert sum(loss_causes(before, before, names, "grasp", held="a").values()) == 0
    with pytest.raises(ValueError):
        loss_causes(before, after[:3], names, "grasp")
