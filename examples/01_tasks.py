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
# # The three thesis tasks as ManiSkill environments
#
# `maniskill_pnp` turns the three parts of a thesis on deep RL for industrial pick-and-place into registered
# ManiSkill 3 tasks. Importing the package registers them with gymnasium:
#
# | id | thesis part | observation | one action = |
# |---|---|---|---|
# | `ConveyorProximity-v1` | I | one discrete state id (ray proximity sensors) | one phase of a pick: wait and sense, pre-pick coordinate, grasp coordinate |
# | `ClutterGrasp-v1` | II | RGB-D heightmaps (colour + height above the table) | one top-down grasp at a heightmap pixel and yaw, then place in the bin |
# | `ClutterGraspSlide-v1` | III | the same heightmaps | one grasp, left slide or right slide at a pixel and yaw |
#
# Unlike ManiSkill's own tasks (one low-level control action per step), **one step here is a whole motion primitive**:
# the Panda's motions are planned with OMPL (RRT-Connect) and executed in the PhysX simulation inside `step`. A
# planning failure is an outcome in `info`, never an exception. Everything runs on the CPU: PhysX on the CPU and
# rendering through lavapipe (`maniskill_pnp.runtime.default_backends` picks the GPU renderer when CUDA is there).

# %%
import os

# MANISKILL_PNP_EXAMPLES_SMALL=1 runs a tiny version of every step (the test suite does); unset, the sizes below are
# what this notebook runs in a few minutes on 2 CPU cores.
SMALL = os.environ.get("MANISKILL_PNP_EXAMPLES_SMALL", "0") == "1"
NUM_OBJECTS = 5 if SMALL else 10  # objects in the random clutters

from maniskill_pnp.notebook import output_dir, show as save_and_show

OUT = output_dir("01_tasks")  # $MANISKILL_PNP_EXAMPLES_OUT, or runs/examples/01_tasks in the checkout
print("small sizes:", SMALL, "| outputs in", OUT)

import gymnasium as gym
import numpy as np
import torch

import maniskill_pnp  # noqa: F401  (registers the task ids)
from maniskill_pnp.runtime import default_backends
from maniskill_pnp.tasks import TASK_IDS

BACKENDS = default_backends()  # {"sim_backend": "physx_cpu", "render_backend": "cpu"} on a CPU-only machine
print(BACKENDS)
assert {"ConveyorProximity-v1", "ClutterGrasp-v1", "ClutterGraspSlide-v1"} <= set(TASK_IDS)

import matplotlib.pyplot as plt


def show(fig, name: str) -> None:
    """Save ``fig`` as OUT/<name>.png and show it."""
    save_and_show(fig, name, OUT)


# %% [markdown]
# ## Part I: `ConveyorProximity-v1`
#
# A cuboid, cylinder or sphere rides a belt towards the robot in one of three lanes (left / center / right) at one of
# three speeds. There is no camera: two horizontal ray gates time the object (speed class) and a row of downward rays
# under the second gate sees its lane (alignment), both PhysX raycasts. The MDP is tiny and discrete, as in the thesis:
# an episode is one object and at most three steps, one per **phase**:
#
# 1. `initial`: action 0 only, wait until the sensors have seen the object;
# 2. `pre_pick`: one of 9 pre-pick coordinates above the belt (3 lanes × 3 rows), reached by a planned motion while
#    the object keeps moving;
# 3. `grasp`: one of 6 grasp coordinates along the belt below the pre-pick one; descend, close, lift and place.
#
# The observation is one state id that encodes (phase, sensed speed, sensed alignment, last coordinate);
# `info` decodes it, holds the raw ray readings, and (for analysis only) the hidden ground truth of the episode.

# %%
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

# %% [markdown]
# An action that is not valid in the current phase (`info["action_mask"]` says which are) is a failed attempt: nothing
# moves, the failure reward, `info["invalid_action"]`, and the episode ends (the agents mask invalid actions out, see
# `agents/tabular/qtable.py: StateActionMask`). A new episode from the same seed follows:

# %%
obs, reward, terminated, truncated, info = env.step(5)  # the initial phase has one action: 0 (wait and sense)
print(f"reward {reward.item()}, terminated {bool(terminated.item())}, invalid_action {bool(info['invalid_action'])}: "
      f"{info['outcome']}")
assert info["invalid_action"] and terminated.item()
obs, info = env.reset(seed=0)

# %% [markdown]
# One episode with the hand-marked best coordinates for the sensed lane and speed (`ConveyorSpec.oracle_action`, the
# thesis' hand-designed choice and the "bonus" reward's reference). We render the scene before each step.

# %%
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

# %% [markdown]
# The sensors' raw readings: each downward alignment ray reports the distance at which it hit the object (`inf`: it
# missed), and the two gate times give the speed estimate that is binned into slow / medium / fast.

# %%
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

# %% [markdown]
# ## Part II: `ClutterGrasp-v1`
#
# 10 to 15 procedural objects (regular and irregular: cuboids, cylinders, spheres, L, T, U, arches, wedges, convex
# hulls) are dropped loosely packed into the workspace. A far top-down camera and a perspective camera are fused
# into two **heightmaps** at 2 mm/px (224×224 by default): colour (uint8) and height above the table (float32, m).
# The action is one flat index over (rotation, row, col), 16 × 224 × 224: a top-down grasp at the pixel's 3-D point
# with the rotation's yaw, then place in the bin and return out of the cameras' view
# (`env.unwrapped.action_layout` encodes and decodes it). Reward: 1 placed, 0.5 grasped only, 0 otherwise.

# %%
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

# %% [markdown]
# The heightmaps are what an agent sees. We pick one grasp from them with the package's scripted heightmap oracle
# (`HeightmapGraspOracle`: the top-surface centre of the highest object and the narrowest rotation the jaws fit; a
# sanity baseline, no learning) and mark it.

# %%
from maniskill_pnp.agents.scripted.clutter_oracle import HeightmapGraspOracle

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

# %%
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

# %% [markdown]
# ## Part III: `ClutterGraspSlide-v1`
#
# Grasp & slide ("G&S") in any clutter, tightly packed allowed: by default 10 objects dropped at random orientations;
# `num_objects="min" / "medium" / "max"` are the thesis' density presets and `layout="complicated"` its 8
# hand-designed locking layouts (notebook 04). The action gains a primitive axis: (primitive, rotation, row, col) with
# primitives `grasp`, `left_slide`, `right_slide`. A slide lowers the closed fingertips beside the pixel's 3-D point
# and pushes them 8 cm to the left or right of the rotation's jaw direction (rotation 0: jaws along +x, left = +y).
# Reward: 1 placed, 0.8 grasped, 0.5 for a slide that changed the heightmap (VPG's changed-pixels test), 0 otherwise.
#
# We push the tallest object of the central part of the workspace: start 4 cm on its -y side and slide left (+y)
# through it. (A slide that knocks an object out of the workspace earns nothing: clearing the table by pushing must
# not pay.)

# %%
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

# %% [markdown]
# Next: `02_conveyor_tabular.py` learns the conveyor with tabular Q-learning and SARSA,
# `03_pixel_grasp_agent.py` trains the pixelwise grasping DQN, `04_grasp_and_slide.py` shows why slides are
# needed on the locking layouts.
