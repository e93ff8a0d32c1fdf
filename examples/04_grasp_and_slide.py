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
# # Grasp & slide on a locking layout (thesis part III)
#
# In tight clutter a top-down grasp often has no room: a finger lands on a neighbour, or the object is wider than the
# open jaws (8 cm) across its only free direction. The thesis' answer is a second kind of primitive, the **slide**:
# push something aside, then grasp. `ClutterGraspSlide-v1` with `layout="complicated"` offers 8 hand-designed
# locking arrangements (`maniskill_pnp/scenes/complicated_layouts.py`) in which no grasp fits until a slide has pulled
# them apart.
#
# This notebook shows the layouts, checks on `row_of_three` (three 4×9 cm bars pressed together) that centre
# grasps fail while a slide then a grasp works, and runs a few greedy steps of a G&S agent (three Q networks: grasp,
# left slide, right slide) with its per-primitive Q maps.

# %%
import os

# MANISKILL_PNP_EXAMPLES_SMALL=1 runs a tiny version of every step (the test suite does); unset, the sizes below are
# what this notebook runs in a few minutes on 2 CPU cores.
SMALL = os.environ.get("MANISKILL_PNP_EXAMPLES_SMALL", "0") == "1"
CENTRE_GRASPS = (1,) if SMALL else (0, 1, 2)  # which bars of the row to try a centre grasp on
AGENT_STEPS = 2 if SMALL else 5  # greedy steps of the (untrained) G&S agent

from maniskill_pnp.notebook import Image, display, output_dir, show as save_and_show

OUT = output_dir("04_grasp_and_slide")  # $MANISKILL_PNP_EXAMPLES_OUT, or runs/examples/04_grasp_and_slide in the checkout
print("small sizes:", SMALL, "| outputs in", OUT)

import gymnasium as gym
import numpy as np
import torch

import maniskill_pnp  # noqa: F401  (registers the task ids)
from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.evaluate import decide, plot_q_heatmaps
from maniskill_pnp.agents.pixel.factories import make_action_mask, make_env, make_model
from maniskill_pnp.agents.pixel.policy import GreedyPixelActor
from maniskill_pnp.runtime import default_backends
from maniskill_pnp.scenes.complicated_layouts import COMPLICATED_LAYOUT_NAMES, complicated_layouts

BACKENDS = default_backends()
torch.manual_seed(0)

import matplotlib.pyplot as plt


def show(fig, name: str) -> None:
    """Save ``fig`` as OUT/<name>.png and show it."""
    save_and_show(fig, name, OUT)


# %% [markdown]
# ## The 8 locking layouts
#
# One env holds them all (they share a pool of objects); `reset(options={"layout_index": k})` picks one, otherwise a
# seeded draw does (`complicated_index=k` at `gym.make` fixes it). The objects touch (1 mm apart, less than a
# pixel), so we draw their designed outlines over the colour heightmaps.

# %%
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

# %% [markdown]
# ## `row_of_three`: centre grasps fail
#
# The three bars stand side by side along x (index 0 at -x). A grasp at a bar's centre with rotation 0 closes the
# jaws along x, across the row: each open finger (about 8 cm apart) comes down on a neighbour. We grasp at the
# designed centre of each bar from a fresh reset.

# %%
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

# %% [markdown]
# ## A slide, then a grasp
#
# A left slide with rotation 0 pushes along +y. We start it beside the end bar's short side, 6.5 cm from its centre
# in -y, and 1.4 cm towards +x: the closed fingers (about 5 cm wide along x) then meet this bar only, not its
# neighbour. After the push, the part of the heightmap that became occupied is the bar's end that now sticks out of
# the row; a grasp at its centre (jaws across the 4 cm bar) finds free space for both fingers.

# %%
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

# %% [markdown]
# ## A G&S agent on the layout
#
# The `gs-cpu-equi` preset is the G&S agent sized for a CPU: three equivariant FCNs (grasp, left slide, right slide),
# 16 rotations, 64 px. It acts by the argmax over all three primitives' maps, under the action mask (grasps on material,
# slides from bare table towards material within half a slide). Here the networks are untrained, so its choices are arbitrary; the point is the
# interface: the per-primitive Q maps and what each step did. Training it is
# `maniskill-pnp train-clutter --preset gs-cpu-equi` (`recipe.main`), evaluating it on these layouts
# `maniskill-pnp eval-clutter <run> --scenarios complicated`.

# %%
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
