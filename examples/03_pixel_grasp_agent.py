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
# # The pixelwise grasping agent (thesis part II)
#
# A pixelwise deep Q-network on `ClutterGrasp-v1`: a fully convolutional network maps the heightmaps (RGB + height,
# 4 channels) to one **Q value per pixel** for each of R = 16 grasp yaws (8 jaw orientations 22.5° apart). The
# `equivariant` backbone (e2cnn, rotation group C16) gives all 16 maps from one pass on the unrotated heightmap; the
# VPG-style backbones (`small`, `densenet121`) run the trunk on 16 rotated copies of the heightmap instead. The action is the argmax over
# (rotation, row, col); only the executed pixel is trained (Huber loss to $r + \gamma \max Q'(s')$, prioritized replay,
# a target network). An action mask keeps grasps on pixels where the heightmap shows material.
#
# The `cpu-equi` preset (`ClutterConfig.from_preset("cpu-equi")`) is sized for 2 CPU cores: the equivariant network,
# 16 rotations, 64×64 heightmaps of a 44.8 cm workspace, 10 objects (`cpu-small` is the same with a small ResNet-18
# trunk on rotated copies, the slower baseline). The thesis preset (`thesis`) is DenseNet-121,
# 16 rotations, 224 px: a GPU job. This notebook shows the network's maps, runs a very short training run with
# `recipe.main` (`maniskill-pnp train-clutter`) and evaluates it with `evaluate.run`
# (`maniskill-pnp eval-clutter`). A short run does not learn much: it shows the pipeline, not the learned figures.

# %%
import os
from pathlib import Path

# MANISKILL_PNP_EXAMPLES_SMALL=1 runs a tiny version of every step (the test suite does); unset, the sizes below are
# what this notebook runs in a few minutes on 2 CPU cores.
SMALL = os.environ.get("MANISKILL_PNP_EXAMPLES_SMALL", "0") == "1"
NUM_OBJECTS = 3 if SMALL else 10  # objects per scene
TRAIN_STEPS = 3 if SMALL else 30  # grasp attempts of the training run (README: 1601 in 35 min learn to ~70%)
EVAL_EPISODES = 1 if SMALL else 2  # greedy evaluation scenes
EVAL_MAX_STEPS = 2 if SMALL else 8  # actions per evaluation scene at most

from maniskill_pnp.notebook import Image, Markdown, display, output_dir, show as save_and_show

OUT = output_dir("03_pixel_grasp_agent")  # $MANISKILL_PNP_EXAMPLES_OUT, or runs/examples/03_pixel_grasp_agent in the checkout
print("small sizes:", SMALL, "| outputs in", OUT)

import dataclasses

import torch

from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.curves import plot_training_curves
from maniskill_pnp.agents.pixel.evaluate import ClutterEvalConfig, decide, plot_q_heatmaps, run as evaluate
from maniskill_pnp.agents.pixel.factories import make_action_mask, make_env, make_model
from maniskill_pnp.agents.pixel.policy import GreedyPixelActor
from maniskill_pnp.agents.pixel.recipe import main as train

torch.manual_seed(0)
DEVICE = torch.device("cpu")

import matplotlib.pyplot as plt


def show(fig, name: str) -> None:
    """Save ``fig`` as OUT/<name>.png and show it."""
    save_and_show(fig, name, OUT)


# %%
# collector="direct": the env in this process. `train-clutter` (and a script's `main` behind an
# `if __name__ == "__main__":` guard) by default steps it in a worker process while the learner updates.
cfg = ClutterConfig.from_preset("cpu-equi", num_objects=NUM_OBJECTS, steps=TRAIN_STEPS, log_interval=1,
                                checkpoint_interval=TRAIN_STEPS, collector="direct", out=OUT / "runs")
print({f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)
       if f.name in ("preset", "task", "backbone", "num_rotations", "heightmap_size", "workspace_side", "num_objects",
                     "steps", "gamma", "lr", "batch_size", "eps_start", "eps_end", "mask_empty")})
print("run folder:", cfg.run_dir)

# %% [markdown]
# ## The task through the recipe
#
# `factories.make_env(cfg)` is `ClutterGrasp-v1` with the config's workspace (64 px, 16 rotations) as a TorchRL
# env (`make_torchrl_env`); `.maniskill_env` is the gymnasium env underneath.

# %%
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

# %% [markdown]
# ## Q maps of an untrained network
#
# `make_model(cfg)` builds one pixel Q network per primitive (here only `grasp`): `(N, 4, H, W) -> (N, P, R, H, W)`.
# `evaluate.decide` runs the greedy actor (masked argmax) on one observation and returns the chosen flat action
# with the maps; `evaluate.plot_q_heatmaps` is the figure `eval-clutter` writes (every rotation on one colour
# scale, the chosen action marked).

# %%
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

# %% [markdown]
# ## A short training run
#
# `recipe.main(cfg)` is `maniskill-pnp train-clutter`: ε-greedy actions through a TorchRL `Collector`, every
# transition into a prioritized replay, one SGD step per action, a checkpoint (model, optimizer, replay) at the end,
# and `actions.csv` with one row per action.

# %%
summary = train(cfg)
print({k: summary[k] for k in ("steps", "episodes", "updates", "grasps", "running_grasp_success", "wall_s")})
assert summary["steps"] == TRAIN_STEPS and summary["updates"] >= 1
assert (cfg.run_dir / "checkpoint.pt").is_file() and (cfg.run_dir / "actions.csv").is_file()

window = max(1, min(10, TRAIN_STEPS))
curves = plot_training_curves({"cpu-equi": cfg.run_dir}, OUT / "training_curves.png", window=window)
print(curves)
display(Image(filename=str(OUT / "training_curves.png")))

# %% [markdown]
# ## Greedy evaluation
#
# `evaluate.run` reloads the checkpoint, plays seeded scenes greedily (seed 1000 on: apart from the training
# seeds) and writes the metrics of `docs/metrics.md` per scenario (Table IX layout), a per-episode CSV and the Q-map figure of
# the first state.

# %%
result = evaluate(ClutterEvalConfig(checkpoint=cfg.run_dir, episodes=EVAL_EPISODES, max_steps=EVAL_MAX_STEPS,
                                    out=OUT / "eval"))
display(Markdown((OUT / "eval" / "eval_table.md").read_text()))
for name, path in result["files"].items():
    assert Path(path).is_file(), name
assert all(0.0 <= v <= 1.0 for v in result["metrics"]["train"].values())
display(Image(filename=result["files"]["q_heatmaps"]))

# %% [markdown]
# For a run that learns (about 28 minutes on 2 cores; see the README for its figures):
#
# ```bash
# .venv/bin/maniskill-pnp train-clutter --preset cpu-equi --steps 3000 --updates-per-step 2 --max-minutes 28
# .venv/bin/maniskill-pnp eval-clutter runs/clutter/cpu-equi_equivariant_r16_px64_seed0 --episodes 24 --max-steps 30
# ```
