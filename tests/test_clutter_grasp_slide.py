"""ClutterGraspSlide-v1: registration, the 3-primitive action, slides, grasps, rewards, the complicated layouts, and a
locking layout that no grasp clears until a slide has pulled it apart."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.tasks import LOSS_CAUSES, TASK_IDS, ClutterGraspSlideEnv
from maniskill_pnp.scenes.clutter import density_range, random_specs, sample_packed, validate_layout
from maniskill_pnp.tasks.clutter_grasp_slide import REWARD_SCHEMES, change_threshold, heightmap_changed
from maniskill_pnp.agents.scripted.clutter_oracle import HeightmapGraspOracle
from maniskill_pnp.scenes.complicated_layouts import COMPLICATED_LAYOUT_NAMES, complicated_layouts
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.cell.workspace import WorkspaceSpec

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=4)
N = 3 * 4 * 64 * 64
CUBE = ObjectSpec("cuboid", (0.02, 0.02, 0.02))
# Two cubes far apart: A to grasp, B to push.
CX, CY = WS.center
TWO_CUBES = [(CUBE, (CX - 0.1, CY, 0.02)), (CUBE, (CX + 0.08, CY + 0.05, 0.02))]


@pytest.fixture(scope="module")
def env():
    """Every complicated layout, 64×64 heightmaps, 4 rotations."""
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout="complicated", **CPU)
    yield e
    e.close()


@pytest.fixture(scope="module")
def two_cubes():
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout=TWO_CUBES, **CPU)
    yield e
    e.close()


def positions(env) -> np.ndarray:
    return np.stack([a.pose.p[0].cpu().numpy() for a in env.unwrapped.clutter.active_actors[0]])


def act(env, primitive: str, rotation: int, xyz) -> tuple[float, dict]:
    """Step the primitive at the pixel under world point ``xyz``."""
    u = env.unwrapped
    row, col = u.workspace.world_to_pixel(np.asarray(xyz))
    _, reward, _, _, info = env.step(u.action_layout.encode(u.PRIMITIVES.index(primitive), rotation, int(row), int(col)))
    assert info["primitive"] == primitive
    return reward.item(), info


def test_id_registers_with_three_primitive_action_space(env):
    assert "ClutterGraspSlide-v1" in TASK_IDS
    u = env.unwrapped
    assert isinstance(u, ClutterGraspSlideEnv)
    assert u.single_action_space == gym.spaces.Discrete(N) and u.action_layout.shape == (3, 4, 64, 64)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=f"0..{N - 1}.*primitive"):
        env.step(N)


def test_defaults_are_the_thesis_setting():
    """10 objects, 224×224 heightmaps and 16 rotations: 3 × 16 × 224 × 224 actions."""
    e = gym.make("ClutterGraspSlide-v1", **CPU)
    try:
        obs, info = e.reset(seed=0)
        assert e.unwrapped.single_action_space == gym.spaces.Discrete(3 * 16 * 224 * 224)
        assert obs["depth_heightmap"].shape == (1, 224, 224)
        assert info["num_objects"] == 10 and info["primitive"] == "" and not info["slide_changed"]
    finally:
        e.close()


def test_slide_directions_are_left_and_right_of_the_jaws():
    np.testing.assert_allclose(WS.slide_direction(0, "left"), [0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(WS.slide_direction(0, "right"), [0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(WS.slide_direction(1, "left"), [-1.0, 0.0], atol=1e-12)  # jaws along +y
    with pytest.raises(ValueError, match="side"):
        WS.slide_direction(0, "up")


def test_change_test_scales_with_the_heightmap():
    assert change_threshold(224, 224) == 300 and change_threshold(64, 64) == pytest.approx(300 * 64**2 / 224**2)
    before = np.zeros((224, 224))
    after = before.copy()
    after.flat[:300] = 0.02
    assert not heightmap_changed(before, after)
    after.flat[300] = 0.02
    assert heightmap_changed(before, after)
    assert not heightmap_changed(before, np.full((224, 224), 0.005))  # below 1 cm: noise
    assert not heightmap_changed(before, np.full((224, 224), 0.5))  # above 30 cm: not a height change of the clutter


def test_grasp_picks_an_isolated_object(two_cubes):
    two_cubes.reset(seed=0)
    reward, info = act(two_cubes, "grasp", 0, TWO_CUBES[0][1])
    assert info["grasp_success"] and reward == (1.0 if info["place_success"] else 0.8)
    assert info["objects_remaining"] == 1 and not info["slide_changed"] and info["consecutive_failures"] == 0


def test_slide_moves_the_object_it_pushes(two_cubes):
    """Right of rotation 1 (jaws along +y) is +x: start 4 cm left of cube B and push it."""
    two_cubes.reset(seed=0)
    before = positions(two_cubes)
    b = np.asarray(TWO_CUBES[1][1])
    reward, info = act(two_cubes, "right_slide", 1, b - [0.04, 0.0, 0.0])
    moved = positions(two_cubes) - before
    assert moved[1, 0] > 0.02 and abs(moved[1, 1]) < 0.02  # pushed along +x
    assert np.linalg.norm(moved[0]) < 1e-3
    assert info["slide_changed"] and reward == 0.5 and info["consecutive_failures"] == 0
    assert info["slide_direction"] == pytest.approx([1.0, 0.0]) and info["slide_start"][2] == pytest.approx(WS.min_tip_height)


def test_slide_through_empty_space_is_a_failure(two_cubes):
    two_cubes.reset(seed=0)
    reward, info = act(two_cubes, "left_slide", 0, (CX + 0.1, CY - 0.15, 0.0))
    assert not info["slide_changed"] and reward == 0.0 and info["consecutive_failures"] == 1


@pytest.mark.parametrize("action", [-1, N, 2.0, float("nan"), np.array([1, 2]), np.zeros((2,), dtype=np.int64), True, "7"])
def test_bad_actions_name_the_valid_range_before_moving(two_cubes, action):
    two_cubes.reset(seed=0)
    q0 = two_cubes.unwrapped.agent.robot.get_qpos().clone()
    with pytest.raises(ValueError, match=f"0..{N - 1}"):
        two_cubes.step(action)
    assert torch.equal(two_cubes.unwrapped.agent.robot.get_qpos(), q0)
    assert two_cubes.unwrapped.num_actions[0] == 0


@pytest.mark.parametrize("loss_cost", [0.0, 1.5])
def test_slide_that_knocks_an_object_out_of_the_workspace_is_a_failure(loss_cost):
    """Left of rotation 0 is +y: a cube 2.5 cm inside the +y edge, pushed from 4 cm behind it, leaves the workspace;
    with a loss cost, the lost object costs that much reward."""
    edge = (CX, CY + WS.side / 2 - 0.025, 0.02)
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout=[(CUBE, edge)], loss_cost=loss_cost, **CPU)
    try:
        e.reset(seed=0)
        reward, info = act(e, "left_slide", 0, np.asarray(edge) - [0.0, 0.04, 0.0])
        assert info["knocked_out"] == 1 and info["lost_objects"] == 1, info
        assert {k: int(info[k]) for k in LOSS_CAUSES} == dict(dict.fromkeys(LOSS_CAUSES, 0), lost_by_slide=1)
        assert reward == -loss_cost and info["consecutive_failures"] == 1 and "out of the workspace" in info["reason"]
    finally:
        e.close()


def test_reward_schemes_differ_only_in_the_slide_reward():
    assert {k: v for k, v in REWARD_SCHEMES["default"].items() if k != "slide"} == {
        k: v for k, v in REWARD_SCHEMES["no_slide_reward"].items() if k != "slide"
    }
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout=TWO_CUBES, reward_scheme="no_slide_reward", **CPU)
    try:
        e.reset(seed=0)
        reward, info = act(e, "right_slide", 1, np.asarray(TWO_CUBES[1][1]) - [0.04, 0.0, 0.0])
        assert info["slide_changed"] and reward == 0.0 and info["consecutive_failures"] == 0  # still not a failure
        reward, info = act(e, "grasp", 0, TWO_CUBES[0][1])
        assert info["grasp_success"] and reward == (1.0 if info["place_success"] else 0.8)
    finally:
        e.close()


def test_every_complicated_layout_builds_and_validates(env):
    u = env.unwrapped
    designs = complicated_layouts(WS)
    assert len(designs) == len(COMPLICATED_LAYOUT_NAMES) >= 8
    assert len(u.clutter.actors) < sum(map(len, designs))  # layouts share pool objects
    for k, design in enumerate(designs):
        assert 3 <= len(validate_layout(design, WS)) <= 7
        _, info = env.reset(seed=0, options={"layout_index": k})
        assert info["layout_index"] == k and info["objects_remaining"] == len(design) and info["lost_objects"] == 0
        want = np.array([pose.p for _, pose in design])
        assert np.abs(positions(env) - want).max() < 0.005, COMPLICATED_LAYOUT_NAMES[k]  # they rest as designed
    with pytest.raises(ValueError, match="layout_index"):
        env.reset(seed=0, options={"layout_index": len(designs)})


def test_heightmap_oracle_first_grasp_fails_on_every_complicated_layout(env):
    oracle = HeightmapGraspOracle(WS)
    for k, name in enumerate(COMPLICATED_LAYOUT_NAMES):
        obs, _ = env.reset(seed=0, options={"layout_index": k})
        _, reward, _, _, info = env.step(oracle(obs["depth_heightmap"][0]))
        assert not info["grasp_success"] and reward.item() == 0.0, name


def test_layout_choice_is_seeded(env):
    chosen = [env.reset(seed=s)[1]["layout_index"] for s in range(6)]
    assert chosen == [env.reset(seed=s)[1]["layout_index"] for s in range(6)]
    assert len(set(chosen)) > 1


def test_locking_row_needs_a_slide(env):
    """Three 4×9 cm bars pressed together: every centre grasp fails (a finger lands on a neighbour, or 9 cm is
    wider than the open jaws), so does the heightmap oracle; pushing the end bar out of the row frees it."""
    k = COMPLICATED_LAYOUT_NAMES.index("row_of_three")
    obs, _ = env.reset(seed=0, options={"layout_index": k})
    _, reward, _, _, info = env.step(HeightmapGraspOracle(WS)(obs["depth_heightmap"][0]))
    assert reward.item() == 0.0 and not info["grasp_success"]
    for i in range(3):
        for rotation in (0, 1):  # across the bar, along it (2 and 3 are their twins)
            env.reset(seed=0, options={"layout_index": k})
            reward, info = act(env, "grasp", rotation, positions(env)[i])
            assert reward == 0.0 and not info["grasp_success"], (i, rotation)
    env.reset(seed=0, options={"layout_index": k})
    before = positions(env)
    # Start beside the end bar's long side, off its centre by the closed fingers' half width (about 2.6 cm along
    # the jaws) minus the bar's half width, so the pusher meets this bar only; rotation 0's left is +y.
    reward, info = act(env, "left_slide", 0, before[2] + [0.014, -0.065, 0.0])
    moved = positions(env) - before
    assert info["slide_changed"] and reward == 0.5 and moved[2, 1] > 0.04 and np.abs(moved[:2]).max() < 0.01
    reward, info = act(env, "grasp", 0, positions(env)[2])
    assert info["grasp_success"] and reward == (1.0 if info["place_success"] else 0.8)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(reward_scheme="dense"), "valid schemes"),
        (dict(num_objects="crowded"), "density preset"),
        (dict(layout="spiral"), "unknown layout"),
        (dict(complicated_index=len(COMPLICATED_LAYOUT_NAMES)), "complicated_index"),
        (dict(complicated_index=True), "complicated_index"),
        (dict(complicated_index=0, layout=TWO_CUBES), "no other layout"),
        (dict(layout=[(CUBE, (CX, CY, 0.02))] * 2), "overlap"),
    ],
)
def test_bad_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("ClutterGraspSlide-v1", workspace=WS, **kwargs, **CPU)


def test_density_presets_accept_short_and_long_names():
    assert density_range("min") == density_range("minimum") == (6, 10)
    assert density_range("medium") == (15, 20)
    assert density_range("max") == density_range("maximum") == (25, 30)
    assert density_range("complicated") == (3, 7)


def test_a_dense_drop_starts_with_every_drawn_object_in_the_workspace():
    """Seeds whose medium pile rolled 4 and 5 objects off the workspace before the re-drop: they fall again."""
    e = gym.make("ClutterGraspSlide-v1", num_objects="medium", **CPU)
    try:
        u = e.unwrapped
        u.REDROP_ROUNDS = 0
        _, info = e.reset(seed=1002)
        assert info["lost_objects"].item() > 0  # the drop as it falls
        del u.REDROP_ROUNDS
        for seed in (1000, 1002):
            _, info = e.reset(seed=seed)
            assert info["lost_objects"].item() == 0 and info["objects_remaining"].item() == info["num_objects"].item()
            assert 15 <= info["num_objects"].item() <= 20
    finally:
        e.close()


def packed_neighbours(specs, poses) -> list[int]:
    """Per object, how many others stand beside it with the same yaw, 1-3 mm apart along one side (footprints
    overlapping along the other)."""
    out = []
    for i, (si, pi) in enumerate(zip(specs, poses)):
        count = 0
        for j, (sj, pj) in enumerate(zip(specs, poses)):
            ri, rj = pi.to_transformation_matrix()[:3, :3], pj.to_transformation_matrix()[:3, :3]
            if i == j or not np.allclose(ri, rj, atol=1e-6):
                continue
            d = np.abs(ri.T @ (pj.p - pi.p))[:2]
            reach = (si.extents[:2] + sj.extents[:2]) / 2
            count += any(0.001 - 1e-6 <= d[k] - reach[k] <= 0.003 + 1e-6 and d[1 - k] < reach[1 - k] for k in (0, 1))
        out.append(count)
    return out


def test_packed_clusters_stand_side_by_side_millimetres_apart():
    rng = np.random.default_rng(0)
    specs = random_specs(rng, 12)
    poses = sample_packed(np.random.default_rng(1), specs, WS)
    assert [tuple(p.p) for p in poses] == [tuple(p.p) for p in sample_packed(np.random.default_rng(1), specs, WS)]
    neighbours = packed_neighbours(specs, poses)
    assert sum(n == 0 for n in neighbours) <= 1, neighbours  # a last cluster of one object may stand alone
    (x0, x1), (y0, y1) = WS.spawn_bounds
    for spec, pose in zip(specs, poses):
        assert x0 <= pose.p[0] <= x1 and y0 <= pose.p[1] <= y1
        assert pose.p[2] == pytest.approx(WS.table_z + spec.extents[2] / 2 + 0.002)
    with pytest.raises(ValueError, match="cluster_size"):
        sample_packed(rng, specs, WS, cluster_size=(0, 3))
    with pytest.raises(ValueError, match="could not pack"):
        sample_packed(rng, random_specs(rng, 200), WS)


def test_packed_fraction_packs_that_share_of_episodes_and_the_piles_validate():
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, num_objects=6, packed_fraction=0.5, **CPU)
    try:
        u = e.unwrapped
        packed = 0
        for seed in range(6):
            e.reset(seed=seed)
            packed += bool(u.clutter.packed[0])
            validate_layout(u.clutter.workspace_layout(0), WS)  # at rest, no two interpenetrating
        assert 0 < packed < 6
    finally:
        e.close()
    for bad, match in ((1.5, "packed_fraction"), (0.5, "not with layout")):
        with pytest.raises(ValueError, match=match):
            gym.make("ClutterGraspSlide-v1", workspace=WS, packed_fraction=bad, layout=TWO_CUBES if bad == 0.5 else None, **CPU)


def test_keep_in_mask_withholds_the_slide_that_pushes_a_cube_out_and_offers_the_one_that_does_not():
    """Two 4 cm cubes, one at the middle and one 2 cm from the workspace's +x edge; the right slide of rotation 1
    pushes +x. From 2 px before each cube the material mask allows both slides; the keep-in mask (the agents' mask)
    keeps the middle one, which leaves its cube in the workspace, and withholds the edge one, which, executed anyway
    (any in-space action is), pushes its cube out."""
    from maniskill_pnp.agents.pixel.mask import HeightmapActionMask

    edge_x = WS.bounds[0, 1] - 0.04
    layout = [(CUBE, (CX - 0.1, CY, 0.02)), (CUBE, (edge_x, CY + 0.12, 0.02))]
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout=layout, **CPU)
    try:
        obs, _ = e.reset(seed=0)
        u = e.unwrapped
        primitives = u.PRIMITIVES
        plain = HeightmapActionMask.for_workspace(primitives, WS)
        keep_in = HeightmapActionMask.for_workspace(primitives, WS, keep_in=True)
        right, rot = primitives.index("right_slide"), 1
        assert np.allclose(WS.slide_direction(rot, "right"), (1.0, 0.0))
        for (x, y, _), stays in zip((layout[0][1], layout[1][1]), (True, False)):
            height = torch.as_tensor(obs["depth_heightmap"]).reshape(1, 64, 64)
            row, face = (int(v) for v in WS.world_to_pixel(np.array([x - 0.02, y, 0.0])))
            col = face - 2
            assert plain.pixel_masks(height)[0, right, rot, row, col], (row, col)
            assert bool(keep_in.pixel_masks(height)[0, right, rot, row, col]) == stays
            obs, _, _, _, info = e.step(u.action_layout.encode(right, rot, row, col))
            assert info["primitive"] == "right_slide" and info["slide_changed"], info
            assert info["lost_by_slide"] == (0 if stays else 1), info
    finally:
        e.close()
