"""Greedy evaluation of conveyor Q-tables, laid out like the thesis' chapter 4 (Tables II–VIII, Figures 8–10).

* Per-category tables (thesis Tables II–VII): ``success_rate`` per object kind (rows) × alignment (columns), one
  table per belt speed, for each agent.
* Random test cases 1–5 (thesis Table VIII), ``iterations`` episodes each: (1) random kinds and speeds, alignments
  in thirds; (2) random kinds and alignments, speeds in thirds; (3), (4), (5) random alignments and speeds, at least
  40% cuboids, spheres and cylinders respectively. Every agent meets the same drawn objects (same seed).
* Learning curves: the training ``train/success_rate`` CSV logs, Q-learning vs SARSA and normal vs other reward
  schemes, as PNG.

Metrics (defined in ``docs/metrics.md``): ``success_rate`` = objects placed in the bin / pick-and-place attempts;
one episode is one object and one attempt, so it is the fraction of episodes that placed their object.
``grasp_success`` = successful grasps / grasp attempts (episodes that reached the grasp phase; a grasp counts when
the task reports ``grasp_success`` for it).
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from maniskill_pnp.agents.run_io import atomic_write_bytes
from maniskill_pnp.agents.tabular.qtable import QTable, make_qtable_policy
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, load_qtable, make_env, qtable_file
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.tasks.conveyor import ConveyorProximityEnv
from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, OBJECT_KINDS, PHASES, SPEEDS

#: Test case -> the object kind that makes up at least 40% of it (thesis order: cuboid, sphere, cylinder).
MAJORITY_KIND = {3: "cuboid", 4: "sphere", 5: "cylinder"}
TEST_CASES = (1, 2, 3, 4, 5)
#: ``info["primitive_index"]`` of the conveyor's grasp step.
GRASP_PRIMITIVE = ConveyorProximityEnv.PRIMITIVES.index("grasp")


@dataclass(frozen=True)
class EvalConfig:
    """Settings of an evaluation run.

    Attributes:
        checkpoints: ``qtable.pt`` files, or run folders that hold one.
        iterations: Episodes per random test case (thesis: 50).
        category_iterations: Episodes per (kind, alignment, speed) cell of the per-category tables; 0 skips them.
        out: Folder for the tables (Markdown, CSV), ``eval.json`` and the plots.
        seed: Seed of the test-case draws and of the episodes (the same for every agent).
        curves: Run folders whose training logs to plot; empty = the checkpoints' run folders.
    """

    checkpoints: tuple[Path, ...] = ()
    iterations: int = 50
    category_iterations: int = 0
    out: Path = Path("runs/conveyor_eval")
    seed: int = 12345
    curves: tuple[Path, ...] = field(default_factory=tuple)

    def __post_init__(self):
        if not self.checkpoints:
            raise ValueError("give at least one checkpoint (qtable.pt or its run folder)")
        if self.iterations < 1 or self.category_iterations < 0:
            raise ValueError(f"need iterations >= 1 and category_iterations >= 0, got {self.iterations}, {self.category_iterations}")


# ----------------------------------------------------------------------------- test-case draws
def test_case_draws(case: int, iterations: int, rng: np.random.Generator) -> list[tuple[str, str, str]]:
    """The ``iterations`` (kind, alignment, speed) of random test case ``case`` (1–5; see the module docstring)."""
    if case not in TEST_CASES:
        raise ValueError(f"unknown test case {case}; valid: {list(TEST_CASES)}")

    def thirds(values):
        out = [values[i % len(values)] for i in range(iterations)]
        rng.shuffle(out)
        return out

    def random(values):
        return [values[i] for i in rng.integers(len(values), size=iterations)]

    kinds = random(OBJECT_KINDS)
    if case in MAJORITY_KIND:
        n = math.ceil(0.4 * iterations)
        kinds = [MAJORITY_KIND[case]] * n + random(OBJECT_KINDS)[n:]
        rng.shuffle(kinds)
    alignments = thirds(ALIGNMENTS) if case == 1 else random(ALIGNMENTS)
    speeds = thirds(SPEEDS) if case == 2 else random(SPEEDS)
    return list(zip(kinds, alignments, speeds))


# ----------------------------------------------------------------------------- episodes
class GreedyRunner:
    """Runs greedy episodes of one Q-table; one env per object kind (the kind is a make-time option of the task)."""

    def __init__(self, table: QTable, cfg: ConveyorConfig, seed: int):
        self.envs = {}
        for kind in OBJECT_KINDS:
            env = make_env(cfg, reward_scheme="normal", object_kinds=(kind,), alignment=None, speed=None)
            env.set_seed(seed + OBJECT_KINDS.index(kind))
            self.envs[kind] = env
        first = next(iter(self.envs.values()))
        self.policy, _, _ = make_qtable_policy(table, first.action_spec_unbatched, eps_init=0.0, eps_end=0.0, annealing_num_steps=1)

    @torch.no_grad()
    def episode(self, kind: str, alignment: str, speed: str) -> dict:
        """One greedy episode; its outcome as the task reports it in the last step's outcome keys."""
        env = self.envs[kind]
        td = env.reset(options=dict(alignment=alignment, speed=speed))
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            for _ in PHASES:
                td = env.step(self.policy(td))
                if bool(td.get(("next", "done")).any()):
                    break
                td = step_mdp(td)
        last = td.get("next")  # the episode's last step: a grasp attempt, or the step that ended it before one
        return dict(
            kind=kind, alignment=alignment, speed=speed, placed=bool(last.get("success").any()),
            grasp_attempt=bool((last.get("primitive_index") == GRASP_PRIMITIVE).any()),
            grasped=bool(last.get("grasp_success").any()), reward=float(last.get("reward").reshape(-1)[0]),
        )

    def close(self):
        for env in self.envs.values():
            env.close()


def summarize(episodes: list[dict]) -> dict:
    """``success_rate`` and ``grasp_success`` (see the module docstring) of a list of episode records."""
    attempts = sum(e["grasp_attempt"] for e in episodes)
    return dict(
        episodes=len(episodes),
        success_rate=sum(e["placed"] for e in episodes) / max(1, len(episodes)),
        grasp_success=sum(e["grasped"] for e in episodes) / attempts if attempts else float("nan"),
    )


# ----------------------------------------------------------------------------- tables
def _pct(x: float) -> str:
    return "n/a" if x != x else f"{100 * x:.0f}%"


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, lambda f: f.write(text.encode()))


def _write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(header)
    writer.writerows(rows)
    _write_text(path, buf.getvalue())


def agent_label(cfg: ConveyorConfig) -> str:
    name = {"qlearning": "Q-learning", "sarsa": "SARSA"}[cfg.algorithm]
    return name if cfg.reward_scheme == "normal" else f"{name} ({cfg.reward_scheme})"


# ----------------------------------------------------------------------------- learning curves
def read_curve(run_dir: Path, name: str = "train/success_rate") -> tuple[np.ndarray, np.ndarray]:
    """``(steps, values)`` of one scalar logged by the recipe's CSV logger."""
    path = Path(run_dir) / "scalars" / f"{name}.csv"
    if not path.is_file():
        raise FileNotFoundError(f"no training log {path}")
    data = np.loadtxt(path, delimiter=",", ndmin=2)
    return data[:, 0], data[:, 1]


def plot_curves(run_dirs: list[Path], out: Path) -> list[Path]:
    """One PNG per comparison: algorithms under one reward scheme, reward schemes under one algorithm (with a
    single run: its own curve, under its reward scheme)."""
    import matplotlib.pyplot as plt  # the backend is left to the caller (Agg when there is no display)

    runs = []
    for d in run_dirs:
        try:  # a Q-table outside its run folder has no config or training log to plot
            cfg = ConveyorConfig.from_json(json.loads((Path(d) / "config.json").read_text()))
            runs.append((cfg, *read_curve(d)))
        except FileNotFoundError:
            continue
    groups = {}
    for cfg, x, y in runs:
        groups.setdefault(("scheme", cfg.reward_scheme), []).append((agent_label(cfg), x, y))
        groups.setdefault(("algorithm", cfg.algorithm), []).append((f"{cfg.reward_scheme} rewards", x, y))
    written = []
    for (by, value), lines in groups.items():
        if len(lines) < 2 and not (len(runs) == 1 and by == "scheme"):
            continue
        fig, ax = plt.subplots(figsize=(6, 3.6))
        for label, x, y in lines:
            ax.plot(x, 100 * y, label=label)
        ax.set_xlabel("training steps")
        ax.set_ylabel("success rate (%), running mean")
        ax.set_ylim(0, 100)
        ax.grid(alpha=0.3)
        ax.legend()
        ax.set_title(f"{'reward scheme' if by == 'scheme' else 'algorithm'}: {value}")
        fig.tight_layout()
        path = out / f"curve_{by}_{value}.png"
        out.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


# ----------------------------------------------------------------------------- main
def run(cfg: EvalConfig) -> dict:
    """Evaluate every checkpoint; write ``test_cases.md/.csv``, ``categories_*.md`` / ``categories.csv``,
    ``eval.json`` and the learning-curve PNGs into ``cfg.out``; print the test-case table."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    agents = []
    for p in cfg.checkpoints:  # load all first: a bad file fails before any episode runs
        table, train_cfg, _ = load_qtable(qtable_file(p))
        agents.append((agent_label(train_cfg), table, train_cfg, qtable_file(p)))

    rng = np.random.default_rng(cfg.seed)
    cases = {c: test_case_draws(c, cfg.iterations, rng) for c in TEST_CASES}
    results = {}
    for label, table, train_cfg, path in agents:
        t0 = time.perf_counter()
        runner = GreedyRunner(table, train_cfg, cfg.seed)
        res = dict(checkpoint=str(path), config=train_cfg.to_json(), test_cases={}, categories={})
        total = len(TEST_CASES) * cfg.iterations + len(OBJECT_KINDS) * len(ALIGNMENTS) * len(SPEEDS) * cfg.category_iterations
        with progress_bar(total=total, desc=f"eval {label}", unit="ep") as bar:
            for case, draws in cases.items():
                eps = []
                for d in draws:
                    eps.append(runner.episode(*d))
                    bar.update()
                res["test_cases"][case] = summarize(eps)
            for speed in SPEEDS if cfg.category_iterations else ():
                for kind in OBJECT_KINDS:
                    for alignment in ALIGNMENTS:
                        eps = []
                        for _ in range(cfg.category_iterations):
                            eps.append(runner.episode(kind, alignment, speed))
                            bar.update()
                        res["categories"][f"{speed}/{kind}/{alignment}"] = summarize(eps)
        runner.close()
        rates = [res["test_cases"][c]["success_rate"] for c in TEST_CASES]
        res["test_case_average_success_rate"] = float(np.mean(rates))
        res["wall_s"] = time.perf_counter() - t0
        results[label] = res

    labels = list(results)
    # Table VIII: random test cases
    header = ["Test case"] + [f"{lb} success_rate" for lb in labels]
    rows = [[f"Test case {c}"] + [_pct(results[lb]["test_cases"][c]["success_rate"]) for lb in labels] for c in TEST_CASES]
    rows.append(["Average"] + [_pct(results[lb]["test_case_average_success_rate"]) for lb in labels])
    md = f"Random test cases, {cfg.iterations} iterations each (greedy policies, seed {cfg.seed})\n\n" + markdown_table(header, rows)
    _write_text(out / "test_cases.md", md)
    _write_csv(
        out / "test_cases.csv", ["agent", "test_case", "episodes", "success_rate", "grasp_success"],
        [[lb, c, *(results[lb]["test_cases"][c][k] for k in ("episodes", "success_rate", "grasp_success"))]
         for lb in labels for c in TEST_CASES],
    )
    # Tables II–VII: per category, one table per agent and speed
    if cfg.category_iterations:
        parts, csv_rows = [], []
        for lb in labels:
            for speed in SPEEDS:
                cells = results[lb]["categories"]
                rows = [[kind] + [_pct(cells[f"{speed}/{kind}/{a}"]["success_rate"]) for a in ALIGNMENTS] for kind in OBJECT_KINDS]
                parts.append(f"### {lb}: success_rate at {speed} speed ({cfg.category_iterations} episodes per cell)\n\n"
                             + markdown_table(["Object category", *ALIGNMENTS], rows))
                csv_rows += [[lb, speed, kind, a, *(cells[f"{speed}/{kind}/{a}"][k] for k in ("episodes", "success_rate", "grasp_success"))]
                             for kind in OBJECT_KINDS for a in ALIGNMENTS]
        _write_text(out / "categories.md", "\n".join(parts))
        _write_csv(out / "categories.csv", ["agent", "speed", "kind", "alignment", "episodes", "success_rate", "grasp_success"], csv_rows)
    # Figures 8–10: learning curves
    curve_dirs = list(cfg.curves) or [p.parent for _, _, _, p in agents]
    plots = plot_curves(curve_dirs, out)
    summary = dict(settings=dict(iterations=cfg.iterations, category_iterations=cfg.category_iterations, seed=cfg.seed),
                   agents=results, plots=[str(p) for p in plots])
    _write_text(out / "eval.json", json.dumps(summary, indent=2, default=str))
    print(md)
    for lb in labels:
        print(f"{lb}: eval wall {results[lb]['wall_s']:.0f} s")
    print(f"tables and plots: {out}")
    return summary
