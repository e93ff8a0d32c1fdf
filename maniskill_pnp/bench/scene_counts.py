"""Benchmark of the scenes a density draws: how many objects each seeded scene starts with, with and without the
re-drop of objects that settle outside the workspace, side by side on the same seeds.

For each density (``ClutterGrasp-v1`` at its default 10-15 loosely packed objects, ``ClutterGraspSlide-v1`` piles
at ``min``, ``medium`` and ``max``) and each seed, one reset with the re-drop off (``REDROP_ROUNDS = 0``: the drop as
it falls) and one with the task's default; prints the distribution of starting counts (objects in the workspace
when the first action is taken), the scenes that start short of their drawn count or below the density's range,
and the mean reset time; writes JSON.
"""

from __future__ import annotations

import statistics
import time
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym

from maniskill_pnp.bench.common import print_machine, write_report
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.runtime import default_backends

#: (task id, num_objects) of the densities measured; None: the task's default.
DENSITIES = (("ClutterGrasp-v1", None), ("ClutterGraspSlide-v1", "min"), ("ClutterGraspSlide-v1", "medium"),
             ("ClutterGraspSlide-v1", "max"))


@dataclass(frozen=True)
class SceneCountsBenchConfig:
    """Settings of the scene-count benchmark.

    Attributes:
        scenes: Seeded scenes per density (seeds ``seed`` .. ``seed + scenes - 1``).
        seed: The first seed (1000: the evaluation scenes).
        out: JSON report path.
    """

    scenes: int = 100
    seed: int = 1000
    out: Path = Path("runs/bench/scene_counts.json")

    def __post_init__(self):
        if self.scenes < 1:
            raise ValueError(f"scenes must be >= 1, got {self.scenes}")


def count_scenes(env, seeds, redrop_rounds: int | None, bar=None) -> dict:
    """Starting counts of ``env``'s scenes for ``seeds`` with ``redrop_rounds`` re-drops (None: the task's default)."""
    task = env.unwrapped
    if redrop_rounds is not None:
        task.REDROP_ROUNDS = redrop_rounds
    lo, hi = task.num_objects_range
    drawn, start, times = [], [], []
    for seed in seeds:
        t0 = time.perf_counter()
        _, info = env.reset(seed=seed)
        times.append(time.perf_counter() - t0)
        drawn.append(int(info["num_objects"]))
        start.append(int(info["objects_remaining"]))
        if bar is not None:
            bar.update()
    if redrop_rounds is not None:
        del task.REDROP_ROUNDS  # back to the class default
    return dict(range=[lo, hi], start_counts=dict(sorted(Counter(start).items())), mean_start=statistics.mean(start),
                short=sum(s < d for s, d in zip(start, drawn)), below_range=sum(s < lo for s in start),
                objects_out=sum(d - s for s, d in zip(start, drawn)), reset_s_mean=statistics.mean(times))


def run(cfg: SceneCountsBenchConfig) -> dict:
    seeds = range(cfg.seed, cfg.seed + cfg.scenes)
    results = {}
    with progress_bar(total=2 * cfg.scenes * len(DENSITIES), desc="resets", unit="reset") as bar:
        for uid, density in DENSITIES:
            env = gym.make(uid, **({} if density is None else dict(num_objects=density)), **default_backends())
            try:
                results[f"{uid}:{density or 'default'}"] = dict(
                    no_redrop=count_scenes(env, seeds, 0, bar), redrop=count_scenes(env, seeds, None, bar))
            finally:
                env.close()
    path = write_report(cfg.out, "scene_counts", {k: str(v) for k, v in asdict(cfg).items()}, results)
    print_machine()
    print(f"objects in the workspace when the first action is taken, {cfg.scenes} scenes per density (seeds {cfg.seed}+)")
    for name, r in results.items():
        lo, hi = r["redrop"]["range"]
        print(f"{name} (draws {lo}-{hi})")
        for mode in ("no_redrop", "redrop"):
            m = r[mode]
            print(f"  {mode:<10} mean {m['mean_start']:.2f}, short of the drawn count {m['short']}, below {lo} "
                  f"{m['below_range']}, objects out {m['objects_out']}, reset {m['reset_s_mean']:.2f} s; counts "
                  + " ".join(f"{k}:{v}" for k, v in m["start_counts"].items()))
    print(f"report: {path}")
    return results
