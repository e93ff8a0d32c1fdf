"""Benchmark of Part I (thesis ch. 4): train Q-learning and SARSA with the default config, then random test cases 1–5.

Prints the test-case table (thesis Table VIII: Q-learning ≈93%, SARSA ≈80%), the training and evaluation wall
times and the machine; writes the numbers as JSON through :func:`maniskill_pnp.bench.common.write_report`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from maniskill_pnp.agents.tabular.evaluate import TEST_CASES, EvalConfig
from maniskill_pnp.agents.tabular.evaluate import run as evaluate
from maniskill_pnp.agents.tabular.qtable import ALGORITHMS
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig
from maniskill_pnp.agents.tabular.recipe import main as train
from maniskill_pnp.bench.common import print_machine, write_report

THESIS_AVERAGE = {"qlearning": 0.93, "sarsa": 0.80}


@dataclass(frozen=True)
class ConveyorBenchConfig:
    """Settings of the conveyor benchmark.

    Attributes:
        iterations: Episodes per random test case (thesis: 50).
        steps: Training steps of each agent (the recipe's default 3000).
        seed: Training seed of both agents.
        out: Folder of the runs, the evaluation and ``conveyor.json``.
    """

    iterations: int = 50
    steps: int = 3000
    seed: int = 0
    out: Path = Path("runs/bench")


def run(cfg: ConveyorBenchConfig) -> dict:
    out = Path(cfg.out)
    trained = {}
    for algorithm in ALGORITHMS:
        train_cfg = ConveyorConfig(algorithm=algorithm, steps=cfg.steps, seed=cfg.seed, out=out / "conveyor_runs")
        trained[algorithm] = (train_cfg, train(train_cfg))
    report = evaluate(EvalConfig(
        checkpoints=tuple(c.run_dir for c, _ in trained.values()), iterations=cfg.iterations, out=out / "conveyor_eval",
    ))
    results = {}
    for (algorithm, (train_cfg, summary)), agent in zip(trained.items(), report["agents"].values()):
        results[algorithm] = dict(
            train_wall_s=summary["wall_s"], train_episodes=summary["episodes"], eval_wall_s=agent["wall_s"],
            test_case_success_rate={c: agent["test_cases"][c]["success_rate"] for c in TEST_CASES},
            average_success_rate=agent["test_case_average_success_rate"], thesis_average=THESIS_AVERAGE[algorithm],
        )
    path = write_report(out / "conveyor.json", "conveyor", {k: str(v) for k, v in asdict(cfg).items()}, results)
    print_machine()
    for algorithm, r in results.items():
        print(f"  {algorithm:9s} average {100 * r['average_success_rate']:.0f}% (thesis {100 * r['thesis_average']:.0f}%), "
              f"train {r['train_wall_s']:.0f} s for {r['train_episodes']} episodes, eval {r['eval_wall_s']:.0f} s")
    print(f"report: {path}")
    return results
