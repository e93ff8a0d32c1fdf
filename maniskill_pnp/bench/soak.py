"""Soak benchmark: thousands of primitive actions on ClutterGraspSlide-v1 under a random policy, watching for
crashes, memory growth and leaked scene objects.

The policy draws uniformly among the actions the heightmap action mask allows (grasps over material, slides next
to it: the training's exploration distribution), or over the whole action space with ``masked=False``. Every
episode ends by the task's own rules (cleared, 10 consecutive failures, the action cap, a fault) and is reset.

Measured: resident memory of the process after every action (``/proc/self/statm``), its growth from the end of
the warm-up to the end and the slope of a least-squares line over the same span; the scene's actors,
articulations, entities, lights and cameras after every reset (any change between resets is a leak); faults,
primitives and outcomes. Target (issue): no crash, growth under 200 MB after warm-up, no leaked scene objects.

Run it with ``maniskill-pnp bench soak --actions 2000``; writes JSON (with the memory series) and a PNG of it.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from maniskill_pnp.bench.common import print_machine, write_report
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.runtime import default_backends

_PAGE = os.sysconf("SC_PAGE_SIZE")


@dataclass(frozen=True)
class SoakBenchConfig:
    """Settings of the soak benchmark.

    Attributes:
        actions: Primitive actions to execute in all (episodes are reset as they end).
        warmup: Actions before the memory baseline is taken (caches, allocator pools and plan caches fill first).
        num_objects: Objects per scene (an int or a density preset such as ``"medium"``).
        heightmap_size: Heightmap pixels per side (the task default is 224).
        num_rotations: Rotations of the action (the task default is 16).
        masked: Draw among the actions the heightmap mask allows (True) or over the whole action space.
        seed: Seed of the first episode and of the policy.
        report_every: Write the report so far (``"complete": false``) every this many actions.
        out: JSON report path (the PNG goes beside it).
    """

    actions: int = 2000
    warmup: int = 200
    num_objects: int | str = 10
    heightmap_size: int = 224
    num_rotations: int = 16
    masked: bool = True
    seed: int = 0
    report_every: int = 100
    out: Path = Path("runs/bench/soak.json")

    def __post_init__(self):
        if self.actions < 1 or not 0 <= self.warmup < self.actions:
            raise ValueError(f"need actions >= 1 and 0 <= warmup < actions, got actions={self.actions}, warmup={self.warmup}")
        if self.report_every < 1:
            raise ValueError(f"report_every must be >= 1, got {self.report_every}")


def rss_mb() -> float:
    """Resident memory of this process (MB)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * _PAGE / 2**20


def scene_counts(env) -> dict[str, int]:
    """How many actors, articulations, entities, lights and cameras the env's (single) scene holds."""
    scene = env.unwrapped.scene
    entities = scene.sub_scenes[0].entities
    kinds = Counter(type(c).__name__ for e in entities for c in e.components)
    return dict(
        actors=len(scene.actors), articulations=len(scene.articulations), entities=len(entities),
        lights=sum(n for k, n in kinds.items() if "Light" in k), cameras=sum(n for k, n in kinds.items() if "Camera" in k),
        sensors=len(scene.sensors),
    )


def random_action(obs: dict, env, rng: np.random.Generator, mask) -> int:
    """A uniform draw among the allowed flat actions (all of them without a mask)."""
    n = env.action_space.n
    if mask is None:
        return int(rng.integers(n))
    allowed = torch.nonzero(mask(obs["depth_heightmap"]).reshape(-1)).flatten()
    return int(allowed[rng.integers(len(allowed))]) if len(allowed) else int(rng.integers(n))


def run(cfg: SoakBenchConfig) -> dict:
    from maniskill_pnp.agents.pixel.mask import HeightmapActionMask
    from maniskill_pnp.tasks.clutter_grasp_slide import ClutterGraspSlideEnv
    from maniskill_pnp.cell.workspace import WorkspaceSpec

    side = WorkspaceSpec().side
    workspace = WorkspaceSpec(heightmap_size=cfg.heightmap_size, pixel_size=side / cfg.heightmap_size, num_rotations=cfg.num_rotations)
    env = gym.make("ClutterGraspSlide-v1", num_objects=cfg.num_objects, workspace=workspace, **default_backends())
    mask = HeightmapActionMask(ClutterGraspSlideEnv.PRIMITIVES, cfg.num_rotations) if cfg.masked else None
    rng = np.random.default_rng(cfg.seed)
    memory, leaks = [], []
    primitives, outcomes, faults = Counter(), Counter(), Counter()
    episodes, t0 = 0, time.perf_counter()
    obs, _ = env.reset(seed=cfg.seed)
    counts = scene_counts(env)
    settings = {k: str(v) for k, v in asdict(cfg).items()}
    with progress_bar(total=cfg.actions, desc="soak ClutterGraspSlide-v1", unit="action") as bar:
        for i in range(cfg.actions):
            obs, reward, terminated, truncated, info = env.step(random_action(obs, env, rng, mask))
            memory.append(rss_mb())
            primitives[info["primitive"]] += 1
            outcomes["placed" if info["place_success"] else "grasped" if info["grasp_success"] else
                     "slide_changed" if info["slide_changed"] else "failed"] += 1
            if info["fault"]:
                reason = str(info["fault_reason"])
                faults[reason.split(" ")[0] if "rests" not in reason else "object on gripper"] += 1
            if terminated.item() or truncated.item():
                episodes += 1
                obs, _ = env.reset(seed=cfg.seed + episodes)
                now = scene_counts(env)
                if now != counts:
                    leaks.append(dict(action=i + 1, before=counts, after=now))
                counts = now
            bar.set_postfix(episodes=episodes, rss_mb=f"{memory[-1]:.0f}")
            bar.update()
            if (i + 1) % cfg.report_every == 0 and i + 1 < cfg.actions:  # a partial report survives an interrupted soak
                partial = summarize(memory, cfg.warmup, episodes, time.perf_counter() - t0, counts, leaks, primitives, outcomes, faults)
                write_report(cfg.out, "soak", settings, dict(partial, complete=False))
    env.close()
    results = dict(summarize(memory, cfg.warmup, episodes, time.perf_counter() - t0, counts, leaks, primitives, outcomes, faults),
                   complete=True)
    path = write_report(cfg.out, "soak", settings, results)
    png = plot_memory(memory, cfg.warmup, path.with_suffix(".png"))
    after, slope, wall = results["rss_mb_after_warmup"], results["slope_mb_per_1000_actions"], results["wall_s"]
    print_machine()
    print(f"ClutterGraspSlide-v1, random {'masked ' if cfg.masked else ''}policy: {cfg.actions} actions, {episodes} episodes, "
          f"{wall / 60:.1f} min ({results['actions_per_s']:.2f} actions/s)")
    print(f"  RSS: start {memory[0]:.0f} MB, after warm-up ({cfg.warmup} actions) {after:.0f} MB, end {memory[-1]:.0f} MB, "
          f"max {max(memory):.0f} MB")
    print(f"  growth after warm-up {results['growth_after_warmup_mb']:+.0f} MB (max {results['max_growth_after_warmup_mb']:+.0f} MB, "
          f"slope {slope:+.1f} MB per 1000 actions); target < 200 MB")
    print(f"  scene objects after every reset: {counts}; leaks: {len(leaks)}")
    print(f"  primitives {dict(primitives)}, outcomes {dict(outcomes)}, faults {dict(faults)}")
    print(f"report: {path}\nplot: {png}")
    return results


def summarize(memory, warmup, episodes, wall, counts, leaks, primitives, outcomes, faults) -> dict:
    """The soak's numbers so far (see the module docstring); the memory baseline is the action after ``warmup``."""
    base = memory[min(warmup, len(memory) - 1)]
    after = np.asarray(memory[min(warmup, len(memory) - 1):])
    slope = float(np.polyfit(np.arange(len(after)), after, 1)[0]) * 1000 if len(after) > 1 else 0.0
    return dict(
        actions=len(memory), episodes=episodes, wall_s=wall, actions_per_s=len(memory) / wall,
        rss_mb_start=memory[0], rss_mb_after_warmup=base, rss_mb_end=memory[-1], rss_mb_max=max(memory),
        growth_after_warmup_mb=float(memory[-1] - base), max_growth_after_warmup_mb=float(after.max() - base),
        slope_mb_per_1000_actions=slope, scene_counts=counts, leaks=list(leaks), primitives=dict(primitives),
        outcomes=dict(outcomes), faults=dict(faults), rss_mb_series=[round(m, 1) for m in memory],
    )


def plot_memory(memory: list[float], warmup: int, path: Path) -> Path:
    import matplotlib.pyplot as plt  # the backend is left to the caller (Agg when there is no display)

    fig, ax = plt.subplots(figsize=(7, 3.4))
    ax.plot(np.arange(1, len(memory) + 1), memory, lw=1)
    ax.axvline(warmup, color="grey", ls="--", lw=1, label=f"end of warm-up ({warmup})")
    ax.set_xlabel("primitive actions")
    ax.set_ylabel("resident memory (MB)")
    ax.set_title("soak: ClutterGraspSlide-v1, random policy")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ["SoakBenchConfig", "random_action", "rss_mb", "run", "scene_counts", "summarize"]
