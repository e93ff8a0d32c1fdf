"""The grasp-feasibility check (maniskill_pnp.scenes.grasp_feasibility) on real collision shapes and the Panda's real
finger and hand geometry, and its ``check-scene`` command."""

import pytest
import sapien

from maniskill_pnp.cli import main
from maniskill_pnp.scenes.complicated_layouts import COMPLICATED_SCENES_DIR
from maniskill_pnp.scenes.grasp_feasibility import check_scene_file, grasp_feasibility
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.cell.workspace import WorkspaceSpec

WS = WorkspaceSpec()
CUBE = ObjectSpec("cuboid", (0.02, 0.02, 0.02))


def _at(x: float, y: float) -> sapien.Pose:
    cx, cy = WS.center
    return sapien.Pose(p=[cx + x, cy + y, 0.02])


def test_square_of_four_is_all_locked():
    grasps = check_scene_file(COMPLICATED_SCENES_DIR / "square_of_four.yaml", WS)
    assert len(grasps) == 4 and all(g.locked and g.example is None for g in grasps)


def test_isolated_cube_and_two_cubes_apart_are_free():
    (single,) = grasp_feasibility([(CUBE, _at(0, 0))], WS)
    assert not single.locked and single.fraction > 0.05
    pair = grasp_feasibility([(CUBE, _at(-0.05, 0)), (CUBE, _at(0.05, 0))], WS)
    assert not any(g.locked for g in pair)


def test_row_of_pressed_cubes_is_graspable_across_the_row_but_not_along_it():
    # three 4 cm cubes 1 mm apart along x: jaws closing along y (across the row) fit every cube, none along x
    row = [(CUBE, _at(dx, 0)) for dx in (-0.041, 0.0, 0.041)]
    grasps = grasp_feasibility(row, WS, yaw_step_deg=90)  # jaw orientations 0 (along x) and 90 degrees
    assert not any(g.locked for g in grasps)
    along = grasp_feasibility(row, WS, yaw_step_deg=180)  # along x only: a finger would go into a 1 mm gap
    assert all(g.locked for g in along)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="at least one object"):
        grasp_feasibility([], WS)
    with pytest.raises(ValueError, match="yaw_step_deg"):
        grasp_feasibility([(CUBE, _at(0, 0))], WS, yaw_step_deg=0)
    with pytest.raises(ValueError, match="layout entry 0"):
        grasp_feasibility([(CUBE, [0, 0, 0.02])], WS)


def test_check_scene_command(capsys):
    main(["check-scene", str(COMPLICATED_SCENES_DIR / "square_of_four.yaml"), str(COMPLICATED_SCENES_DIR / "sandwich.yaml")])
    out = capsys.readouterr().out
    assert "square_of_four.yaml: 4 objects, 4 locked" in out and "all 2 scenes: 7 objects, 7 locked" in out


def test_shipped_hard_scenes_load_and_are_at_least_half_locked():
    from maniskill_pnp.agents.pixel.factories import scenario_layout_files, scenario_options
    from maniskill_pnp.scenes.hard_scenes import HARD_SCENE_COUNT, hard_layout_files, hard_scene_files

    files = hard_scene_files()
    assert len(files) == HARD_SCENE_COUNT
    for path in files[::6]:  # load_scene runs check_layout
        grasps = check_scene_file(path, WS)
        assert 2 * sum(g.locked for g in grasps) >= len(grasps), path
    assert scenario_layout_files("hard") == hard_layout_files() and len(hard_layout_files()) == HARD_SCENE_COUNT + 8
    assert scenario_options("hard", "grasp_slide")["layout_file"][0] == str(files[0])


def test_generator_reproduces_a_shipped_scene():
    from maniskill_pnp.scenes.hard_scenes import HARD_SEED, hard_layout, hard_scene_files
    from maniskill_pnp.scenes.scene_file import load_scene

    _, layout, locked = hard_layout(HARD_SEED + 2, WS)
    shipped = load_scene(hard_scene_files()[2], WS)
    assert [s for s, _ in layout] == [s for s, _ in shipped] and 2 * locked >= len(layout)
    for (_, a), (_, b) in zip(layout, shipped):
        assert abs(a.p - b.p).max() < 1e-5
