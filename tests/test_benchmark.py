"""``maniskill-pnp benchmark``: the whole protocol of an agent in one command (maniskill_pnp.bench.protocol).

One real quick run, shared by the tests of this file: the bundled G&S agent and an untrained conveyor Q-table, every
part played on real scenes by eval-clutter / eval-conveyor in two worker processes."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import pytest
import torch

from maniskill_pnp.agents.pixel.evaluate import LOSS_CAUSE_KEYS
from maniskill_pnp.agents.tabular.qtable import QTable
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, save_qtable
from maniskill_pnp.bench.protocol import (GRASP_SLIDE_PARTS, QUICK_EPISODES, BenchmarkConfig, agent_kind, plan_jobs,
                                          protocol)
from maniskill_pnp.bench.protocol_report import write_report
from maniskill_pnp.cli import main
from maniskill_pnp.tasks.conveyor_config import ConveyorSpec

BUNDLED = Path(__file__).resolve().parents[1] / "maniskill_pnp" / "weights" / "gs-cpu-equi-fit.pt"


@pytest.fixture(scope="module")
def qtable(tmp_path_factory) -> Path:
    spec = ConveyorSpec()
    path = tmp_path_factory.mktemp("conveyor") / "untrained-qtable.pt"
    save_qtable(QTable(spec.num_states, spec.action_n), ConveyorConfig(), path, spec=spec)
    return path


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, qtable) -> tuple[Path, float]:
    """``benchmark BUNDLED QTABLE --quick`` run once from the command line: the report folder and its wall time."""
    out = tmp_path_factory.mktemp("benchmark")
    t0 = time.perf_counter()
    main(["benchmark", str(BUNDLED), str(qtable), "--quick", "--out", str(out), "--workers", "2"])
    return out, time.perf_counter() - t0


def test_quick_protocol_plays_every_part_and_reports_it(quick_run):
    out, _ = quick_run
    report = (out / "report.md").read_text()
    assert "quick protocol" in report
    for part in GRASP_SLIDE_PARTS:  # every part has its row, with the metrics and the slide and loss columns
        row = next(line for line in report.splitlines() if line.startswith(f"| {part.name} | {QUICK_EPISODES} |"))
        assert row.count("%") == 4 and row.count(" / ") >= len(LOSS_CAUSE_KEYS) - 1
        summary = json.loads((out / "gs-cpu-equi-fit" / part.name.replace(" ", "_") / "eval_summary.json").read_text())
        assert summary["eval_config"]["grasp_only"] == part.grasp_only
        assert summary["eval_config"]["guard_force"] == part.guard_force
        assert len(summary["episodes"]) == QUICK_EPISODES
        assert all("futile_slides" in e and e["futile_slides"] <= e["slides"] for e in summary["episodes"])
    assert "G&S − its grasp-only restriction, paired per scene" in report
    assert "| hard_unseen | 1 |" in report.split("paired per scene")[1]
    assert "Random test cases 1-5, 5 episodes each" in report  # the conveyor Q-table's section
    assert (out / "scenarios.png").stat().st_size > 10_000 and (out / "paired.png").stat().st_size > 10_000
    for link in [part.split(")")[0] for part in report.split("](")[1:]]:  # every linked strip and figure exists
        assert (out / link).is_file(), link


def test_a_finished_run_is_not_run_again(quick_run, qtable, capsys):
    out, first_wall = quick_run
    before = (out / "gs-cpu-equi-fit" / "hard" / "eval_summary.json").stat().st_mtime_ns
    t0 = time.perf_counter()
    main(["benchmark", str(BUNDLED), str(qtable), "--quick", "--out", str(out)])
    assert time.perf_counter() - t0 < first_wall / 4
    assert (out / "gs-cpu-equi-fit" / "hard" / "eval_summary.json").stat().st_mtime_ns == before
    assert "parts done" in capsys.readouterr().out
    # a part that did not finish (its marker gone) is the only one left to run
    marker = out / "gs-cpu-equi-fit" / "min" / "done"
    saved = marker.read_text()
    marker.unlink()
    try:
        todo = [j for j in plan_jobs(BenchmarkConfig((BUNDLED, qtable), quick=True, out=out)) if not j.done]
        assert [(j.label, j.part.name) for j in todo] == [("gs-cpu-equi-fit", "min")]
    finally:
        marker.write_text(saved)


def test_results_of_another_protocol_or_agent_are_never_overwritten(quick_run, tmp_path):
    out, _ = quick_run
    with pytest.raises(SystemExit, match="another agent or protocol"):  # the full protocol into the quick folder
        main(["benchmark", str(BUNDLED), "--out", str(out)])
    other = tmp_path / "gs-cpu-equi-fit.pt"  # same name, other weights
    shutil.copy(BUNDLED.with_name("gs-cpu-equi.pt"), other)
    with pytest.raises(SystemExit, match="another agent or protocol"):
        main(["benchmark", str(other), "--quick", "--out", str(out)])


def test_two_agents_are_compared_scene_by_scene(quick_run, tmp_path):
    """The report of two G&S agents pairs them per scene; here the second agent's parts are the first's, copied."""
    out, _ = quick_run
    shutil.copytree(out / "gs-cpu-equi-fit", tmp_path / "gs-cpu-equi-fit")
    shutil.copytree(out / "gs-cpu-equi-fit", tmp_path / "twin")
    twin = tmp_path / "twin.pt"
    shutil.copy(BUNDLED, twin)
    cfg = BenchmarkConfig((BUNDLED, twin), quick=True, out=tmp_path)
    report = write_report(plan_jobs(cfg), cfg, {}).read_text()
    compared = report.split("## Agents compared with gs-cpu-equi-fit, paired per scene")[1]
    assert "twin − gs-cpu-equi-fit" in compared
    assert "| hard | 1 | +0.0 ± 0.0 | +0.0 ± 0.0 | +0.0 ± 0.0 | +0.0 ± 0.0 |" in compared


def test_protocol_sizes_and_bad_input(tmp_path):
    full = protocol("grasp_slide", quick=False)
    assert {(p.scenario, p.episodes) for p in full} >= {("medium", 24), ("min", 8), ("max", 8), ("complicated", 8),
                                                          ("hard", 32), ("hard_unseen", 48)}
    assert all(p.guard_force == 20.0 for p in full if p.scenario.startswith("hard"))
    assert {p.scenario for p in full if p.grasp_only} == {"medium", "hard", "hard_unseen", "anywhere"}
    assert all(p.episodes == QUICK_EPISODES for p in protocol("grasp_slide", quick=True))
    assert agent_kind(BUNDLED) == "grasp_slide"
    with pytest.raises(SystemExit, match="no such agent"):
        main(["benchmark", str(tmp_path / "missing.pt")])
    foreign = tmp_path / "foreign.pt"
    torch.save({"format": "something else"}, foreign)
    with pytest.raises(SystemExit, match="neither a clutter DQN agent nor a conveyor Q-table"):
        main(["benchmark", str(foreign), "--out", str(tmp_path / "b")])
    shutil.copy(BUNDLED, tmp_path / "gs-cpu-equi-fit.pt")
    with pytest.raises(SystemExit, match="share the name"):
        main(["benchmark", str(BUNDLED), str(tmp_path / "gs-cpu-equi-fit.pt")])
    with pytest.raises(SystemExit, match="workers must be >= 0"):
        main(["benchmark", str(BUNDLED), "--workers", "-1"])


def test_a_long_episode_strip_keeps_its_failures_and_latest_decisions():
    from maniskill_pnp.agents.pixel.decision_strip import MAX_STRIP_ROWS, strip_rows

    decisions = [dict(index=i, failed=i in (3, 40), lost=int(i == 7)) for i in range(60)]
    rows = strip_rows(decisions)
    indices = [d["index"] for d in rows]
    assert len(rows) == MAX_STRIP_ROWS and indices == sorted(indices)
    assert {3, 7, 40} <= set(indices) and indices[-1] == 59
    assert strip_rows(decisions[:5]) == decisions[:5]
