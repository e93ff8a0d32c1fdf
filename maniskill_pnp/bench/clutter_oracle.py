"""Benchmark of the clutter tasks with a scripted oracle: grasp success, completion and the cost of one step.

Runs seeded scenes to the end with one of the oracles of :data:`ORACLES`: ``heightmap``
(:class:`~maniskill_pnp.agents.scripted.clutter_oracle.HeightmapGraspOracle`: highest pixel of an isolated object, jaws across
its shorter side, on ClutterGrasp-v1), ``grasp-only`` and ``slide-then-grasp``
(:class:`~maniskill_pnp.agents.scripted.slide_oracle.FeasibleGraspOracle`, which see the objects' shapes and poses: grasps
where the grasp check finds one, and, for the second, a slide that frees a locked object where none does, on
ClutterGraspSlide-v1), and prints the metrics of ``docs/metrics.md``
(``success_rate``, ``grasp_success``, ``completion``, ``action_efficiency``, counted as ``eval-clutter`` counts them)
and the time of one grasp step broken
down into render, heightmap, oracle and motion (planning included); writes JSON.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym

from maniskill_pnp.agents.pixel.evaluate import EpisodeTally, summarize
from maniskill_pnp.agents.pixel.factories import FILE_SCENARIOS, scenario_layout_files
from maniskill_pnp.bench.common import print_machine, write_report
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.runtime import default_backends
from maniskill_pnp.agents.scripted.clutter_oracle import HeightmapGraspOracle
from maniskill_pnp.agents.scripted.slide_oracle import FeasibleGraspOracle

#: The oracles: name -> the task it plays.
ORACLES = {"heightmap": "ClutterGrasp-v1", "grasp-only": "ClutterGraspSlide-v1", "slide-then-grasp": "ClutterGraspSlide-v1"}


@dataclass(frozen=True)
class ClutterOracleBenchConfig:
    """Settings of the clutter oracle benchmark.

    Attributes:
        scenes: Seeded scenes (seeds 0..scenes-1).
        num_objects: Objects per scene (random clutter).
        scenario: None: random loosely packed clutter of ``num_objects``; ``"hard"``: the hard test set's scene files
            (tightly packed, at least half the objects locked, and the locking layouts), or ``"hard_unseen"``: the
            held-out families' scene files; scene i playing file i mod their number.
        guard_force: Guarded grasps (N, see ``ClutterGrasp-v1``'s ``guard_force``); None: unguarded.
        oracle: One of :data:`ORACLES`.
        out: JSON report path.
    """

    scenes: int = 5
    num_objects: int = 10
    scenario: str | None = None
    guard_force: float | None = None
    oracle: str = "heightmap"
    out: Path = Path("runs/bench/clutter_oracle.json")


def run(cfg: ClutterOracleBenchConfig) -> dict:
    if cfg.scenes < 1 or cfg.num_objects < 1:
        raise ValueError(f"scenes and num_objects must be >= 1, got {cfg.scenes} and {cfg.num_objects}")
    if cfg.scenario is not None and cfg.scenario not in FILE_SCENARIOS:
        raise ValueError(f"scenario must be None (random clutter) or one of {list(FILE_SCENARIOS)}, got {cfg.scenario!r}")
    if cfg.oracle not in ORACLES:
        raise ValueError(f"unknown oracle {cfg.oracle!r}; valid: {list(ORACLES)}")
    files = None if cfg.scenario is None else scenario_layout_files(cfg.scenario)
    scene_args = dict(num_objects=cfg.num_objects) if files is None else dict(layout_file=[str(p) for p in files])
    env = gym.make(ORACLES[cfg.oracle], guard_force=cfg.guard_force, **scene_args, **default_backends())
    if cfg.oracle == "heightmap":
        heightmap_oracle = HeightmapGraspOracle(env.unwrapped.workspace)
        oracle = lambda obs: heightmap_oracle(obs["depth_heightmap"][0])  # noqa: E731
    else:
        oracle = FeasibleGraspOracle(env.unwrapped, slides=cfg.oracle == "slide-then-grasp")
    per_scene, times = [], {"render": [], "heightmap": [], "oracle": [], "motion": [], "planning": [], "step": []}
    for seed in progress_bar(range(cfg.scenes), desc="scenes", unit="scene"):
        obs, info = env.reset(seed=seed, options=None if files is None else {"layout_index": seed % len(files)})
        objects = int(info["objects_remaining"])
        tally = EpisodeTally(env.unwrapped.primitive_names)
        done = False
        while not done:
            t0 = time.perf_counter()
            action = oracle(obs)
            t_oracle = time.perf_counter() - t0
            obs, _, terminated, truncated, info = env.step(action)
            times["step"].append(time.perf_counter() - t0)
            times["oracle"].append(t_oracle)
            for part in ("render", "heightmap", "motion", "planning"):
                times[part].append(env.unwrapped.step_timings[part])
            tally.add(info)
            done = bool(terminated.item() or truncated.item())
        layout = None if files is None else files[seed % len(files)].stem
        per_scene.append(dict(seed=seed, layout=layout, objects=objects, actions=tally.actions, grasp_attempts=tally.grasp_attempts,
                              slides=tally.actions - tally.grasp_attempts,
                              grasps=tally.grasps, placed=tally.placed, cleared=bool(terminated.item()),
                              lost=int(info["lost_objects"]), max_failure_run=tally.max_failure_run, faults=tally.faults))
    env.close()
    results = dict(summarize(per_scene), scenes=per_scene,
                   step_time_s_median={k: statistics.median(v) for k, v in times.items()},
                   step_time_s_mean={k: statistics.mean(v) for k, v in times.items()})
    path = write_report(cfg.out, "clutter_oracle", {k: str(v) for k, v in asdict(cfg).items()}, results)
    print_machine()
    scenes = f"{cfg.num_objects} objects (loosely packed)" if files is None else "the hard set's files"
    guard = "unguarded" if cfg.guard_force is None else f"guarded at {cfg.guard_force:g} N"
    print(f"{ORACLES[cfg.oracle]}, {cfg.oracle} oracle, {cfg.scenes} scenes x {scenes}, {guard}")
    for key in ("success_rate", "grasp_success", "completion", "action_efficiency"):
        print(f"  {key:<18} {results[key]:.1%}")
    print(f"  actions {sum(s['actions'] for s in per_scene)} ({sum(s['slides'] for s in per_scene)} slides) for "
          f"{sum(s['objects'] for s in per_scene)} objects, {sum(s['placed'] for s in per_scene)} placed")
    print("  one step (median / mean, s):")
    for k in times:
        print(f"    {k:<10} {results['step_time_s_median'][k]:.3f} / {results['step_time_s_mean'][k]:.3f}")
    print(f"report: {path}")
    return results
