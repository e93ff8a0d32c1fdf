"""Benchmark of the motion layer: pick-and-place of an isolated cube over seeded episodes.

Prints the success count, the median planning time of a pick, the wall time of a whole pick-and-place
(pick, place, return home; no rendering) and its sim steps; writes the numbers as JSON. Side by side in the
same run it times ManiSkill's own mplib motion-planning solution of ``PickCube-v1`` (pick and lift to a goal),
the yardstick named in the design notes, and prints the ratio of episodes per second (reset included in both).
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym

from maniskill_pnp.bench.common import print_machine, write_report
from maniskill_pnp.demo import STATIC_ACTORS, cube_grasp_pose
from maniskill_pnp.planning import MotionPrimitives
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.runtime import default_backends


@dataclass(frozen=True)
class PrimitivesBenchConfig:
    """Settings of the primitives benchmark.

    Attributes:
        episodes: Seeded pick-and-place episodes (seeds 0..episodes-1).
        yardstick: Also run ManiSkill's mplib solution of PickCube-v1 for the same seeds.
        out: JSON report path.
    """

    episodes: int = 20
    yardstick: bool = True
    out: Path = Path("runs/bench/primitives.json")


def run(cfg: PrimitivesBenchConfig) -> dict:
    if cfg.episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {cfg.episodes}")
    env = gym.make("CubeToBin-v1", obs_mode="state", control_mode="pd_joint_pos", **default_backends())
    pick_plan, walls, steps, successes, failures = [], [], [], 0, []
    t_all = time.perf_counter()
    prims = MotionPrimitives(env, static_actors=STATIC_ACTORS, seed=0)  # one instance per run, as the tasks do
    for seed in progress_bar(range(cfg.episodes), desc="pick-and-place", unit="ep"):
        env.reset(seed=seed)
        prims.reset()
        t0 = time.perf_counter()
        pick = prims.pick(cube_grasp_pose(env), target="cube")
        results = [pick]
        if pick.ok:
            results.append(prims.place(env.unwrapped.bin_spec.region()))
        results.append(prims.go_home())
        walls.append(time.perf_counter() - t0)
        pick_plan.append(pick.planning_time)
        steps.append(sum(r.sim_steps for r in results))
        ok = bool(env.unwrapped.evaluate()["success"].item())
        successes += ok
        if not ok:
            failures.append({"seed": seed, "stages": [(r.stage, r.reason) for r in results if not r.ok]})
    ours_eps = cfg.episodes / (time.perf_counter() - t_all)
    env.close()
    results = {
        "successes": successes,
        "episodes": cfg.episodes,
        "pick_planning_time_s_median": statistics.median(pick_plan),
        "pick_and_place_wall_s_median": statistics.median(walls),
        "pick_and_place_sim_steps_median": statistics.median(steps),
        "episodes_per_s_incl_reset": ours_eps,
        "failures": failures,
    }
    if cfg.yardstick:
        results["maniskill_mplib_pickcube"] = _maniskill_yardstick(cfg.episodes)
        results["episodes_per_s_ratio_ours_over_maniskill"] = ours_eps / results["maniskill_mplib_pickcube"]["episodes_per_s_incl_reset"]
    path = write_report(cfg.out, "primitives", {k: str(v) for k, v in asdict(cfg).items()}, results)
    print_machine()
    print(f"pick-and-place of an isolated cube, {cfg.episodes} seeded episodes, no rendering")
    print(f"  success                       {successes}/{cfg.episodes}")
    print(f"  median planning time (pick)   {results['pick_planning_time_s_median'] * 1000:.1f} ms")
    print(f"  median wall time (pick+place+home) {results['pick_and_place_wall_s_median']:.3f} s")
    print(f"  median sim steps              {results['pick_and_place_sim_steps_median']:.0f}")
    print(f"  episodes per second (incl. reset) {ours_eps:.2f}")
    if cfg.yardstick:
        ms = results["maniskill_mplib_pickcube"]
        print(f"ManiSkill's mplib PickCube-v1 solution, same seeds: {ms['successes']}/{cfg.episodes} solved, "
              f"{ms['episodes_per_s_incl_reset']:.2f} episodes/s")
        print(f"  ratio ours / ManiSkill        {results['episodes_per_s_ratio_ours_over_maniskill']:.2f}x")
    print(f"report: {path}")
    return results


def _maniskill_yardstick(episodes: int) -> dict:
    """ManiSkill's own mplib-based PickCube-v1 solver over the same seeds (its run script's settings)."""
    from mani_skill.examples.motionplanning.panda.solutions import solvePickCube

    env = gym.make("PickCube-v1", obs_mode="none", control_mode="pd_joint_pos", **default_backends())
    solved = 0
    t0 = time.perf_counter()
    for seed in progress_bar(range(episodes), desc="ManiSkill PickCube (mplib)", unit="ep"):
        res = solvePickCube(env, seed=seed, debug=False, vis=False)
        solved += int(res != -1 and bool(res[-1]["success"].item()))
    eps = episodes / (time.perf_counter() - t0)
    env.close()
    return {"successes": solved, "episodes_per_s_incl_reset": eps}
