"""The anywhere test set (maniskill_pnp.scenes.anywhere_scenes): packed arrangements of every family anywhere in the
workspace, half of them near its edge, each wholly over the heightmap and in reach, and a scenario of eval-clutter."""

from __future__ import annotations

from maniskill_pnp.agents.pixel.factories import FILE_SCENARIOS, scenario_layout_files, scenario_options
from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.anywhere_scenes import (ANYWHERE_COUNT, ANYWHERE_SEED, NEAR_EDGE, anywhere_layout,
                                                  anywhere_scene_files, edge_distance)
from maniskill_pnp.scenes.grasp_feasibility import grasp_feasibility
from maniskill_pnp.scenes.scene_file import load_scene, read_scene

WS = WorkspaceSpec()


def test_the_shipped_set_is_packed_reachable_and_half_of_it_near_the_edge():
    files = anywhere_scene_files()
    assert len(files) == ANYWHERE_COUNT == 24 and all(f.is_file() for f in files)
    distances = []
    for i, path in enumerate(files):
        layout = load_scene(path, WS)  # the layout check: wholly over the heightmap, centres in reach
        distances.append(edge_distance(layout, WS))
        if i % 4 == 0:
            locked = sum(g.locked for g in grasp_feasibility(layout, WS))
            assert 3 <= len(layout) <= 8 and 2 * locked >= len(layout), path
    assert all(d <= NEAR_EDGE + 1e-6 for d in distances[::2])  # the even ones within 5 cm of an edge
    assert min(distances) >= 0.0
    families = {read_scene(p).description.split(": ")[1].split(",")[0] for p in files}
    assert len(families) >= 5, families


def test_a_seed_draws_its_shipped_scene_again():
    family, layout, locked = anywhere_layout(ANYWHERE_SEED + 3, WS)
    shipped = load_scene(anywhere_scene_files()[3], WS)
    assert len(layout) == len(shipped)
    for (spec, pose), (spec2, pose2) in zip(layout, shipped):
        assert spec.kind == spec2.kind and abs(pose.p - pose2.p).max() < 1e-4


def test_anywhere_is_a_scenario():
    assert "anywhere" in FILE_SCENARIOS
    files = scenario_layout_files("anywhere")
    assert files == anywhere_scene_files()
    assert scenario_options("anywhere", "grasp_slide") == dict(layout_file=[str(p) for p in files])
