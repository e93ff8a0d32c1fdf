"""The README's main job (``maniskill-pnp quickstart``) end to end with tiny settings, the bundled agent, and
``export-clutter``."""

from __future__ import annotations

import json

import pytest
import torch

from maniskill_pnp.agents.pixel.checkpoint import export_weights, load_checkpoint
from maniskill_pnp.agents.pixel.factories import load_policy, make_workspace
from maniskill_pnp.cli import main as cli
from maniskill_pnp.quickstart import BUNDLED_AGENTS, QuickstartConfig, report, run


def test_quickstart_trains_evaluates_and_films(tiny_clutter_run, tmp_path):
    out = tmp_path / "quick"
    summary = run(QuickstartConfig(out=out, conveyor_steps=21, eval_iterations=1, agent=str(tiny_clutter_run), max_decisions=1))

    conveyor = summary["conveyor"]
    assert (out / "conveyor" / "qlearning_normal_seed0" / "qtable.pt").is_file()
    assert set(conveyor["test_case_success_rate"]) == {1, 2, 3, 4, 5}
    assert 0.0 <= conveyor["average_success_rate"] <= 1.0
    assert all(f"| Test case {c} |" in (out / "conveyor_eval" / "test_cases.md").read_text() for c in range(1, 6))
    assert conveyor["plots"] and all((out / "conveyor_eval").joinpath(p).is_file() for p in conveyor["plots"])

    clutter = summary["clutter"]
    assert clutter["decisions"] == 1 and len(clutter["primitives"]) == 1
    for key in ("video", "strip"):
        assert (out / "clutter_video").joinpath(clutter["files"][key]).stat().st_size > 0
    assert json.loads((out / "quickstart.json").read_text())["clutter"]["decisions"] == 1
    text = report(summary)
    assert "video:" in text and "table:" in text and str(out / "conveyor_eval" / "test_cases.md") in text


def test_quickstart_names_a_missing_agent(tmp_path):
    with pytest.raises(SystemExit, match="quickstart: agent .*nowhere.pt"):
        cli(["quickstart", "--agent", str(tmp_path / "nowhere.pt"), "--out", str(tmp_path / "q")])
    with pytest.raises(ValueError, match="conveyor_steps must be >= 1"):
        QuickstartConfig(conveyor_steps=0)


@pytest.mark.parametrize("name, backbone", [("gs-cpu-equi-fit", "equivariant"), ("gs-cpu-equi", "equivariant"),
                                                 ("gs-cpu-small", "small")])
def test_bundled_agent_loads_as_a_three_primitive_greedy_policy(name, backbone):
    path = BUNDLED_AGENTS[name]
    actor, cfg, counters = load_policy(path, torch.device("cpu"))
    assert cfg.task == "grasp_slide" and actor.q_network.primitives == ("grasp", "left_slide", "right_slide")
    assert cfg.preset == name and cfg.backbone == backbone
    assert counters["steps"] > 0
    assert path.stat().st_size < 16 * 2**20  # weights only, float16
    if name == "gs-cpu-equi-fit":  # the default agent tests its grasps' fit on the 3.5 mm fit heightmap
        assert (cfg.mask_grasp_fit, cfg.mask_fit_scale, cfg.heightmap_size) == (True, 2, 64)


def test_export_keeps_only_config_and_weights(tiny_clutter_run, tmp_path):
    dest = export_weights(tiny_clutter_run / "checkpoint.pt", tmp_path / "agent.pt")
    slim, full = load_checkpoint(dest), load_checkpoint(tiny_clutter_run / "checkpoint.pt")
    assert set(slim) == {"format", "config", "model", "counters"} and slim["config"] == full["config"]
    for name, tensor in full["model"].items():
        assert slim["model"][name].dtype == (torch.float16 if tensor.is_floating_point() else tensor.dtype)
        torch.testing.assert_close(slim["model"][name].float(), tensor.float(), atol=1e-2, rtol=1e-3)
    actor, _, _ = load_policy(dest, torch.device("cpu"))  # loads back into a float32 network
    assert next(actor.q_network.parameters()).dtype == torch.float32
    with pytest.raises(SystemExit, match="export-clutter: .*nowhere"):
        cli(["export-clutter", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.pt")])


def test_export_sets_how_the_agent_acts_and_nothing_else(tiny_clutter_run, tmp_path):
    cli(["export-clutter", str(tiny_clutter_run), "--out", str(tmp_path / "fit.pt"), "--mask-grasp-fit", "--mask-fit-scale", "2"])
    _, cfg, _ = load_policy(tmp_path / "fit.pt", torch.device("cpu"))
    assert cfg.mask_grasp_fit and not load_checkpoint(tiny_clutter_run / "checkpoint.pt")["config"].get("mask_grasp_fit")
    assert cfg.mask_fit_scale == 2 and make_workspace(cfg).fit_scale == 2  # its env observes the fit heightmap
    _, plain, _ = load_policy(tmp_path / "fit.pt", torch.device("cpu"), mask_grasp_fit=False)
    assert (plain.mask_grasp_fit, plain.mask_fit_scale) == (False, 1)  # no fit test, so no fit heightmap
    with pytest.raises(ValueError, match="mask_fit_scale"):  # a finer fit test needs the fit test
        export_weights(tiny_clutter_run / "checkpoint.pt", tmp_path / "x.pt", mask_fit_scale=2)
    with pytest.raises(ValueError, match="slide_margin"):  # a grasp-only agent has no slides
        export_weights(tiny_clutter_run / "checkpoint.pt", tmp_path / "x.pt", slide_margin=0.5)
    with pytest.raises(ValueError, match="only"):
        export_weights(tiny_clutter_run / "checkpoint.pt", tmp_path / "x.pt", lr=1.0)
