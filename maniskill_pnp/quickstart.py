"""The README's main job: a real default run of the package in about ten minutes on 2 CPU cores.

1. train tabular Q-learning on ConveyorProximity-v1 (thesis part I; the default config, 3000 steps),
2. evaluate it greedily on the thesis' random test cases 1-5 (table and learning-curve plot),
3. film one ClutterGraspSlide-v1 episode of the G&S agent trained with the ``gs-cpu-equi-fit`` preset that ships
   with the package (:data:`BUNDLED_AGENTS`): an MP4 of the arm beside each decision and a decision strip.

Run it with ``maniskill-pnp quickstart`` (``bash scripts/run.sh`` installs everything first); it prints where the
table, plots and video were written and leaves ``quickstart.json`` with all paths and numbers in ``out``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from maniskill_pnp.agents.run_io import require_positive, write_json

#: Agents that ship with the package: network weights and config exported from a training run
#: (:func:`~maniskill_pnp.agents.pixel.checkpoint.export_weights`); the README says which run and command.
BUNDLED_AGENTS = {name: Path(__file__).parent / "weights" / f"{name}.pt"
                  for name in ("gs-cpu-equi-fit", "gs-cpu-equi", "gs-cpu-small")}


@dataclass(frozen=True)
class QuickstartConfig:
    """Settings of the main job (defaults: the README's run)."""

    out: Path = Path("runs/quickstart")
    """Folder for everything the job writes."""
    conveyor_steps: int = 3000
    """Training steps of the conveyor Q-learning agent (one step is one phase decision)."""
    eval_iterations: int = 20
    """Greedy episodes per random test case of the conveyor evaluation (thesis: 50)."""
    agent: str = "gs-cpu-equi-fit"
    """The G&S agent to film: a bundled agent's name (see BUNDLED_AGENTS) or a checkpoint / run folder."""
    scenario: str = "train"
    """ClutterGraspSlide-v1 scene of the filmed episode (as record-clutter's --scenario)."""
    max_decisions: int = 12
    """Cap on the decisions of the filmed episode."""
    seed: int = 0
    """Seed of the conveyor training and of the filmed scene."""

    def __post_init__(self):
        object.__setattr__(self, "out", Path(self.out))
        require_positive(self, ("conveyor_steps", "eval_iterations", "max_decisions"))

    @property
    def agent_path(self) -> Path:
        path = BUNDLED_AGENTS.get(self.agent, Path(self.agent))
        if not path.exists():
            raise FileNotFoundError(f"agent {self.agent!r}: {path} does not exist (bundled agents: {list(BUNDLED_AGENTS)})")
        return path


def run(cfg: QuickstartConfig) -> dict:
    """Run the three parts; return (and write to ``quickstart.json``) their numbers and files."""
    from maniskill_pnp.agents.pixel.video import ClutterVideoConfig, run as record_clutter
    from maniskill_pnp.agents.tabular.evaluate import EvalConfig, run as evaluate_conveyor
    from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, main as train_conveyor

    agent = cfg.agent_path  # a missing agent fails before the long parts
    t0 = time.perf_counter()
    print(f"[1/3] training tabular Q-learning on ConveyorProximity-v1 ({cfg.conveyor_steps} steps)", flush=True)
    conveyor_cfg = ConveyorConfig(algorithm="qlearning", steps=cfg.conveyor_steps, seed=cfg.seed, out=cfg.out / "conveyor")
    train = train_conveyor(conveyor_cfg)
    t1 = time.perf_counter()

    print(f"[2/3] greedy evaluation on the random test cases 1-5 ({cfg.eval_iterations} episodes each)", flush=True)
    evaluation = evaluate_conveyor(EvalConfig(
        checkpoints=(conveyor_cfg.run_dir,), iterations=cfg.eval_iterations, out=cfg.out / "conveyor_eval", seed=12345 + cfg.seed))
    (result,) = evaluation["agents"].values()
    t2 = time.perf_counter()

    print(f"[3/3] filming one ClutterGraspSlide-v1 episode of the {cfg.agent} agent", flush=True)
    video = record_clutter(ClutterVideoConfig(
        checkpoint=agent, scenario=cfg.scenario, seed=1000 + cfg.seed, max_steps=cfg.max_decisions, out=cfg.out / "clutter_video"))
    t3 = time.perf_counter()

    eval_dir = cfg.out / "conveyor_eval"
    summary = dict(
        conveyor=dict(run=str(conveyor_cfg.run_dir), train=train, test_case_success_rate=result["test_cases"],
                      average_success_rate=result["test_case_average_success_rate"], table=str(eval_dir / "test_cases.md"),
                      plots=evaluation["plots"]),
        clutter=dict(agent=str(agent), decisions=len(video["decisions"]), objects=video["objects"], placed=video["placed"],
                     primitives=[d["primitive"] for d in video["decisions"]], files=video["files"]),
        wall_s=dict(conveyor_train=round(t1 - t0, 1), conveyor_eval=round(t2 - t1, 1), clutter_video=round(t3 - t2, 1)),
        config={k: str(v) for k, v in dataclasses.asdict(cfg).items()},
    )
    write_json(cfg.out / "quickstart.json", summary)
    return summary


def report(summary: dict) -> str:
    """The lines the command prints at the end: the numbers and where the files are."""
    conv, clut = summary["conveyor"], summary["clutter"]
    lines = [
        f"conveyor Q-learning: average greedy success {conv['average_success_rate']:.0%} over the random test cases 1-5",
        f"  table: {conv['table']}",
        *(f"  plot: {p}" for p in conv["plots"]),
        f"ClutterGraspSlide-v1: {clut['placed']} of {clut['objects']} objects placed in {clut['decisions']} decisions "
        f"({', '.join(clut['primitives'])})",
        f"  video: {clut['files']['video']}",
        f"  decision strip: {clut['files']['strip']}",
        f"times (s): {summary['wall_s']}",
    ]
    return "\n".join(lines)


__all__ = ["BUNDLED_AGENTS", "QuickstartConfig", "report", "run"]
