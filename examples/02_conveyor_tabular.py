# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.18.1
#   kernelspec:
#     display_name: Python 3 (ipykernel)
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Tabular Q-learning vs SARSA on the conveyor (thesis chapter 4)
#
# `ConveyorProximity-v1` has 640 state ids and at most 9 actions, so the thesis learns it with a **Q-table**.
# `maniskill_pnp.agents.tabular.recipe` trains one on TorchRL: the table is a TorchRL module, exploration is
# `EGreedyModule` over the phase's valid actions (the action mask comes from the public `ConveyorSpec`), a TorchRL
# `Collector` drives `make_torchrl_env("ConveyorProximity-v1")`, and the two algorithms differ only in the bootstrap
# term of the TD update:
#
# * Q-learning (off-policy): $Q(s,a) \leftarrow Q(s,a) + \alpha\,[r + \gamma \max_{a'} Q(s',a') - Q(s,a)]$
# * SARSA (on-policy): $Q(s,a) \leftarrow Q(s,a) + \alpha\,[r + \gamma\, Q(s',a'_{\text{taken}}) - Q(s,a)]$
#
# This is what `maniskill-pnp train-conveyor --algorithm qlearning|sarsa` runs (`cli.py` builds a `ConveyorConfig`
# from its options and calls `agents.tabular.recipe.main`), followed by `maniskill-pnp eval-conveyor` (`agents.tabular.evaluate.run`).
#
# **Sizes.** The full setting (all 3 speed classes, 3000 training steps per agent: about 5.5 min each on 2 cores) is
# what the README reports. The Q-table starts optimistic (1.0, the reward of a placed object), so the greedy policy
# tries every (pre-pick, grasp) pair of every sensed case before it settles: 9 cases × 9 × 6 pairs, about 500 episodes
# of 3 steps before learning shows. To see learning in a few minutes, this notebook fixes the belt speed to one class
# (`speed="medium"`: 3 sensed cases, about 160 pairs) and trains 900 steps per agent.

# %%
import os

# MANISKILL_PNP_EXAMPLES_SMALL=1 runs a tiny version of every step (the test suite does); unset, the sizes below are
# what this notebook runs in a few minutes on 2 CPU cores.
SMALL = os.environ.get("MANISKILL_PNP_EXAMPLES_SMALL", "0") == "1"
STEPS = 60 if SMALL else 900  # agent steps per algorithm (README: 3000 over all speeds); an episode is 1-3 steps
SPEED = "medium"  # train on one belt speed class (None: all three, as the README's runs)
EVAL_ITERATIONS = 1 if SMALL else 5  # greedy episodes per random test case (thesis: 50)
CATEGORY_ITERATIONS = 1 if SMALL else 2  # greedy episodes per (object kind, alignment, speed) cell
LOG_INTERVAL = 6 if SMALL else 30  # steps between two points of the learning curve

from maniskill_pnp.notebook import Markdown, display, output_dir, show as save_and_show

OUT = output_dir("02_conveyor_tabular")  # $MANISKILL_PNP_EXAMPLES_OUT, or runs/examples/02_conveyor_tabular in the checkout
print("small sizes:", SMALL, "| outputs in", OUT)

import numpy as np
import torch

from maniskill_pnp.agents.tabular.evaluate import EvalConfig, read_curve, run as evaluate
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, load_qtable, main as train
from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, SPEEDS, ConveyorSpec

import matplotlib.pyplot as plt


def show(fig, name: str) -> None:
    """Save ``fig`` as OUT/<name>.png and show it."""
    save_and_show(fig, name, OUT)


# %% [markdown]
# ## Train both agents
#
# Same seed, same hyper-parameters; ε decays linearly from 0.3 to 0.1 (the thesis' chapter-5 schedule) over the first
# two thirds of the run (as the defaults do: 2000 of 3000 steps), α = 0.5, γ = 0.9. Each run writes `config.json`,
# `qtable.pt` and CSV logs into its own folder.

# %%
configs = {
    algorithm: ConveyorConfig(algorithm=algorithm, steps=STEPS, eps_decay_steps=max(1, 2 * STEPS // 3), speed=SPEED,
                              log_interval=LOG_INTERVAL, seed=0, out=OUT / "runs")
    for algorithm in ("qlearning", "sarsa")
}
summaries = {}
for algorithm, cfg in configs.items():
    summaries[algorithm] = train(cfg)
    s = summaries[algorithm]
    print(f"{algorithm}: {s['steps']} steps, {s['episodes']} episodes, {s['placed']} placed, "
          f"running success {s['final_running_success_rate']:.0%}, {s['wall_s']:.0f} s")
    assert s["steps"] == STEPS and (cfg.run_dir / "qtable.pt").is_file()

# %% [markdown]
# ## Learning curves
#
# The running success rate of the ε-greedy behaviour (mean over the last 100 episodes), read back from each run's
# CSV log with `agents.tabular.evaluate.read_curve`, side by side, with ε on the same axes. The first few hundred steps are
# the optimistic exploration; then the success rate climbs.

# %%
fig, axes = plt.subplots(1, 2, figsize=(11, 3.6), sharey=True)
for ax, (algorithm, cfg) in zip(axes, configs.items()):
    steps, success = read_curve(cfg.run_dir, "train/success_rate")
    eps_steps, eps = read_curve(cfg.run_dir, "train/epsilon")
    assert len(steps) >= 2 and np.all((0 <= success) & (success <= 1))
    ax.plot(steps, 100 * success, label="success rate (running mean)")
    ax.plot(eps_steps, 100 * eps, "--", color="grey", label="ε (%)")
    ax.set_title({"qlearning": "Q-learning", "sarsa": "SARSA"}[algorithm] + f" (speed: {SPEED or 'all'})")
    ax.set_xlabel("training steps")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
axes[0].set_ylabel("%")
axes[0].legend(loc="upper left", fontsize=8)
show(fig, "learning_curves")

# %% [markdown]
# ## What the greedy policies chose
#
# For every sensed (alignment, speed) the greedy pre-pick coordinate and then the greedy grasp coordinate under it,
# read straight out of each Q-table (only the phase's valid actions count), next to the hand-marked best pair of
# `ConveyorSpec.best` (several pairs around it also catch the object). A table knows only the states it visited:
# a case never seen (here the other speed classes) keeps its initial values, so its argmax is the first valid action.

# %%
spec = ConveyorSpec()
tables = {algorithm: load_qtable(cfg.run_dir / "qtable.pt")[0].values for algorithm, cfg in configs.items()}


def greedy_pair(q: torch.Tensor, alignment: str, speed: str) -> tuple[int, int]:
    prepick = int(q[spec.encode_state("pre_pick", speed, alignment, None), : spec.num_actions["pre_pick"]].argmax())
    grasp = int(q[spec.encode_state("grasp", speed, alignment, prepick), : spec.num_actions["grasp"]].argmax())
    return prepick, grasp


rows = ["| alignment | speed | hand-marked best | Q-learning | SARSA |", "|---|---|---|---|---|"]
for speed in SPEEDS:
    for alignment in ALIGNMENTS:
        best = spec.best(alignment, speed)
        pairs = [greedy_pair(tables[a], alignment, speed) for a in ("qlearning", "sarsa")]
        cells = [f"{pair}" + (" ✓" if pair == best else "") for pair in pairs]
        rows.append(f"| {alignment} | {speed} | {best} | " + " | ".join(cells) + " |")
display(Markdown("(pre-pick index, grasp index) per sensed case\n\n" + "\n".join(rows)))

# %% [markdown]
# ## Greedy evaluation
#
# `agents.tabular.evaluate.run` (the `eval-conveyor` command) runs both greedy policies on the same seeded episodes:
#
# * per category (thesis Tables II-VII): every (object kind, alignment, speed) cell, `CATEGORY_ITERATIONS` episodes
#   each; summarized below per speed class, where the speed trained on stands out;
# * the thesis' random test cases 1-5 (Table VIII): (1) alignments in thirds, (2) speeds in thirds, (3)-(5) at least
#   40% cuboids / spheres / cylinders. They mix all three speeds, so an agent trained on one class can only place the
#   objects of that class.
#
# It writes Markdown and CSV tables, `eval.json`, and its own learning-curve PNG into the evaluation folder.

# %%
report = evaluate(EvalConfig(checkpoints=tuple(cfg.run_dir for cfg in configs.values()), iterations=EVAL_ITERATIONS,
                             category_iterations=CATEGORY_ITERATIONS, out=OUT / "eval"))
labels = list(report["agents"])
rows = ["| speed class | " + " | ".join(f"{label} success_rate" for label in labels) + " |", "|---" * (1 + len(labels)) + "|"]
for speed in SPEEDS:
    rates = []
    for label in labels:
        cells = [c for key, c in report["agents"][label]["categories"].items() if key.startswith(f"{speed}/")]
        assert len(cells) == 9 and all(c["episodes"] == CATEGORY_ITERATIONS for c in cells)
        rates.append(np.mean([c["success_rate"] for c in cells]))
    rows.append(f"| {speed}" + (" (trained)" if speed == SPEED else "") + " | " + " | ".join(f"{r:.0%}" for r in rates) + " |")
display(Markdown(f"Per speed class: mean over the 9 (kind, alignment) cells, {CATEGORY_ITERATIONS} episodes each\n\n"
                 + "\n".join(rows)))
display(Markdown((OUT / "eval" / "test_cases.md").read_text()))
for label, agent in report["agents"].items():
    assert set(agent["test_cases"]) == {1, 2, 3, 4, 5}
    assert all(case["episodes"] == EVAL_ITERATIONS for case in agent["test_cases"].values())
assert (OUT / "eval" / "test_cases.csv").is_file() and (OUT / "eval" / "categories.md").is_file()

# %% [markdown]
# With all three speed classes and the full 3000 steps per agent, the README reports 100% (Q-learning) and 91%
# (SARSA) on the random test cases with 50 iterations each (thesis: about 93% and 80%). From the command line:
#
# ```bash
# .venv/bin/maniskill-pnp train-conveyor --algorithm qlearning --seed 0
# .venv/bin/maniskill-pnp train-conveyor --algorithm sarsa --seed 0
# .venv/bin/maniskill-pnp eval-conveyor runs/conveyor/qlearning_normal_seed0 runs/conveyor/sarsa_normal_seed0 \
#     --iterations 50 --category-iterations 5
# ```
