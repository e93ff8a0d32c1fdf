"""Training for tightly packed clutter: the hard training arrangements (disjoint from the test set, mixed into the
training clutters at a random yaw), the "unlock" reward scheme that pays a slide only when it frees a locked
object, and the config fields that reach the training env (guard_force, hard_fraction)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.factories import make_env
from maniskill_pnp.scenes.complicated_layouts import COMPLICATED_LAYOUT_NAMES
from maniskill_pnp.scenes.hard_scenes import (
    HARD_SCENE_COUNT, HARD_SEED, HARD_TRAIN_COUNT, HARD_TRAIN_SEED, hard_layout, hard_train_files, main,
)
from maniskill_pnp.scenes.hard_scenes import hard_scene_files
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.scenes.packed_families import PACKED_TRAIN_COUNT, training_arrangement_files, unseen_scene_files
from maniskill_pnp.scenes.scene_file import load_scene
from maniskill_pnp.cell.workspace import WorkspaceSpec

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=4)


def pairwise(xy: np.ndarray) -> np.ndarray:
    return np.linalg.norm(xy[:, None] - xy[None], axis=-1)


def test_training_arrangements_are_shipped_reproducible_and_disjoint_from_the_test_seeds():
    assert HARD_TRAIN_SEED >= HARD_SEED + HARD_SCENE_COUNT or HARD_TRAIN_SEED + HARD_TRAIN_COUNT <= HARD_SEED
    files = hard_train_files()
    assert len(files) == HARD_TRAIN_COUNT and all(f.is_file() for f in files)
    _, layout, locked = hard_layout(HARD_TRAIN_SEED + 1, WS)
    shipped = load_scene(files[1], WS)
    assert [s for s, _ in layout] == [s for s, _ in shipped] and 2 * locked >= len(layout)
    with pytest.raises(SystemExit):  # the writer refuses seeds of the other set
        main(["--train", "--seed", str(HARD_SEED), "--count", "2"])


def test_hard_fraction_plays_a_training_arrangement_turned_as_one_piece():
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, hard_fraction=1.0, **CPU)
    try:
        u = e.unwrapped
        shipped = [load_scene(f, WS) for f in hard_train_files()]
        seen = []
        for seed in (0, 1, 2):
            _, info = e.reset(seed=seed)
            j = int(u.clutter.arrangement_index[0])
            layout = u.clutter.workspace_layout(0)
            assert j >= 0 and info["objects_remaining"].item() == len(shipped[j]) == len(layout)
            xy = np.array([p.p[:2] for _, p in layout])
            assert np.abs(pairwise(xy) - pairwise(np.array([p.p[:2] for _, p in shipped[j]]))).max() < 0.003
            seen.append((j, xy))
        _, _ = e.reset(seed=1)
        assert u.clutter.arrangement_index[0] == seen[1][0]
        assert np.abs(np.array([p.p[:2] for _, p in u.clutter.workspace_layout(0)]) - seen[1][1]).max() < 1e-4
    finally:
        e.close()
    for bad, match in ((1.5, "hard_fraction must be"), (0.5, "not with layout")):
        with pytest.raises(ValueError, match=match):
            gym.make("ClutterGraspSlide-v1", workspace=WS, hard_fraction=bad,
                     layout="complicated" if bad == 0.5 else None, **CPU)


def slide(e, side: str, rotation: int, xyz):
    u = e.unwrapped
    row, col = u.workspace.world_to_pixel(np.asarray(xyz))
    _, reward, _, _, info = e.step(u.action_layout.encode(u.PRIMITIVES.index(side), rotation, int(row), int(col)))
    return reward.item(), info


def positions(e) -> np.ndarray:
    return np.stack([a.pose.p[0].cpu().numpy() for a in e.unwrapped.clutter.active_actors[0]])


def assert_a_pushed_free_cube_pays_nothing(scheme: str, freed_key: str) -> None:
    """An isolated cube pushed aside changes the scene but frees nothing: no reward, and no failure."""
    cx, cy = WS.center
    cube = (ObjectSpec("cuboid", (0.02, 0.02, 0.02)), (cx + 0.08, cy + 0.05, 0.02))
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout=[cube], reward_scheme=scheme, **CPU)
    try:
        e.reset(seed=0)
        reward, info = slide(e, "right_slide", 1, np.asarray(cube[1]) - [0.04, 0.0, 0.0])  # right of rotation 1: +x
        assert info["slide_changed"] and info[freed_key] == 0 and reward == 0.0, info
        assert info["consecutive_failures"] == 0
    finally:
        e.close()


@pytest.mark.parametrize("scheme", ["unlock", "unlock_each"])
def test_unlock_schemes_pay_the_slide_that_frees_a_bar_and_not_one_that_only_moves_things(scheme):
    """row_of_three (three 4×9 cm bars pressed together, all locked): pushing the end bar out of the row frees it
    and pays ("unlock": 0.5 once; "unlock_each": 0.5 per object freed, at most 1); pushing the middle bar frees
    all three ("unlock" still 0.5, "unlock_each" 1). An isolated cube pushed aside changes the scene but frees
    nothing: 0, and still no failure."""
    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout="complicated", reward_scheme=scheme, guard_force=20.0,
                 complicated_index=COMPLICATED_LAYOUT_NAMES.index("row_of_three"), **CPU)
    try:
        e.reset(seed=0)
        before = positions(e)
        reward, info = slide(e, "left_slide", 0, before[2] + [0.014, -0.065, 0.0])  # rotation 0's left is +y
        freed = info["slide_unlocked"]
        assert info["slide_changed"] and freed >= 1, info
        assert reward == (0.5 if scheme == "unlock" else 0.5 * min(freed, 2)), info
        assert positions(e)[2, 1] - before[2, 1] > 0.04
        e.reset(seed=0)  # pushing at the middle bar's centre takes the middle and the first bar along: all three freed
        reward, info = slide(e, "left_slide", 0, before[1] + [0.0, -0.065, 0.0])
        freed = info["slide_unlocked"]
        assert info["slide_changed"] and freed >= 2, info
        assert reward == (0.5 if scheme == "unlock" else 1.0), info
    finally:
        e.close()
    assert_a_pushed_free_cube_pays_nothing(scheme, "slide_unlocked")


def test_fit_gain_pays_the_slide_that_adds_a_graspable_region_from_the_heightmaps_alone():
    """row_of_three: no grasp fits the heightmap of three pressed bars; pushing the end bar out of the row adds a
    region where grasps fit, and "fit_gain" pays 0.5. An isolated cube pushed aside keeps its one region: 0, and still
    no failure. The judgement reads only the heightmaps: the same numbers come from the observations."""
    from maniskill_pnp.scenes.heightmap_fit import HeightmapGraspFit, graspable_regions

    e = gym.make("ClutterGraspSlide-v1", workspace=WS, layout="complicated", reward_scheme="fit_gain", guard_force=20.0,
                 complicated_index=COMPLICATED_LAYOUT_NAMES.index("row_of_three"), **CPU)
    fit = HeightmapGraspFit.for_workspace(WS)

    def regions(obs) -> int:
        h = obs["depth_heightmap"]
        occupied = h > 0.01
        return graspable_regions(fit(h, occupied, obs.get("fit_heightmap"))[0].any(dim=0), occupied[0])

    try:
        obs, _ = e.reset(seed=0)
        assert regions(obs) == 0
        before = positions(e)
        u = e.unwrapped
        row, col = u.workspace.world_to_pixel(before[2] + [0.014, -0.065, 0.0])
        obs, reward, _, _, info = e.step(u.action_layout.encode(u.PRIMITIVES.index("left_slide"), 0, int(row), int(col)))
        assert info["slide_changed"] and info["slide_fit_gain"].item() == regions(obs) >= 1, info
        assert reward.item() == 0.5 and info["slide_unlocked"].item() == 0  # the simulator's judgement is not made
    finally:
        e.close()
    assert_a_pushed_free_cube_pays_nothing("fit_gain", "slide_fit_gain")


def test_config_fields_reach_the_training_env_only():
    cfg = ClutterConfig.from_preset("gs-cpu-equi-fit", heightmap_size=32, num_rotations=4, loss_cost=1.0,
                                    hard_sets=("hard_train", "packed_train"))
    assert (cfg.hard_fraction, cfg.guard_force, cfg.reward_scheme) == (0.5, 20.0, "unlock")
    env = make_env(cfg)
    try:
        base = env.base_env
        assert base.guard_force == 20.0 and base.clutter.arrangement_fraction == 0.5 and base.reward_scheme == "unlock"
        assert base.loss_cost == 1.0  # the reward scheme's cost of a loss, in training and evaluation alike
        # both training sets, never a test set: the arrangements are those of the two sets' files
        files = training_arrangement_files(("hard_train", "packed_train"))
        assert len(base.clutter.arrangement_slots) == len(files) == HARD_TRAIN_COUNT + PACKED_TRAIN_COUNT
        assert not set(files) & set(unseen_scene_files() + hard_scene_files())
    finally:
        env.close()
    for bad, match in (
        (dict(hard_fraction=0.8, packed_fraction=0.3), "hard_fraction"),
        (dict(guard_force=-1.0), "guard_force"),
        (dict(loss_cost=-0.5), "loss_cost"),
        (dict(hard_sets=("hard",)), "unknown hard_sets"),
        (dict(reward_scheme="pushy"), "reward scheme"),
    ):
        with pytest.raises(ValueError, match=match):
            ClutterConfig.from_preset("gs-cpu-equi-fit", **bad)
