"""Build the example notebooks of ``examples/`` from the cell sources below: the one source of the notebooks.

Edit the cells here, then run ``.venv/bin/python examples/build_notebooks.py``; it rewrites every ``.ipynb`` (without
outputs, with stable cell ids, so a rebuild of unchanged cells changes no byte). ``--check`` writes nothing and exits
with status 1 when a notebook differs from what this file builds (``tests/test_examples.py`` checks the same).

Every notebook's first code cell reads ``MANISKILL_PNP_EXAMPLES_SMALL`` ("1": tiny sizes, what the test suite runs;
unset: the sizes a newcomer runs in a few minutes on 2 CPU cores) and ``MANISKILL_PNP_EXAMPLES_OUT`` (output folder;
default ``runs/examples/<notebook stem>`` under the repository root, which git ignores).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import nbformat

HERE = Path(__file__).resolve().parent


def md(text: str) -> tuple[str, str]:
    return ("markdown", text.strip("\n"))


def code(text: str) -> tuple[str, str]:
    return ("code", text.strip("\n"))


def setup_cell(stem: str, sizes: str, imports: str) -> tuple[str, str]:
    """The first code cell of every notebook: sizes from MANISKILL_PNP_EXAMPLES_SMALL, the output folder, imports."""
    return code(f'''
import os
from pathlib import Path

# MANISKILL_PNP_EXAMPLES_SMALL=1 runs a tiny version of every step (the test suite does); unset, the sizes below are
# what this notebook runs in a few minutes on 2 CPU cores.
SMALL = os.environ.get("MANISKILL_PNP_EXAMPLES_SMALL", "0") == "1"
{sizes.strip()}


def repo_root() -> Path:
    """The checkout holding this notebook (runs/ there is git-ignored), else the working directory."""
    for folder in (Path.cwd(), *Path.cwd().parents):
        if (folder / "pyproject.toml").is_file() and (folder / "maniskill_pnp").is_dir():
            return folder
    return Path.cwd()


OUT = Path(os.environ.get("MANISKILL_PNP_EXAMPLES_OUT") or repo_root() / "runs" / "examples" / "{stem}")
OUT.mkdir(parents=True, exist_ok=True)
print("small sizes:", SMALL, "| outputs in", OUT)

{imports.strip()}
''')


#: Shared by every notebook: matplotlib figures shown with display() and saved into OUT.
SHOW = '''
import matplotlib.pyplot as plt
from IPython.display import Image, display


def show(fig, name: str) -> None:
    """Save ``fig`` as OUT/<name>.png and show that PNG inline. (Not plt.show(): the package's plot functions switch
    matplotlib to its non-interactive Agg backend, after which plt.show() shows nothing.)"""
    path = OUT / f"{name}.png"
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    display(Image(filename=str(path)))
'''

# ----------------------------------------------------------------------------------------------------------------------
# 01: the three tasks
# ----------------------------------------------------------------------------------------------------------------------
TASKS = [
    md('''
# The three thesis tasks as ManiSkill environments

`maniskill_pnp` turns the three parts of a thesis on deep RL for industrial pick-and-place into registered
ManiSkill 3 tasks. Importing the package registers them with gymnasium:

| id | thesis part | observation | one action = |
|---|---|---|---|
| `ConveyorProximity-v1` | I | one discrete state id (ray proximity sensors) | one phase of a pick: wait and sense, pre-pick coordinate, grasp coordinate |
| `ClutterGrasp-v1` | II | RGB-D heightmaps (colour + height above the table) | one top-down grasp at a heightmap pixel and yaw, then place in the bin |
| `ClutterGraspSlide-v1` | III | the same heightmaps | one grasp, left slide or right slide at a pixel and yaw |

Unlike ManiSkill's own tasks (one low-level control action per step), **one step here is a whole motion primitive**:
the Panda's motions are planned with OMPL (RRT-Connect) and executed in the PhysX simulation inside `step`. A
planning failure is an outcome in `info`, never an exception. Everything runs on the CPU: PhysX on the CPU and
rendering through lavapipe (`maniskill_pnp.runtime.default_backends` picks the GPU renderer when CUDA is there).
'''),
    setup_cell("01_tasks", '''
NUM_OBJECTS = 5 if SMALL else 10  # objects in the random clutters
''', '''
import gymnasium as gym
import numpy as np
import torch

import maniskill_pnp  # noqa: F401  (registers the task ids)
from maniskill_pnp.runtime import default_backends
from maniskill_pnp.tasks import TASK_IDS

BACKENDS = default_backends()  # {"sim_backend": "physx_cpu", "render_backend": "cpu"} on a CPU-only machine
print(BACKENDS)
assert {"ConveyorProximity-v1", "ClutterGrasp-v1", "ClutterGraspSlide-v1"} <= set(TASK_IDS)
''' + SHOW),
    md('''
## Part I: `ConveyorProximity-v1`

A cuboid, cylinder or sphere rides a belt towards the robot in one of three lanes (left / center / right) at one of
three speeds. There is no camera: two horizontal ray gates time the object (speed class) and a row of downward rays
under the second gate sees its lane (alignment), both PhysX raycasts. The MDP is tiny and discrete, as in the thesis:
an episode is one object and at most three steps, one per **phase**:

1. `initial`: action 0 only, wait until the sensors have seen the object;
2. `pre_pick`: one of 9 pre-pick coordinates above the belt (3 lanes × 3 rows), reached by a planned motion while
   the object keeps moving;
3. `grasp`: one of 6 grasp coordinates along the belt below the pre-pick one; descend, close, lift and place.

The observation is one state id that encodes (phase, sensed speed, sensed alignment, last coordinate);
`info` decodes it, holds the raw ray readings, and (for analysis only) the hidden ground truth of the episode.
'''),
    code('''
env = gym.make("ConveyorProximity-v1", render_mode="rgb_array", **BACKENDS)
obs, info = env.reset(seed=0)
conveyor = env.unwrapped.conveyor  # ConveyorSpec: geometry, sensors, coordinate sets and the state encoding

print("observation space:", env.observation_space, "-", conveyor.num_states, "state ids")
print("action space:     ", env.action_space, "- valid actions per phase:", conveyor.num_actions)
state = int(obs.reshape(-1)[0])
print("state id", state, "=", conveyor.decode_state(state))
print("info:", {k: info[k] for k in ("phase", "sensed_speed", "sensed_alignment", "action_mask", "outcome")})
print("hidden truth:", info["truth"])
assert conveyor.decode_state(state)["phase"] == info["phase"] == "initial"
assert env.unwrapped.single_observation_space.n == conveyor.num_states
'''),
    md('''
An action that is not valid in the current phase (`info["action_mask"]` says which are) is a failed attempt: nothing
moves, the failure reward, `info["invalid_action"]`, and the episode ends (the agents mask invalid actions out, see
`agents/tabular/qtable.py: StateActionMask`). A new episode from the same seed follows:
'''),
    code('''
obs, reward, terminated, truncated, info = env.step(5)  # the initial phase has one action: 0 (wait and sense)
print(f"reward {reward.item()}, terminated {bool(terminated.item())}, invalid_action {bool(info['invalid_action'])}: "
      f"{info['outcome']}")
assert info["invalid_action"] and terminated.item()
obs, info = env.reset(seed=0)
'''),
    md('''
One episode with the hand-marked best coordinates for the sensed lane and speed (`ConveyorSpec.oracle_action`, the
thesis' hand-designed choice and the "bonus" reward's reference). We render the scene before each step.
'''),
    code('''
frames = [env.render()[0].cpu().numpy()]
titles = ["reset"]
while info["phase"] != "done":
    phase = info["phase"]
    sensed_alignment = None if info["sensed_alignment"] == "unknown" else info["sensed_alignment"]
    sensed_speed = None if info["sensed_speed"] == "unknown" else info["sensed_speed"]
    action = conveyor.oracle_action(phase, sensed_alignment, sensed_speed)
    obs, reward, terminated, truncated, info = env.step(action)
    frames.append(env.render()[0].cpu().numpy())
    titles.append(f"after {phase} (action {action})")
    print(f"{phase:>9} action {action}: reward {reward.item():.1f}, terminated {bool(terminated.item())}, "
          f"next state {conveyor.decode_state(int(obs.reshape(-1)[0]))}")
print("outcome:", info["outcome"], "| object in bin:", info["object_in_bin"])
print("sensed:", info["sensed_alignment"], info["sensed_speed"], "| truth:", info["truth"]["alignment"], info["truth"]["speed"])
assert info["sensed_alignment"] == info["truth"]["alignment"] and info["sensed_speed"] == info["truth"]["speed"]
assert bool(terminated.item()) and reward.item() in (0.0, 0.5, 1.0)

fig, axes = plt.subplots(1, len(frames), figsize=(3.2 * len(frames), 3.4))
for ax, frame, title in zip(axes, frames, titles):
    ax.imshow(frame)
    ax.set_title(title, fontsize=9)
    ax.axis("off")
show(fig, "conveyor_episode")
'''),
    md('''
The sensors' raw readings: each downward alignment ray reports the distance at which it hit the object (`inf`: it
missed), and the two gate times give the speed estimate that is binned into slow / medium / fast.
'''),
    code('''
rays = info["rays"]
ray_x = np.asarray(conveyor.align_ray_x)
dist = np.asarray(rays["align_distances"], dtype=float)
hit = np.isfinite(dist)
fig, ax = plt.subplots(figsize=(6, 2.6))
ax.bar(ray_x[hit] * 100, dist[hit] * 100, width=1.8, label="hit: distance from the ray origin")
ax.plot(ray_x[~hit] * 100, np.zeros((~hit).sum()), "x", color="grey", label="missed")
for name, offset in zip(("left", "center", "right"), conveyor.lane_offsets):
    ax.axvline(offset * 100, color="k", lw=0.5, ls=":")
    ax.text(offset * 100, ax.get_ylim()[1] * 0.95, name, ha="center", fontsize=8)
ax.set_xlabel("ray x offset from the belt centre (cm)")
ax.set_ylabel("cm")
ax.legend(fontsize=8, loc="lower right")
ax.set_title(f"alignment rays; speed estimate {rays['speed_estimate']:.3f} m/s (belt: {info['truth']['belt_speed']} m/s)", fontsize=9)
show(fig, "conveyor_rays")
env.close()
'''),
    md('''
## Part II: `ClutterGrasp-v1`

10 to 15 procedural objects (regular and irregular: cuboids, cylinders, spheres, L, T, U, arches, wedges, convex
hulls) are dropped loosely packed into the workspace. A far top-down camera and a perspective camera are fused
into two **heightmaps** at 2 mm/px (224×224 by default): colour (uint8) and height above the table (float32, m).
The action is one flat index over (rotation, row, col), 16 × 224 × 224: a top-down grasp at the pixel's 3-D point
with the rotation's yaw, then place in the bin and return out of the cameras' view
(`env.unwrapped.action_layout` encodes and decodes it). Reward: 1 placed, 0.5 grasped only, 0 otherwise.
'''),
    code('''
env = gym.make("ClutterGrasp-v1", num_objects=NUM_OBJECTS, render_mode="rgb_array", **BACKENDS)
obs, info = env.reset(seed=0)
task = env.unwrapped
ws = task.workspace  # WorkspaceSpec: the one source of truth for bounds, pixel size, cameras, pixel <-> world
size = ws.heightmap_size

print("observation space:", env.observation_space)
print("action space:", env.action_space, "= (primitive, rotation, row, col)", task.action_layout.shape)
print(f"heightmap {size}x{size} px of {ws.pixel_size * 1000:.1f} mm, {ws.num_rotations} rotations, bounds (m):")
print(ws.bounds.round(3))
print("objects:", info["num_objects"], "| remaining:", info["objects_remaining"])
assert obs["depth_heightmap"].shape == (1, size, size) and obs["depth_heightmap"].dtype == torch.float32
assert obs["color_heightmap"].shape == (1, size, size, 3) and obs["color_heightmap"].dtype == torch.uint8
assert info["num_objects"] == NUM_OBJECTS == info["objects_remaining"]
'''),
    md('''
The heightmaps are what an agent sees. We pick one grasp from them with the package's scripted heightmap oracle
(`HeightmapGraspOracle`: the top-surface centre of the highest object and the narrowest rotation the jaws fit; a
sanity baseline, no learning) and mark it.
'''),
    code('''
from maniskill_pnp.tasks.clutter_oracle import HeightmapGraspOracle

color = obs["color_heightmap"][0].cpu().numpy()
depth = obs["depth_heightmap"][0].cpu().numpy()
choice = HeightmapGraspOracle(ws).choose(depth)
xyz = ws.pixel_to_world(choice.row, choice.col, float(depth[choice.row, choice.col]))
yaw = np.degrees(ws.rotation_to_yaw(choice.rotation))
print(f"grasp at pixel (row {choice.row}, col {choice.col}), rotation {choice.rotation} = yaw {yaw:.1f} deg, "
      f"world point {xyz.round(3)}, jaw width needed {choice.width * 100:.1f} cm")
assert task.action_layout.decode(choice.action) == (0, choice.rotation, choice.row, choice.col)

fig, axes = plt.subplots(1, 3, figsize=(13, 4.2))
axes[0].imshow(env.render()[0].cpu().numpy())
axes[0].set_title("render camera")
axes[1].imshow(color)
axes[1].set_title("colour heightmap")
im = axes[2].imshow(depth, cmap="viridis")
axes[2].set_title("height above the table (m)")
fig.colorbar(im, ax=axes[2], fraction=0.046)
for ax in axes[1:]:
    ax.plot(choice.col, choice.row, "rx", markersize=12, markeredgewidth=2)
for ax in axes:
    ax.axis("off")
show(fig, "clutter_heightmaps")
'''),
    code('''
obs, reward, terminated, truncated, info = env.step(choice.action)
print(f"reward {reward.item()} | grasp_success {info['grasp_success']} | place_success {info['place_success']}")
print(f"stage {info['stage']!r}, reason {info['reason']!r}")
print(f"objects remaining {info['objects_remaining']}, in bin {info['objects_in_bin']}, lost {info['lost_objects']}")
timings = task.step_timings  # wall-clock times stay out of info, which is deterministic
print(f"planning {timings['planning']:.2f} s, motion incl. planning {timings['motion']:.2f} s, "
      f"render {timings['render']:.2f} s, heightmap fusion {timings['heightmap']:.3f} s")
assert info["num_actions"] == 1 and reward.item() in (0.0, 0.5, 1.0)
assert info["objects_remaining"] + info["objects_in_bin"] + info["lost_objects"] == info["num_objects"]

fig, axes = plt.subplots(1, 2, figsize=(8, 4))
axes[0].imshow(depth, cmap="viridis")
axes[0].set_title("height before")
axes[1].imshow(obs["depth_heightmap"][0].cpu().numpy(), cmap="viridis")
axes[1].set_title(f"height after (reward {reward.item():g})")
for ax in axes:
    ax.axis("off")
show(fig, "clutter_after_grasp")
env.close()
'''),
    md('''
## Part III: `ClutterGraspSlide-v1`

Grasp & slide ("G&S") in any clutter, tightly packed allowed: by default 10 objects dropped at random orientations;
`num_objects="min" / "medium" / "max"` are the thesis' density presets and `layout="complicated"` its 8
hand-designed locking layouts (notebook 04). The action gains a primitive axis: (primitive, rotation, row, col) with
primitives `grasp`, `left_slide`, `right_slide`. A slide lowers the closed fingertips beside the pixel's 3-D point
and pushes them 8 cm to the left or right of the rotation's jaw direction (rotation 0: jaws along +x, left = +y).
Reward: 1 placed, 0.8 grasped, 0.5 for a slide that changed the heightmap (VPG's changed-pixels test), 0 otherwise.

We push the tallest object of the central part of the workspace: start 4 cm on its -y side and slide left (+y)
through it. (A slide that knocks an object out of the workspace earns nothing: clearing the table by pushing must
not pay.)
'''),
    code('''
env = gym.make("ClutterGraspSlide-v1", num_objects=NUM_OBJECTS, **BACKENDS)
obs, info = env.reset(seed=0)
task = env.unwrapped
ws = task.workspace
print("action space:", env.action_space, "=", dict(zip(("primitive", "rotation", "row", "col"), task.action_layout.shape)))
print("primitives:", task.primitive_names, "| rewards:", task.rewards)

before = obs["depth_heightmap"][0].cpu().numpy()
size = ws.heightmap_size
centre = before[size // 4: 3 * size // 4, size // 4: 3 * size // 4]
row, col = np.array(np.unravel_index(int(centre.argmax()), centre.shape)) + size // 4  # the tallest object there
start_row = max(0, row - int(round(0.04 / ws.pixel_size)))  # rows grow with world y: 4 cm towards -y
action = task.action_layout.encode(task.primitive_names.index("left_slide"), 0, int(start_row), int(col))
print(f"slide from pixel ({start_row}, {col}) towards +y, through the object at ({row}, {col}), "
      f"push direction {ws.slide_direction(0, 'left')}")
obs, reward, terminated, truncated, info = env.step(action)
after = obs["depth_heightmap"][0].cpu().numpy()
print(f"reward {reward.item()} | primitive {info['primitive']} | slide_changed {info['slide_changed']} "
      f"({info['changed_pixels']} pixels changed) | stage {info['stage']!r} {info['reason']!r}")
assert info["primitive"] == "left_slide" and not info["grasp_success"]
assert reward.item() in (0.0, task.rewards["slide"]) and (reward.item() == 0.0 or info["slide_changed"])

fig, axes = plt.subplots(1, 3, figsize=(12, 4))
for ax, img, title in zip(axes, (before, after, after - before), ("height before", "height after", "after - before")):
    im = ax.imshow(img, cmap="viridis" if title != "after - before" else "coolwarm")
    ax.set_title(title)
    ax.axis("off")
    fig.colorbar(im, ax=ax, fraction=0.046)
push_px = ws.slide_length / ws.pixel_size  # the 8 cm push, in pixels
axes[0].annotate("", xy=(col, start_row + push_px), xytext=(col, start_row), arrowprops=dict(color="red", width=1, headwidth=6))
show(fig, "slide")
env.close()
'''),
    md('''
Next: `02_conveyor_tabular.ipynb` learns the conveyor with tabular Q-learning and SARSA,
`03_pixel_grasp_agent.ipynb` trains the pixelwise grasping DQN, `04_grasp_and_slide.ipynb` shows why slides are
needed on the locking layouts.
'''),
]

# ----------------------------------------------------------------------------------------------------------------------
# 02: tabular Q-learning and SARSA on the conveyor
# ----------------------------------------------------------------------------------------------------------------
CONVEYOR = [
    md('''
# Tabular Q-learning vs SARSA on the conveyor (thesis chapter 4)

`ConveyorProximity-v1` has 640 state ids and at most 9 actions, so the thesis learns it with a **Q-table**.
`maniskill_pnp.agents.tabular.recipe` trains one on TorchRL: the table is a TorchRL module, exploration is
`EGreedyModule` over the phase's valid actions (the action mask comes from the public `ConveyorSpec`), a TorchRL
`Collector` drives `make_torchrl_env("ConveyorProximity-v1")`, and the two algorithms differ only in the bootstrap
term of the TD update:

* Q-learning (off-policy): $Q(s,a) \\leftarrow Q(s,a) + \\alpha\\,[r + \\gamma \\max_{a'} Q(s',a') - Q(s,a)]$
* SARSA (on-policy): $Q(s,a) \\leftarrow Q(s,a) + \\alpha\\,[r + \\gamma\\, Q(s',a'_{\\text{taken}}) - Q(s,a)]$

This is what `maniskill-pnp train-conveyor --algorithm qlearning|sarsa` runs (`cli.py` builds a `ConveyorConfig`
from its options and calls `agents.tabular.recipe.main`), followed by `maniskill-pnp eval-conveyor` (`agents.tabular.evaluate.run`).

**Sizes.** The full setting (all 3 speed classes, 3000 training steps per agent: about 5.5 min each on 2 cores) is
what the README reports. The Q-table starts optimistic (1.0, the reward of a placed object), so the greedy policy
tries every (pre-pick, grasp) pair of every sensed case before it settles: 9 cases × 9 × 6 pairs, about 500 episodes
of 3 steps before learning shows. To see learning in a few minutes, this notebook fixes the belt speed to one class
(`speed="medium"`: 3 sensed cases, about 160 pairs) and trains 900 steps per agent.
'''),
    setup_cell("02_conveyor_tabular", '''
STEPS = 60 if SMALL else 900  # agent steps per algorithm (README: 3000 over all speeds); an episode is 1-3 steps
SPEED = "medium"  # train on one belt speed class (None: all three, as the README's runs)
EVAL_ITERATIONS = 1 if SMALL else 5  # greedy episodes per random test case (thesis: 50)
CATEGORY_ITERATIONS = 1 if SMALL else 2  # greedy episodes per (object kind, alignment, speed) cell
LOG_INTERVAL = 6 if SMALL else 30  # steps between two points of the learning curve
''', '''
import numpy as np
import torch
from IPython.display import Markdown

from maniskill_pnp.agents.tabular.evaluate import EvalConfig, read_curve, run as evaluate
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, load_qtable, main as train
from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, SPEEDS, ConveyorSpec
''' + SHOW),
    md('''
## Train both agents

Same seed, same hyper-parameters; ε decays linearly from 0.3 to 0.1 (the thesis' chapter-5 schedule) over the first
two thirds of the run (as the defaults do: 2000 of 3000 steps), α = 0.5, γ = 0.9. Each run writes `config.json`,
`qtable.pt` and CSV logs into its own folder.
'''),
    code('''
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
'''),
    md('''
## Learning curves

The running success rate of the ε-greedy behaviour (mean over the last 100 episodes), read back from each run's
CSV log with `agents.tabular.evaluate.read_curve`, side by side, with ε on the same axes. The first few hundred steps are
the optimistic exploration; then the success rate climbs.
'''),
    code('''
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
'''),
    md('''
## What the greedy policies chose

For every sensed (alignment, speed) the greedy pre-pick coordinate and then the greedy grasp coordinate under it,
read straight out of each Q-table (only the phase's valid actions count), next to the hand-marked best pair of
`ConveyorSpec.best` (several pairs around it also catch the object). A table knows only the states it visited:
a case never seen (here the other speed classes) keeps its initial values, so its argmax is the first valid action.
'''),
    code('''
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
display(Markdown("(pre-pick index, grasp index) per sensed case\\n\\n" + "\\n".join(rows)))
'''),
    md('''
## Greedy evaluation

`agents.tabular.evaluate.run` (the `eval-conveyor` command) runs both greedy policies on the same seeded episodes:

* per category (thesis Tables II-VII): every (object kind, alignment, speed) cell, `CATEGORY_ITERATIONS` episodes
  each; summarized below per speed class, where the speed trained on stands out;
* the thesis' random test cases 1-5 (Table VIII): (1) alignments in thirds, (2) speeds in thirds, (3)-(5) at least
  40% cuboids / spheres / cylinders. They mix all three speeds, so an agent trained on one class can only place the
  objects of that class.

It writes Markdown and CSV tables, `eval.json`, and its own learning-curve PNG into the evaluation folder.
'''),
    code('''
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
display(Markdown(f"Per speed class: mean over the 9 (kind, alignment) cells, {CATEGORY_ITERATIONS} episodes each\\n\\n"
                 + "\\n".join(rows)))
display(Markdown((OUT / "eval" / "test_cases.md").read_text()))
for label, agent in report["agents"].items():
    assert set(agent["test_cases"]) == {1, 2, 3, 4, 5}
    assert all(case["episodes"] == EVAL_ITERATIONS for case in agent["test_cases"].values())
assert (OUT / "eval" / "test_cases.csv").is_file() and (OUT / "eval" / "categories.md").is_file()
'''),
    md('''
With all three speed classes and the full 3000 steps per agent, the README reports 100% (Q-learning) and 91%
(SARSA) on the random test cases with 50 iterations each (thesis: about 93% and 80%). From the command line:

```bash
.venv/bin/maniskill-pnp train-conveyor --algorithm qlearning --seed 0
.venv/bin/maniskill-pnp train-conveyor --algorithm sarsa --seed 0
.venv/bin/maniskill-pnp eval-conveyor runs/conveyor/qlearning_normal_seed0 runs/conveyor/sarsa_normal_seed0 \\
    --iterations 50 --category-iterations 5
```
'''),
]

# ----------------------------------------------------------------------------------------------------------------------
# 03: the pixelwise grasp agent
# ----------------------------------------------------------------------------------------------------------------
PIXEL = [
    md('''
# The pixelwise grasping agent (thesis part II)

A pixelwise deep Q-network on `ClutterGrasp-v1`: a fully convolutional network maps the heightmaps (RGB + height,
4 channels) to one **Q value per pixel** for each of R = 16 grasp yaws (8 jaw orientations 22.5° apart). The
`equivariant` backbone (e2cnn, rotation group C16) gives all 16 maps from one pass on the unrotated heightmap; the
VPG-style backbones (`small`, `densenet121`) run the trunk on 16 rotated copies of the heightmap instead. The action is the argmax over
(rotation, row, col); only the executed pixel is trained (Huber loss to $r + \\gamma \\max Q'(s')$, prioritized replay,
a target network). An action mask keeps grasps on pixels where the heightmap shows material.

The `cpu-equi` preset (`ClutterConfig.from_preset("cpu-equi")`) is sized for 2 CPU cores: the equivariant network,
16 rotations, 64×64 heightmaps of a 44.8 cm workspace, 10 objects (`cpu-small` is the same with a small ResNet-18
trunk on rotated copies, the slower baseline). The thesis preset (`thesis`) is DenseNet-121,
16 rotations, 224 px: a GPU job. This notebook shows the network's maps, runs a very short training run with
`recipe.main` (`maniskill-pnp train-clutter`) and evaluates it with `evaluate.run`
(`maniskill-pnp eval-clutter`). A short run does not learn much: it shows the pipeline, not the learned figures.
'''),
    setup_cell("03_pixel_grasp_agent", '''
NUM_OBJECTS = 3 if SMALL else 10  # objects per scene
TRAIN_STEPS = 3 if SMALL else 30  # grasp attempts of the training run (README: 1601 in 35 min learn to ~70%)
EVAL_EPISODES = 1 if SMALL else 2  # greedy evaluation scenes
EVAL_MAX_STEPS = 2 if SMALL else 8  # actions per evaluation scene at most
''', '''
import dataclasses

import torch
from IPython.display import Markdown

from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.curves import plot_training_curves
from maniskill_pnp.agents.pixel.evaluate import ClutterEvalConfig, decide, plot_q_heatmaps, run as evaluate
from maniskill_pnp.agents.pixel.factories import make_action_mask, make_env, make_model
from maniskill_pnp.agents.pixel.policy import GreedyPixelActor
from maniskill_pnp.agents.pixel.recipe import main as train

torch.manual_seed(0)
DEVICE = torch.device("cpu")
''' + SHOW),
    code('''
cfg = ClutterConfig.from_preset("cpu-equi", num_objects=NUM_OBJECTS, steps=TRAIN_STEPS, log_interval=1,
                                checkpoint_interval=TRAIN_STEPS, out=OUT / "runs")
print({f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)
       if f.name in ("preset", "task", "backbone", "num_rotations", "heightmap_size", "workspace_side", "num_objects",
                     "steps", "gamma", "lr", "batch_size", "eps_start", "eps_end", "mask_empty")})
print("run folder:", cfg.run_dir)
'''),
    md('''
## The task through the recipe

`factories.make_env(cfg)` is `ClutterGrasp-v1` with the config's workspace (64 px, 16 rotations) as a TorchRL
env (`make_torchrl_env`); `.maniskill_env` is the gymnasium env underneath.
'''),
    code('''
env = make_env(cfg)
td = env.reset()
print("observation spec keys:", sorted(k for k in env.observation_spec.keys() if "heightmap" in k))
print("action spec:", type(env.action_spec).__name__, "with", env.action_spec.space.n, "actions =",
      env.maniskill_env.unwrapped.action_layout.shape)
color, depth = td["color_heightmap"], td["depth_heightmap"]
size = cfg.heightmap_size
assert depth.shape == (1, size, size) and color.shape == (1, size, size, 3)
assert env.action_spec.space.n == cfg.num_rotations * size * size

mask = make_action_mask(cfg)
allowed = mask.pixel_masks(depth)[0, 0, 0]  # (H, W) pixels where a grasp (rotation 0) is allowed
fig, axes = plt.subplots(1, 3, figsize=(11, 3.6))
axes[0].imshow(color[0].numpy())
axes[0].set_title("colour heightmap")
im = axes[1].imshow(depth[0].numpy(), cmap="viridis")
axes[1].set_title("height (m)")
fig.colorbar(im, ax=axes[1], fraction=0.046)
axes[2].imshow(allowed.numpy(), cmap="gray")
axes[2].set_title(f"action mask: {allowed.float().mean():.0%} of the pixels")
for ax in axes:
    ax.axis("off")
show(fig, "heightmaps")
'''),
    md('''
## Q maps of an untrained network

`make_model(cfg)` builds one pixel Q network per primitive (here only `grasp`): `(N, 4, H, W) -> (N, P, R, H, W)`.
`evaluate.decide` runs the greedy actor (masked argmax) on one observation and returns the chosen flat action
with the maps; `evaluate.plot_q_heatmaps` is the figure `eval-clutter` writes (every rotation on one colour
scale, the chosen action marked).
'''),
    code('''
model = make_model(cfg).eval()
print(f"{sum(p.numel() for p in model.parameters()) / 1e6:.2f} M parameters")
actor = GreedyPixelActor(model, mask)
action, maps = decide(actor, td, DEVICE)
assert maps.shape == (1, cfg.num_rotations, size, size) and torch.isfinite(maps).all()
layout = env.maniskill_env.unwrapped.action_layout
primitive, rotation, row, col = (int(v) for v in layout.decode(action))
assert allowed[row, col], "the greedy action must be an allowed one"
print(f"greedy action {action}: rotation {rotation}, pixel ({row}, {col})")
png = plot_q_heatmaps(dict(color=color[0].numpy(), depth=depth[0].numpy(), maps=maps.numpy(), action=action),
                      cfg.primitives, OUT / "untrained_q_heatmaps.png")
display(Image(filename=str(png)))
env.close()
'''),
    md('''
## A short training run

`recipe.main(cfg)` is `maniskill-pnp train-clutter`: ε-greedy actions through a TorchRL `Collector`, every
transition into a prioritized replay, one SGD step per action, a checkpoint (model, optimizer, replay) at the end,
and `actions.csv` with one row per action.
'''),
    code('''
summary = train(cfg)
print({k: summary[k] for k in ("steps", "episodes", "updates", "grasps", "running_grasp_success", "wall_s")})
assert summary["steps"] == TRAIN_STEPS and summary["updates"] >= 1
assert (cfg.run_dir / "checkpoint.pt").is_file() and (cfg.run_dir / "actions.csv").is_file()

window = max(1, min(10, TRAIN_STEPS))
curves = plot_training_curves({"cpu-equi": cfg.run_dir}, OUT / "training_curves.png", window=window)
print(curves)
display(Image(filename=str(OUT / "training_curves.png")))
'''),
    md('''
## Greedy evaluation

`evaluate.run` reloads the checkpoint, plays seeded scenes greedily (seed 1000 on: apart from the training
seeds) and writes the metrics of `docs/metrics.md` per scenario (Table IX layout), a per-episode CSV and the Q-map figure of
the first state.
'''),
    code('''
result = evaluate(ClutterEvalConfig(checkpoint=cfg.run_dir, episodes=EVAL_EPISODES, max_steps=EVAL_MAX_STEPS,
                                    out=OUT / "eval"))
display(Markdown((OUT / "eval" / "eval_table.md").read_text()))
for name, path in result["files"].items():
    assert Path(path).is_file(), name
assert all(0.0 <= v <= 1.0 for v in result["metrics"]["train"].values())
display(Image(filename=result["files"]["q_heatmaps"]))
'''),
    md('''
For a run that learns (about 28 minutes on 2 cores; see the README for its figures):

```bash
.venv/bin/maniskill-pnp train-clutter --preset cpu-equi --steps 3000 --updates-per-step 2 --max-minutes 28
.venv/bin/maniskill-pnp eval-clutter runs/clutter/cpu-equi_equivariant_r16_px64_seed0 --episodes 24 --max-steps 30
```
'''),
]

# ----------------------------------------------------------------------------------------------------------------------
# 04: grasp and slide on a locking layout
# ----------------------------------------------------------------------------------------------------------------
GRASP_SLIDE = [
    md('''
# Grasp & slide on a locking layout (thesis part III)

In tight clutter a top-down grasp often has no room: a finger lands on a neighbour, or the object is wider than the
open jaws (8 cm) across its only free direction. The thesis' answer is a second kind of primitive, the **slide**:
push something aside, then grasp. `ClutterGraspSlide-v1` with `layout="complicated"` offers 8 hand-designed
locking arrangements (`maniskill_pnp/tasks/complicated_layouts.py`) in which no grasp fits until a slide has pulled
them apart.

This notebook shows the layouts, checks on `row_of_three` (three 4×9 cm bars pressed together) that centre
grasps fail while a slide then a grasp works, and runs a few greedy steps of a G&S agent (three Q networks: grasp,
left slide, right slide) with its per-primitive Q maps.
'''),
    setup_cell("04_grasp_and_slide", '''
CENTRE_GRASPS = (1,) if SMALL else (0, 1, 2)  # which bars of the row to try a centre grasp on
AGENT_STEPS = 2 if SMALL else 5  # greedy steps of the (untrained) G&S agent
''', '''
import gymnasium as gym
import numpy as np
import torch

import maniskill_pnp  # noqa: F401  (registers the task ids)
from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.evaluate import decide, plot_q_heatmaps
from maniskill_pnp.agents.pixel.factories import make_action_mask, make_env, make_model
from maniskill_pnp.agents.pixel.policy import GreedyPixelActor
from maniskill_pnp.runtime import default_backends
from maniskill_pnp.tasks.complicated_layouts import COMPLICATED_LAYOUT_NAMES, complicated_layouts

BACKENDS = default_backends()
torch.manual_seed(0)
''' + SHOW),
    md('''
## The 8 locking layouts

One env holds them all (they share a pool of objects); `reset(options={"layout_index": k})` picks one, otherwise a
seeded draw does (`complicated_index=k` at `gym.make` fixes it). The objects touch (1 mm apart, less than a
pixel), so we draw their designed outlines over the colour heightmaps.
'''),
    code('''
env = gym.make("ClutterGraspSlide-v1", layout="complicated", render_mode="rgb_array", **BACKENDS)
task = env.unwrapped
ws = task.workspace
designs = complicated_layouts(ws)  # per layout: [(ObjectSpec, designed pose), ...]
assert len(designs) == len(COMPLICATED_LAYOUT_NAMES) == 8
size = ws.heightmap_size
CROP = slice(size // 4, 3 * size // 4)  # the central half of the workspace, where the layouts stand



def outline(ax, spec, pose, offset: int) -> None:
    """Draw an object's designed footprint (cuboid rectangle or cylinder circle) on a heightmap cropped at ``offset``."""
    x, y = pose.p[:2]
    w, q = pose.q[0], pose.q[3]
    yaw = 2 * np.arctan2(q, w)  # the layouts turn objects about z only
    if spec.kind == "cylinder":
        t = np.linspace(0, 2 * np.pi, 40)
        pts = np.stack([x + spec.size[0] * np.cos(t), y + spec.size[0] * np.sin(t)], axis=1)
    else:
        hx, hy = spec.extents[0] / 2, spec.extents[1] / 2
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]])
        rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        pts = local @ rot.T + [x, y]
    (x0, _), (y0, _) = ws.bounds[:2]
    ax.plot((pts[:, 0] - x0) / ws.pixel_size - 0.5 - offset, (pts[:, 1] - y0) / ws.pixel_size - 0.5 - offset, "k-", lw=1)


fig, axes = plt.subplots(2, 4, figsize=(13, 6.8))
for k, (ax, name) in enumerate(zip(axes.ravel(), COMPLICATED_LAYOUT_NAMES)):
    obs, info = env.reset(seed=0, options={"layout_index": k})
    assert info["layout_index"] == k and info["objects_remaining"] == len(designs[k]) and info["lost_objects"] == 0
    ax.imshow(obs["color_heightmap"][0].cpu().numpy()[CROP, CROP])
    for spec, pose in designs[k]:
        outline(ax, spec, pose, CROP.start)
    ax.set_title(f"{k}: {name} ({len(designs[k])} objects)", fontsize=9)
    ax.axis("off")
show(fig, "layouts")
'''),
    md('''
## `row_of_three`: centre grasps fail

The three bars stand side by side along x (index 0 at -x). A grasp at a bar's centre with rotation 0 closes the
jaws along x, across the row: each open finger (about 8 cm apart) comes down on a neighbour. We grasp at the
designed centre of each bar from a fresh reset.
'''),
    code('''
K = COMPLICATED_LAYOUT_NAMES.index("row_of_three")
bars = np.array([pose.p for _, pose in designs[K]])  # designed centres (x, y, z) of the three bars
obs, info = env.reset(seed=0, options={"layout_index": K})
depth0 = obs["depth_heightmap"][0].cpu().numpy()
render0 = env.render()[0].cpu().numpy()


def grasp_action(xyz, rotation: int) -> int:
    row, col = ws.world_to_pixel(np.asarray(xyz))
    return task.action_layout.encode(task.primitive_names.index("grasp"), rotation, int(row), int(col))


for i in CENTRE_GRASPS:
    env.reset(seed=0, options={"layout_index": K})
    obs, reward, terminated, truncated, info = env.step(grasp_action(bars[i], rotation=0))
    print(f"bar {i}: centre grasp -> reward {reward.item()}, grasp_success {info['grasp_success']}, "
          f"stage {info['stage']!r}, reason {info['reason']!r}")
    assert not info["grasp_success"] and reward.item() == 0.0
'''),
    md('''
## A slide, then a grasp

A left slide with rotation 0 pushes along +y. We start it beside the end bar's short side, 6.5 cm from its centre
in -y, and 1.4 cm towards +x: the closed fingers (about 5 cm wide along x) then meet this bar only, not its
neighbour. After the push, the part of the heightmap that became occupied is the bar's end that now sticks out of
the row; a grasp at its centre (jaws across the 4 cm bar) finds free space for both fingers.
'''),
    code('''
obs, info = env.reset(seed=0, options={"layout_index": K})
before = obs["depth_heightmap"][0].cpu().numpy()
start = bars[2] + [0.014, -0.065, 0.0]
row, col = ws.world_to_pixel(start)
slide = task.action_layout.encode(task.primitive_names.index("left_slide"), 0, int(row), int(col))
obs, reward, terminated, truncated, info = env.step(slide)
after = obs["depth_heightmap"][0].cpu().numpy()
print(f"left slide -> reward {reward.item()}, slide_changed {info['slide_changed']} ({info['changed_pixels']} pixels)")
assert info["slide_changed"] and reward.item() == task.rewards["slide"]

new = (after > 0.01) & (before <= 0.01)  # pixels the slide moved material onto
rows, cols = np.nonzero(new)
nearest = int(np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2))
g_row, g_col = int(rows[nearest]), int(cols[nearest])
grasp = task.action_layout.encode(task.primitive_names.index("grasp"), 0, g_row, g_col)
obs, reward, terminated, truncated, info = env.step(grasp)
print(f"grasp at pixel ({g_row}, {g_col}) -> reward {reward.item()}, grasp_success {info['grasp_success']}, "
      f"place_success {info['place_success']}, objects remaining {info['objects_remaining']}")
assert info["grasp_success"] and reward.item() in (task.rewards["grasp"], task.rewards["place"])

fig, axes = plt.subplots(1, 4, figsize=(15, 3.8))
axes[0].imshow(render0)
axes[0].set_title("row_of_three")
for ax, img, title in zip(axes[1:], (before, after, obs["depth_heightmap"][0].cpu().numpy()),
                          ("height before", "after the left slide", "after the grasp")):
    ax.imshow(img[CROP, CROP], cmap="viridis", vmin=0, vmax=0.05)
    ax.set_title(title)
o = CROP.start  # pixel offset of the crop
axes[1].annotate("", xy=(col - o, row - o + ws.slide_length / ws.pixel_size), xytext=(col - o, row - o),
                 arrowprops=dict(color="red", width=2, headwidth=8))
axes[2].plot(g_col - o, g_row - o, "rx", markersize=12, markeredgewidth=2)
for ax in axes:
    ax.axis("off")
show(fig, "slide_then_grasp")
env.close()
'''),
    md('''
## A G&S agent on the layout

The `gs-cpu-equi` preset is the G&S agent sized for a CPU: three equivariant FCNs (grasp, left slide, right slide),
16 rotations, 64 px. It acts by the argmax over all three primitives' maps, under the action mask (grasps on material,
slides from bare table towards material within half a slide). Here the networks are untrained, so its choices are arbitrary; the point is the
interface: the per-primitive Q maps and what each step did. Training it is
`maniskill-pnp train-clutter --preset gs-cpu-equi` (`recipe.main`), evaluating it on these layouts
`maniskill-pnp eval-clutter <run> --scenarios complicated`.
'''),
    code('''
cfg = ClutterConfig.from_preset("gs-cpu-equi", out=OUT / "runs")
tenv = make_env(cfg, layout="complicated", complicated_index=K)  # TorchRL env; .maniskill_env is the gym env
genv = tenv.maniskill_env
layout = genv.unwrapped.action_layout
print("primitives:", cfg.primitives, "| action layout (P, R, H, W):", layout.shape)
actor = GreedyPixelActor(make_model(cfg).eval(), make_action_mask(cfg))

obs, info = genv.reset(seed=0)
for step in range(AGENT_STEPS):
    action, maps = decide(actor, obs, torch.device("cpu"))
    assert maps.shape == (3, cfg.num_rotations, cfg.heightmap_size, cfg.heightmap_size)
    p, r, row, col = (int(v) for v in layout.decode(action))
    if step == 0:
        png = plot_q_heatmaps(dict(color=obs["color_heightmap"][0].numpy(), depth=obs["depth_heightmap"][0].numpy(),
                                   maps=maps.numpy(), action=action), cfg.primitives, OUT / "gs_q_heatmaps.png")
        display(Image(filename=str(png)))
    # per primitive: the best value over the rotations at every pixel
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.2))
    axes[0].imshow(obs["depth_heightmap"][0].numpy(), cmap="viridis")
    axes[0].set_title(f"step {step}: height")
    axes[0].plot(col, row, "rx", markersize=10, markeredgewidth=2)
    best = maps.amax(dim=1)
    for ax, name, m in zip(axes[1:], cfg.primitives, best):
        ax.imshow(m.numpy(), cmap="jet", vmin=float(best.min()), vmax=float(best.max()))
        ax.set_title(f"{name}: max over rotations" + (" (chosen)" if name == cfg.primitives[p] else ""), fontsize=9)
    for ax in axes:
        ax.axis("off")
    show(fig, f"gs_step{step}")
    obs, reward, terminated, truncated, info = genv.step(action)
    print(f"step {step}: {info['primitive']} rotation {r} pixel ({row}, {col}) -> reward {reward.item()}, "
          f"grasp_success {info['grasp_success']}, slide_changed {info['slide_changed']}, "
          f"objects remaining {info['objects_remaining']}")
    assert info["primitive"] == cfg.primitives[p]
    if terminated.item() or truncated.item():
        break
tenv.close()
'''),
]

NOTEBOOKS: dict[str, list[tuple[str, str]]] = {
    "01_tasks": TASKS,
    "02_conveyor_tabular": CONVEYOR,
    "03_pixel_grasp_agent": PIXEL,
    "04_grasp_and_slide": GRASP_SLIDE,
}


def build(stem: str) -> nbformat.NotebookNode:
    """The notebook ``stem`` without outputs, with stable cell ids."""
    cells = []
    for i, (kind, source) in enumerate(NOTEBOOKS[stem]):
        cell = nbformat.v4.new_markdown_cell(source) if kind == "markdown" else nbformat.v4.new_code_cell(source)
        cell["id"] = f"{stem.split('_')[0]}-{i:02d}"
        cells.append(cell)
    nb = nbformat.v4.new_notebook(cells=cells)
    nb.metadata.update(
        kernelspec={"name": "python3", "display_name": "Python 3 (ipykernel)", "language": "python"},
        language_info={"name": "python"},
    )
    nbformat.validate(nb)
    return nb


def render(stem: str) -> str:
    """The ``.ipynb`` text of ``stem`` as written to disk."""
    return nbformat.writes(build(stem)) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if a notebook is out of date")
    args = parser.parse_args(argv)
    stale = []
    for stem in NOTEBOOKS:
        path = HERE / f"{stem}.ipynb"
        text = render(stem)
        if path.is_file() and path.read_text() == text:
            continue
        stale.append(path.name)
        if not args.check:
            path.write_text(text)
    if args.check:
        print("out of date: " + ", ".join(stale) if stale else "all notebooks up to date")
        return 1 if stale else 0
    print("wrote: " + ", ".join(stale) if stale else "nothing to write: all notebooks up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
