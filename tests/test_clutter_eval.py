"""Greedy evaluation of a clutter DQN checkpoint: a tiny trained run evaluated end to end, and clear errors."""

from __future__ import annotations

import json
import math
import statistics

import matplotlib.image
import pytest

from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.evaluate import (
    METRICS, SCENARIO_COLUMNS, ClutterEvalConfig, comparison_table, is_completed, paired_differences, run, scene_values,
    summarize,
)
from maniskill_pnp.agents.pixel.recipe import main as train
from maniskill_pnp.cli import main as cli
from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.packed_families import unseen_scene_files
from maniskill_pnp.scenes.scene_file import load_scene


def test_eval_writes_metrics_tables_and_q_map_figure(tiny_clutter_run, tmp_path):
    out = tmp_path / "eval"
    summary = run(ClutterEvalConfig(checkpoint=tiny_clutter_run, episodes=1, max_steps=2, out=out))

    for name in ("eval_summary.json", "eval_table.md", "eval_table.csv", "eval_episodes.csv", "q_heatmaps.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    report = json.loads((out / "eval_summary.json").read_text())
    assert set(METRICS) <= set(report["metrics"]["train"])
    for key in METRICS:
        assert 0.0 <= report["metrics"]["train"][key] <= 1.0, key
    (episode,) = report["episodes"]
    assert episode["seed"] == 1000 and 1 <= episode["actions"] <= 2 and episode["objects"] == 2
    assert episode["grasp_attempts"] == episode["actions"]  # a grasp-only agent
    assert report["train_config"]["num_rotations"] == 2
    assert report["action_mask"]["primitives"] == ["grasp"] and report["action_mask"]["num_rotations"] == 2
    assert summary["metrics"] == report["metrics"]

    csv_lines = (out / "eval_table.csv").read_text().splitlines()
    assert csv_lines[0] == ",".join(SCENARIO_COLUMNS) and csv_lines[1].startswith("train,1,")
    assert len(csv_lines) == 2

    image = matplotlib.image.imread(out / "q_heatmaps.png")
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 300 and image.shape[2] in (3, 4)
    assert image[..., :3].std() > 0  # not a blank canvas


def _episode(seed, actions, grasp_attempts, grasps, placed, cleared, objects=4, faults=0, scenario="medium", lost=0,
             **causes):
    return dict(scenario=scenario, seed=seed, objects=objects, actions=actions, grasp_attempts=grasp_attempts,
                grasps=grasps, placed=placed, lost=lost, cleared=cleared, max_failure_run=1, faults=faults, layout="",
                **causes)


def test_completion_needs_every_starting_object_in_the_bin_and_counts_objects_not_grasps():
    # 4 objects: one grasp carried two into the bin (3 grasps place 4), so efficiency counts 4 objects / 3 actions
    two_in_one = _episode(1, 3, 3, 3, 4, True)
    # the workspace was emptied, but one object was pushed off it: not completed, though "workspace cleared"
    knocked_off = _episode(2, 4, 4, 3, 3, True, lost=1, lost_by_grasp=1)
    assert is_completed(two_in_one) and not is_completed(knocked_off)
    s = summarize([two_in_one, knocked_off])
    assert s["completion"] == 0.5 and s["workspace_cleared"] == 1.0 and s["lost_per_scene"] == 0.5
    assert s["lost_by_grasp_per_scene"] == 0.5 and s["lost_by_slide_per_scene"] == s["lost_at_release_per_scene"] == 0
    assert s["action_efficiency"] == pytest.approx(4 / 3) and s["success_rate"] == pytest.approx((4 / 3 + 3 / 4) / 2)
    assert scene_values(knocked_off)["action_efficiency"] == 0.0


def test_summary_has_standard_errors_over_scenes_and_fault_rate():
    episodes = [_episode(1, 4, 4, 4, 4, True), _episode(2, 8, 6, 3, 2, False, faults=1), _episode(3, 5, 0, 0, 0, False)]
    s = summarize(episodes)
    assert s["success_rate"] == pytest.approx((1 + 0.25 + 0) / 3)
    assert s["grasp_success"] == pytest.approx(7 / 10)  # pooled over attempts
    assert s["completion"] == pytest.approx(1 / 3) and s["action_efficiency"] == pytest.approx(1.0)
    assert s["success_rate_se"] == pytest.approx(statistics.stdev([1, 0.25, 0]) / math.sqrt(3))
    assert s["grasp_success_se"] == pytest.approx(statistics.stdev([1, 0.5]) / math.sqrt(2))  # scenes with attempts
    assert s["completion_se"] == pytest.approx(statistics.stdev([1, 0, 0]) / math.sqrt(3))
    assert s["faults_per_100_actions"] == pytest.approx(100 / 17)
    assert summarize(episodes[:1])["success_rate_se"] == 0.0


def test_paired_differences_match_scenes_and_the_comparison_command(tmp_path, capsys):
    a = [_episode(1, 4, 4, 4, 4, True), _episode(2, 4, 2, 2, 2, False), _episode(9, 4, 4, 4, 4, True)]
    b = [_episode(1, 8, 8, 4, 4, True), _episode(2, 4, 4, 1, 1, False), _episode(3, 4, 4, 4, 4, True)]
    d = paired_differences(a, b)["medium"]
    assert d["scenes"] == 2  # seeds 1 and 2 are in both
    assert d["success_rate"]["mean"] == pytest.approx(((1 - 0.5) + (0.5 - 0.25)) / 2)
    assert d["success_rate"]["se"] == pytest.approx(statistics.stdev([0.5, 0.25]) / math.sqrt(2))
    assert d["completion"]["mean"] == 0.0
    with pytest.raises(ValueError, match="share no scene"):
        paired_differences(a, [_episode(7, 1, 1, 1, 1, True)])

    for name, episodes in (("a", a), ("b", b)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "eval_summary.json").write_text(json.dumps(dict(episodes=episodes)))
    table = comparison_table(tmp_path / "a", tmp_path / "b")
    assert "| medium | 2 | +37.5 ± 12.5 |" in table
    cli(["compare-clutter", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "cmp.md"),
         "--plot", str(tmp_path / "cmp.png")])
    assert "| medium | 2 |" in capsys.readouterr().out and (tmp_path / "cmp.md").read_text().strip() == table
    assert (tmp_path / "cmp.png").stat().st_size > 5_000
    with pytest.raises(SystemExit, match="compare-clutter: .*nowhere"):
        cli(["compare-clutter", str(tmp_path / "a"), str(tmp_path / "nowhere")])


def test_missing_or_corrupt_checkpoint_is_a_clear_error(tmp_path):
    missing = tmp_path / "nowhere" / "checkpoint.pt"
    with pytest.raises(FileNotFoundError, match="nowhere"):
        run(ClutterEvalConfig(checkpoint=missing, out=tmp_path / "eval"))
    with pytest.raises(SystemExit, match="eval-clutter: .*nowhere"):
        cli(["eval-clutter", str(missing), "--out", str(tmp_path / "eval")])

    corrupt = tmp_path / "checkpoint.pt"
    corrupt.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="checkpoint.pt"):
        run(ClutterEvalConfig(checkpoint=tmp_path, out=tmp_path / "eval"))
    assert not (tmp_path / "eval").exists()


@pytest.mark.parametrize("option", [dict(episodes=0), dict(max_steps=0), dict(actions_per_object=0), dict(num_objects=0), dict(seed=-1),
                                    dict(device="gpu7"), dict(scenarios=("crowded",))])
def test_bad_options_name_the_option(option, tmp_path):
    name = next(iter(option))
    with pytest.raises(ValueError, match=name):
        ClutterEvalConfig(checkpoint=tmp_path, **option)


def test_grasp_slide_table_ix_over_scenarios_and_grasp_only(tmp_path):
    """A tiny G&S run evaluated on two scenarios (Table IX rows), then restricted to its grasps."""
    cfg = ClutterConfig.from_preset("gs-cpu-small", heightmap_size=32, num_rotations=2, num_objects=3, steps=2,
                                    checkpoint_interval=2, log_interval=1, collector="direct", out=tmp_path)
    train(cfg)
    both = run(ClutterEvalConfig(checkpoint=cfg.run_dir, episodes=1, max_steps=2,
                                 scenarios=("2", "complicated", "hard_unseen"), out=tmp_path / "gs", strips=1))
    assert list(both["metrics"]) == ["2", "complicated", "hard_unseen"]
    for e in both["episodes"]:  # every action a grasp or a slide; slides that changed nothing among the slides
        assert e["slides"] <= e["actions"] and 0 <= e["futile_slides"] <= e["slides"]
    # a strip per scenario whose episode was not perfect (2 actions cannot clear a locking layout): one row a decision
    assert any("complicated" in p.rsplit("/", 1)[-1] for p in both["strips"])
    for path in both["strips"]:
        assert matplotlib.image.imread(path).shape[0] >= 256
    rows = (tmp_path / "gs" / "eval_table.md").read_text().splitlines()
    assert rows[0].startswith("| scenario | episodes | success_rate") and len(rows) == 5
    assert [e["scenario"] for e in both["episodes"]] == ["2", "complicated", "hard_unseen"]
    assert 3 <= both["episodes"][1]["objects"] <= 7  # a hand-designed locking layout
    unseen = both["episodes"][2]  # the held-out families' first scene file
    assert unseen["layout"] == "unseen_00" and unseen["objects"] == len(load_scene(unseen_scene_files()[0], WorkspaceSpec()))

    grasps = run(ClutterEvalConfig(checkpoint=cfg.run_dir, episodes=1, scenarios=("2",), grasp_only=True,
                                   actions_per_object=0.5, out=tmp_path / "grasp_only"))
    (episode,) = grasps["episodes"]
    assert episode["grasp_attempts"] == episode["actions"]
    assert episode["actions"] == 1  # at most 0.5 x 2 objects actions


def test_record_clutter_films_the_arm_beside_each_decision(tiny_clutter_run, tmp_path):
    """The MP4 holds the scene render beside the decision panels, many frames per decision (the arm's motion);
    the strip has one row per decision; the JSON lists the decisions with their outcomes."""
    import imageio.v3 as iio

    from maniskill_pnp.agents.pixel.video import PANEL, ClutterVideoConfig, run as record

    out = tmp_path / "video"
    summary = record(ClutterVideoConfig(checkpoint=tiny_clutter_run, max_steps=2, frame_every=4, out=out))
    decisions = summary["decisions"]
    assert 1 <= len(decisions) <= 2
    assert {"primitive", "rotation", "row", "col", "q", "reward", "grasp_success"} <= set(decisions[0])
    assert json.loads((out / "video_summary.json").read_text())["decisions"] == decisions

    video = iio.imread(out / "episode.mp4")
    assert video.ndim == 4 and video.shape[0] == summary["frames"]
    assert summary["frames"] > 10 * len(decisions)  # frames during the primitives, not one per decision
    assert video.shape[1] == 512 and video.shape[2] > 512  # the 512 px render camera plus the decision panels
    assert video[:, :, :512].std(axis=0).mean() > 1.0  # the scene changes: the arm moves

    strip = iio.imread(out / "decisions.png")
    assert strip.shape[0] == PANEL * len(decisions) and strip.shape[1] == 5 * PANEL
    assert strip.std() > 0


def test_record_clutter_errors_name_the_problem(tmp_path):
    from maniskill_pnp.agents.pixel.video import ClutterVideoConfig

    with pytest.raises(ValueError, match="unknown scenario 'dense'"):
        ClutterVideoConfig(checkpoint=tmp_path, scenario="dense")
    with pytest.raises(ValueError, match="frame_every must be >= 1"):
        ClutterVideoConfig(checkpoint=tmp_path, frame_every=0)
    with pytest.raises(SystemExit, match="record-clutter: .*nowhere"):
        cli(["record-clutter", str(tmp_path / "nowhere"), "--out", str(tmp_path / "video")])


def test_decide_never_picks_an_excluded_action(tiny_clutter_run):
    import torch

    from maniskill_pnp.agents.pixel.evaluate import decide
    from maniskill_pnp.agents.pixel.factories import load_policy

    actor, cfg, _ = load_policy(tiny_clutter_run, torch.device("cpu"))
    s = cfg.heightmap_size
    depth = torch.zeros(1, s, s)
    depth[0, s // 4 : s // 2, s // 4 : s // 2] = 0.05  # one block of material: the mask allows grasps on it only
    obs = dict(color_heightmap=torch.full((1, s, s, 3), 128, dtype=torch.uint8), depth_heightmap=depth)
    best, maps = decide(actor, obs, torch.device("cpu"))
    second, _ = decide(actor, obs, torch.device("cpu"), exclude=[best])
    allowed = actor.action_mask(depth).reshape(-1)
    flat = maps.reshape(-1)
    assert second != best and allowed[second] and flat[second] == flat[allowed].sort(descending=True).values[1]
    everything = torch.nonzero(allowed).reshape(-1).tolist()
    assert decide(actor, obs, torch.device("cpu"), exclude=everything)[0] == best  # nothing left: the argmax stays
