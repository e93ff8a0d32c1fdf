"""Draw docs/design.png: the package's parts and how data flows between them (run: python docs/design_figure.py)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

BOXES = {
    # name: (x, y, w, h, colour, title, lines)
    "sim": (0.2, 4.3, 3.4, 1.6, "#dde8f5", "ManiSkill 3 / SAPIEN", ["PhysX (CPU or CUDA) physics", "lavapipe / GPU rendering", "Panda, pd_joint_pos, 20 Hz control"]),
    "tasks": (0.2, 1.6, 3.4, 2.3, "#e3f1df", "maniskill_pnp.tasks", ["ConveyorProximity-v1: ray sensors", "ClutterGrasp-v1: RGB-D heightmap", "ClutterGraspSlide-v1: 3 primitives,", "  density presets, locking layouts", "one step = one planned primitive"]),
    "planning": (4.7, 1.6, 3.0, 2.3, "#fbe9d0", "maniskill_pnp.planning", ["IK (pinocchio) + FCL collisions", "OMPL RRT-Connect + simplify", "TOPP-RA timing, plan cache", "pick / place / slide / go_home"]),
    "torchrl": (4.7, 4.3, 3.0, 1.6, "#efe3f5", "TorchRL", ["ManiSkillTorchRLEnv, Collector", "prioritized replay (memmap)", "EGreedyModule, LossModule, loggers"]),
    "agents": (8.5, 3.0, 3.4, 2.9, "#f6dede", "maniskill_pnp.agents", ["tabular Q-learning / SARSA", "pixel FCN Q maps (DenseNet-121,", "  ResNet-101, small) x rotations", "pixel DQN / BCE loss, action mask", "recipes: config, checkpoints, resume", "evaluation, curves, video; oracles"]),
    "scenes": (0.2, 0.15, 7.5, 1.2, "#e8f4ea", "maniskill_pnp.scenes, maniskill_pnp.cell", ["scenes: objects (procedural, mesh, YCB), clutter, scene files, locking layouts, hard sets", "cell: WorkspaceSpec (grid, cameras, rotations), bin, heightmap projection, pixel <-> action"]),
    "cli": (8.5, 0.5, 3.4, 2.0, "#eeeeee", "maniskill-pnp (cli.py)", ["quickstart, train-*, eval-*,", "record-clutter, plot-clutter,", "bench ... -> runs/<name>/"]),
}
#: (start, end, label, label position): edge to edge between the boxes above.
ARROWS = [
    ((1.9, 4.25), (1.9, 3.95), "scene, sensors", (1.15, 4.1)),
    ((3.65, 3.3), (4.65, 3.3), "goal poses", (4.15, 3.48)),
    ((4.65, 2.3), (3.65, 2.3), "joint targets", (4.15, 2.48)),
    ((3.3, 3.95), (4.65, 4.6), "obs, reward, info", (3.75, 4.55)),
    ((7.75, 5.3), (8.45, 5.3), "batches", (8.1, 5.48)),
    ((8.45, 4.6), (7.75, 4.6), "actions", (8.1, 4.78)),
    ((10.2, 2.55), (10.2, 2.95), "configs", (10.75, 2.75)),
    ((1.9, 1.4), (1.9, 1.55), "layouts, objects, grid", (2.9, 1.48)),
]


def main(path: Path = Path(__file__).parent / "design.png") -> Path:
    fig, ax = plt.subplots(figsize=(12, 6.4))
    ax.set_xlim(0, 12)
    ax.set_ylim(0, 6.3)
    ax.axis("off")
    for x, y, w, h, colour, title, lines in BOXES.values():
        ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.05", fc=colour, ec="#555555", lw=1.2))
        ax.text(x + 0.12, y + h - 0.3, title, fontsize=11, fontweight="bold", va="center")
        for i, line in enumerate(lines):
            ax.text(x + 0.15, y + h - 0.68 - 0.36 * i, line, fontsize=9, va="center", family="monospace")
    for start, end, text, (lx, ly) in ARROWS:
        ax.add_patch(FancyArrowPatch(start, end, arrowstyle="-|>", mutation_scale=14, color="#333333", lw=1.3))
        ax.text(lx, ly, text, fontsize=8.5, ha="center", va="center", color="#222222")
    ax.set_title("maniskill_pnp: tasks on ManiSkill, motions by OMPL, agents on TorchRL", fontsize=13)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == "__main__":
    print(main())
