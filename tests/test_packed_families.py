"""The packed families beyond the hard set's: every family draws valid, mostly locked arrangements; the shipped
held-out set (``hard_unseen``) and training set keep to their families; the held-out families are never drawn for
training; ``check-scene`` and the scenarios read the held-out set by name."""

from __future__ import annotations

import re

import pytest

from maniskill_pnp.agents.pixel.factories import FILE_SCENARIOS, scenario_layout_files, scenario_options
from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.cli import FILE_SCENARIO_NAMES, main
from maniskill_pnp.scenes.grasp_feasibility import grasp_feasibility
from maniskill_pnp.scenes.packed_families import (
    FAMILIES, HELD_OUT_FAMILIES, PACKED_TRAIN_COUNT, PACKED_TRAIN_SEED, TRAIN_FAMILIES, UNSEEN_COUNT, UNSEEN_SEED,
    packed_layout, packed_train_files, unseen_scene_files,
)
from maniskill_pnp.scenes.hard_scenes import HARD_SEED, HARD_SCENE_COUNT, HARD_TRAIN_COUNT, HARD_TRAIN_SEED
from maniskill_pnp.scenes.scene_file import load_scene

WS = WorkspaceSpec()


def _family(path) -> str:
    """The family a shipped scene file's description names."""
    text = path.read_text()
    match = re.search(r"seed \d+: (\w+), (\d+) objects, (\d+) locked", text)
    assert match, path
    return match.group(1)


#: A seed per family whose first draw qualifies here (any seed qualifies within a few draws; these keep the test short).
FAMILY_SEEDS = dict(arch_nest=0, interlock=1, tall_block=0, ring=2, wedge_block=0)


@pytest.mark.parametrize("family", FAMILIES)
def test_each_family_draws_a_packed_arrangement_of_3_to_8_objects_at_least_half_locked(family):
    seed = FAMILY_SEEDS[family]
    name, layout, locked = packed_layout(seed, (family,), WS)
    assert name == family and 3 <= len(layout) <= 8
    recount = sum(g.locked for g in grasp_feasibility(layout, WS))
    assert recount == locked and 2 * locked >= len(layout)
    again = packed_layout(seed, (family,), WS)[1]  # the same seed, the same arrangement (in this process)
    assert [s for s, _ in again] == [s for s, _ in layout]
    assert all((a.p == b.p).all() and (a.q == b.q).all() for (_, a), (_, b) in zip(again, layout))


def test_held_out_families_are_apart_from_training_and_the_seed_ranges_do_not_meet():
    assert set(TRAIN_FAMILIES).isdisjoint(HELD_OUT_FAMILIES) and len(HELD_OUT_FAMILIES) >= 2
    ranges = [(HARD_SEED, HARD_SCENE_COUNT), (HARD_TRAIN_SEED, HARD_TRAIN_COUNT), (UNSEEN_SEED, UNSEEN_COUNT),
              (PACKED_TRAIN_SEED, PACKED_TRAIN_COUNT)]
    seeds = [s for start, count in ranges for s in range(start, start + count)]
    assert len(seeds) == len(set(seeds))
    with pytest.raises(ValueError, match="unknown packed families"):
        packed_layout(0, ("pyramid",), WS)


def test_shipped_sets_keep_to_their_families_and_are_at_least_half_locked():
    unseen, train = unseen_scene_files(), packed_train_files()
    assert len(unseen) == UNSEEN_COUNT >= 24 and len(train) == PACKED_TRAIN_COUNT
    assert {_family(p) for p in unseen} == set(HELD_OUT_FAMILIES)
    assert {_family(p) for p in train} <= set(TRAIN_FAMILIES)
    for path in unseen[::4] + train[::8]:  # load_scene runs the layout check; the rest load in the scenario test
        layout = load_scene(path, WS)
        locked = sum(g.locked for g in grasp_feasibility(layout, WS))
        assert 3 <= len(layout) <= 8 and 2 * locked >= len(layout), path


def test_hard_unseen_is_a_scenario_of_eval_and_check_scene(capsys):
    assert FILE_SCENARIO_NAMES == FILE_SCENARIOS and "hard_unseen" in FILE_SCENARIOS
    files = scenario_layout_files("hard_unseen")
    assert files == unseen_scene_files() and all(f.is_file() for f in files)
    assert scenario_options("hard_unseen", "grasp_slide") == dict(layout_file=[str(p) for p in files])
    main(["check-scene", "hard_unseen", "--yaw-step", "45", "--position-step", "8"])
    out = capsys.readouterr().out
    assert out.count("unseen_") == UNSEEN_COUNT
    summary = re.search(r"all (\d+) scenes: (\d+) objects, (\d+) locked; (\d+) scenes with at least half", out)
    assert summary and int(summary.group(1)) == UNSEEN_COUNT
    assert int(summary.group(2)) == sum(len(load_scene(f, WS)) for f in files)
