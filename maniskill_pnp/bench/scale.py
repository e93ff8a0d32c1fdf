"""Benchmarks of how far one machine goes: env overhead, collection scaling, and where a decision's time goes.

**env-overhead** — physics steps per second of ``ClutterGrasp-v1`` while its primitives execute (random grasps on
material, each a real pick-and-place or a failed grasp) ÷ those of a bare ManiSkill ``PickCube-v1`` with the same
robot (Panda), controller (``pd_joint_pos``) and backends, stepped with ``env.step`` (and, for reference, with the
bare control step ``_step_action`` our executor uses), measured side by side in one run.

**collection** — transitions per second of the TorchRL process collector with 2 env workers ÷ with 1 (or any list of
worker counts), on the conveyor or a clutter task, with the recipe's exploring policy (ε = 1: random allowed actions).
Worker start-up is left out: the first ``warmup`` batches are not timed.

**decision-breakdown** — one table of where a greedy G&S decision's time goes: render, heightmap, network, planning,
execution (primitive and way home, planning excluded), and the rest of the env step.

**batched-decisions** — decisions per second of a clutter task (the recipe's exploring actor, ε = 1: random allowed
actions, one network call for all envs) with ManiSkill's GPU simulation and rendering at each ``num_envs``, beside
the CPU path (PhysX CPU, lavapipe, one env) measured in the same run; ratios against the CPU row. Without a CUDA GPU
only the CPU row runs.

Each prints the machine, versions and settings with its numbers and writes them as JSON
(:func:`maniskill_pnp.bench.common.write_report`); run them with ``maniskill-pnp bench env-overhead`` /
``collection`` / ``decision-breakdown`` / ``batched-decisions``.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path

import gymnasium as gym
import torch

from maniskill_pnp.agents.run_io import require_positive
from maniskill_pnp.bench.common import print_machine, write_report
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.runtime import default_backends

#: The clutter recipe preset the decision benchmarks measure unless told otherwise.
DEFAULT_PRESET = "gs-cpu-equi"

#: Tasks the collection benchmark can run, with the recipe that builds them.
COLLECTION_TASKS = ("conveyor", "clutter", "clutter-slide")
#: Parts of a decision in the breakdown table, in pipeline order.
DECISION_PARTS = ("render", "heightmap", "network", "planning", "execution", "other")


def _clutter_config(preset: str, **overrides):
    from maniskill_pnp.agents.pixel.config import ClutterConfig

    return ClutterConfig.from_preset(preset, **overrides)


def _exploring_pixel_policy(cfg, env, eps: float):
    """The clutter recipe's actor over a freshly initialised network: ε = 1 random allowed actions, 0 greedy."""
    from maniskill_pnp.agents.pixel.factories import make_model, make_policy

    greedy, explore, _ = make_policy(cfg, make_model(cfg).eval(), env.action_spec, eps=eps)
    return greedy if eps == 0 else explore


def _check_preset(preset: str) -> None:
    from maniskill_pnp.agents.pixel.config import presets

    if preset not in presets():
        raise ValueError(f"unknown preset {preset!r}; valid: {list(presets())}")


# ============================================================================= env-overhead
@dataclass(frozen=True)
class EnvOverheadBenchConfig:
    """Settings of the env-overhead benchmark.

    Attributes:
        actions: Primitive actions (random grasps on material) of ClutterGrasp-v1 timed.
        bare_steps: Control steps of the bare PickCube-v1 timed (each way).
        num_objects: Objects in the clutter.
        heightmap_size: Heightmap pixels per side of the clutter task.
        seed: Seed of the clutters and the random grasps.
        out: JSON report.
    """

    actions: int = 8
    bare_steps: int = 300
    num_objects: int = 6
    heightmap_size: int = 64
    seed: int = 0
    out: Path = Path("runs/bench/env_overhead.json")

    def __post_init__(self):
        require_positive(self, ("actions", "bare_steps", "num_objects", "heightmap_size"))


def _bare_pickcube(steps: int, seed: int) -> dict:
    """Sim steps per second of PickCube-v1 (Panda, pd_joint_pos, no observations) held at its start pose."""
    import mani_skill.envs  # noqa: F401  (registers PickCube-v1)

    env = gym.make("PickCube-v1", robot_uids="panda", control_mode="pd_joint_pos", obs_mode="none",
                   **default_backends(1))
    env.reset(seed=seed)
    base = env.unwrapped
    hold = base.agent.robot.get_qpos()[:, :8].clone()
    hold[:, 7] = 1.0  # 7 arm joint targets and the gripper command (open)
    per_control = base._sim_steps_per_control
    env.step(hold)  # warm-up
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(hold)
    t_step = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(steps):
        base._step_action(hold)
    t_control = time.perf_counter() - t0
    env.close()
    sim_steps = steps * per_control
    return dict(sim_steps=sim_steps, sim_freq=base.sim_freq, control_freq=base.control_freq,
                env_step_sim_steps_per_s=sim_steps / t_step, control_step_sim_steps_per_s=sim_steps / t_control)


def _clutter_primitives(cfg: EnvOverheadBenchConfig) -> dict:
    """Sim steps and times of random grasps on material in ClutterGrasp-v1 (the recipe's env, ε = 1)."""
    from maniskill_pnp.agents.pixel.factories import make_env

    ccfg = _clutter_config("cpu-small", num_objects=cfg.num_objects, heightmap_size=cfg.heightmap_size, seed=cfg.seed)
    env = make_env(ccfg)
    env.set_seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    policy = _exploring_pixel_policy(ccfg, env, eps=1.0)
    base = env.base_env
    td = env.reset()
    sums = dict(sim_steps=0, motion=0.0, planning=0.0, step=0.0)
    grasps = 0
    for _ in progress_bar(range(cfg.actions), desc="ClutterGrasp-v1 primitives", unit="action"):
        with torch.inference_mode():
            td = policy(td)
        t0 = time.perf_counter()
        td, td_next = env.step_and_maybe_reset(td)
        sums["step"] += time.perf_counter() - t0
        timings = base.step_timings
        for key in ("sim_steps", "motion", "planning"):
            sums[key] += timings[key]
        grasps += int(base.last[0].get("grasp_success", False))
        td = td_next
    env.close()
    execution = sums["motion"] - sums["planning"]
    return dict(actions=cfg.actions, grasps=grasps, sim_freq=base.sim_freq, control_freq=base.control_freq, **sums,
                execution_sim_steps_per_s=sums["sim_steps"] / execution,
                motion_sim_steps_per_s=sums["sim_steps"] / sums["motion"],
                step_sim_steps_per_s=sums["sim_steps"] / sums["step"])


def run_env_overhead(cfg: EnvOverheadBenchConfig) -> dict:
    ours = _clutter_primitives(cfg)
    bare = _bare_pickcube(cfg.bare_steps, cfg.seed)
    results = dict(
        clutter_grasp=ours, pickcube=bare,
        ratio_execution_vs_env_step=ours["execution_sim_steps_per_s"] / bare["env_step_sim_steps_per_s"],
        ratio_execution_vs_control_step=ours["execution_sim_steps_per_s"] / bare["control_step_sim_steps_per_s"],
        ratio_whole_step_vs_env_step=ours["step_sim_steps_per_s"] / bare["env_step_sim_steps_per_s"],
    )
    write_report(Path(cfg.out), "env-overhead", {k: str(v) for k, v in asdict(cfg).items()}, results)
    print_machine()
    print(f"ClutterGrasp-v1 ({cfg.num_objects} objects, {cfg.heightmap_size} px): {ours['actions']} primitives, "
          f"{ours['grasps']} grasps, {ours['sim_steps']} sim steps")
    print(f"  sim steps/s while executing {ours['execution_sim_steps_per_s']:.0f}, over the whole primitive with "
          f"planning {ours['motion_sim_steps_per_s']:.0f}, over the whole env step {ours['step_sim_steps_per_s']:.0f}")
    print(f"PickCube-v1 bare (panda, pd_joint_pos): env.step {bare['env_step_sim_steps_per_s']:.0f} sim steps/s, "
          f"_step_action {bare['control_step_sim_steps_per_s']:.0f} sim steps/s")
    print(f"ratio ours executing / bare env.step: {results['ratio_execution_vs_env_step']:.2f} "
          f"(vs bare control step {results['ratio_execution_vs_control_step']:.2f}; whole step incl. planning and "
          f"rendering {results['ratio_whole_step_vs_env_step']:.2f})")
    print(f"report: {cfg.out}")
    return results


# ============================================================================= collection
@dataclass(frozen=True)
class CollectionBenchConfig:
    """Settings of the collection-scaling benchmark.

    Attributes:
        task: "conveyor" (ConveyorProximity-v1), "clutter" (ClutterGrasp-v1) or "clutter-slide" (ClutterGraspSlide-v1).
        workers: Worker counts measured, each with a fresh process collector; ratios are against the first.
        frames: Timed transitions per worker count (rounded up to whole batches).
        warmup: Untimed batches first (worker start-up, first resets).
        num_objects: Objects in the clutter (clutter tasks).
        seed: Seed of the first worker.
        out: JSON report.
    """

    task: str = "conveyor"
    workers: tuple[int, ...] = (1, 2)
    frames: int = 24
    warmup: int = 2
    num_objects: int = 6
    seed: int = 0
    out: Path = Path("runs/bench/collection.json")

    def __post_init__(self):
        if self.task not in COLLECTION_TASKS:
            raise ValueError(f"unknown task {self.task!r}; valid: {list(COLLECTION_TASKS)}")
        workers = tuple(int(w) for w in self.workers)
        if not workers or min(workers) < 1:
            raise ValueError(f"workers must be counts >= 1, got {list(self.workers)}")
        object.__setattr__(self, "workers", workers)
        require_positive(self, ("frames", "num_objects"))
        if self.warmup < 0:
            raise ValueError(f"warmup must be >= 0, got {self.warmup}")


def collection_setup(task: str, seed: int = 0, **clutter_overrides):
    """``(make_env(seed), policy)`` of ``task`` (a :data:`COLLECTION_TASKS` name), built the way its recipe builds
    them, with the exploring policy at ε = 1 (random allowed actions); ``clutter_overrides`` change the clutter
    config (e.g. ``heightmap_size``, ``num_rotations``, ``num_objects``)."""
    if task not in COLLECTION_TASKS:
        raise ValueError(f"unknown task {task!r}; valid: {list(COLLECTION_TASKS)}")
    if task == "conveyor":
        from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, make_env, make_worker_env
        from maniskill_pnp.agents.tabular.qtable import QTable, make_qtable_policy
        from maniskill_pnp.tasks.conveyor_config import ConveyorSpec

        tcfg = ConveyorConfig(seed=seed)
        env = make_env(tcfg)
        spec = ConveyorSpec()
        _, policy, _ = make_qtable_policy(QTable(spec.num_states, spec.action_n), env.action_spec_unbatched,
                                          eps_init=1.0, eps_end=1.0, annealing_num_steps=1)
    else:
        from maniskill_pnp.agents.pixel.factories import make_env, make_worker_env

        tcfg = _clutter_config("cpu-small" if task == "clutter" else "gs-cpu-small", seed=seed, **clutter_overrides)
        env = make_env(tcfg)
        policy = _exploring_pixel_policy(tcfg, env, eps=1.0)
    env.close()  # it only gave the specs; every worker builds its own
    return partial(make_worker_env, tcfg), policy


def _measure_collection(make_env, policy, workers: int, cfg: CollectionBenchConfig) -> dict:
    from maniskill_pnp.agents.collection import make_collector

    batches = cfg.warmup + -(-cfg.frames // workers)
    collector = make_collector(make_env, policy, seed=cfg.seed, total_frames=batches * workers, workers=workers,
                               backend="process")
    timed = 0
    t0 = time.perf_counter()
    bar = progress_bar(total=batches * workers, desc=f"{cfg.task}, {workers} worker(s)", unit="frame")
    for i, batch in enumerate(collector):
        bar.update(batch.numel())
        if i + 1 == cfg.warmup:
            t0 = time.perf_counter()
        elif i + 1 > cfg.warmup:
            timed += batch.numel()
        if i + 1 >= batches:
            break
    elapsed = time.perf_counter() - t0
    bar.close()
    collector.shutdown()
    return dict(workers=workers, frames=timed, seconds=elapsed, transitions_per_s=timed / elapsed)


def run_collection(cfg: CollectionBenchConfig) -> dict:
    make_env, policy = collection_setup(cfg.task, cfg.seed, num_objects=cfg.num_objects)
    rows = [_measure_collection(make_env, policy, w, cfg) for w in cfg.workers]
    base = rows[0]["transitions_per_s"]
    for row in rows:
        row["ratio_vs_first"] = row["transitions_per_s"] / base
    results = dict(task=cfg.task, rows=rows)
    write_report(Path(cfg.out), "collection", {k: str(v) for k, v in asdict(cfg).items()}, results)
    print_machine()
    print(f"collection of {cfg.task} (process backend, ε = 1, {cfg.frames} timed frames after {cfg.warmup} batches):")
    for row in rows:
        print(f"  {row['workers']} worker(s): {row['transitions_per_s']:.2f} transitions/s "
              f"(x{row['ratio_vs_first']:.2f} of {cfg.workers[0]} worker(s))")
    print(f"report: {cfg.out}")
    return results


# ============================================================================= decision-breakdown
@dataclass(frozen=True)
class DecisionBreakdownBenchConfig:
    """Settings of the per-decision breakdown.

    Attributes:
        preset: Clutter recipe preset of the agent and the task (an untrained network: the time, not the choice,
            is measured).
        decisions: Greedy decisions timed (episodes restart as needed).
        num_objects: Objects in the clutter.
        seed: Seed of the network, the clutters and the planner.
        out: JSON report (a Markdown table is written beside it).
    """

    preset: str = DEFAULT_PRESET
    decisions: int = 10
    num_objects: int = 10
    seed: int = 0
    out: Path = Path("runs/bench/decision_breakdown.json")

    def __post_init__(self):
        _check_preset(self.preset)
        require_positive(self, ("decisions", "num_objects"))


def breakdown_table(rows: list[dict]) -> str:
    """Markdown table: median and mean milliseconds and the share of the total, per part of a decision."""
    total = sum(statistics.fmean(r[p] for r in rows) for p in DECISION_PARTS)
    lines = ["| part | median ms | mean ms | share |", "|---|---|---|---|"]
    for p in DECISION_PARTS + ("total",):
        values = [sum(r[q] for q in DECISION_PARTS) if p == "total" else r[p] for r in rows]
        mean = statistics.fmean(values)
        lines.append(f"| {p} | {1e3 * statistics.median(values):.1f} | {1e3 * mean:.1f} | {100 * mean / total:.1f}% |")
    return "\n".join(lines)


def run_decision_breakdown(cfg: DecisionBreakdownBenchConfig) -> dict:
    from maniskill_pnp.agents.pixel.factories import make_env

    torch.manual_seed(cfg.seed)
    ccfg = _clutter_config(cfg.preset, num_objects=cfg.num_objects, seed=cfg.seed)
    env = make_env(ccfg)
    env.set_seed(cfg.seed)
    policy = _exploring_pixel_policy(ccfg, env, eps=0.0)
    base = env.base_env
    td = env.reset()
    rows = []
    for _ in progress_bar(range(cfg.decisions), desc=f"{cfg.preset} decisions", unit="decision"):
        t0 = time.perf_counter()
        with torch.inference_mode():
            td = policy(td)
        t1 = time.perf_counter()
        td, td_next = env.step_and_maybe_reset(td)
        t_step = time.perf_counter() - t1
        t = base.step_timings
        rows.append(dict(render=t["render"], heightmap=t["heightmap"], network=t1 - t0, planning=t["planning"],
                         execution=t["motion"] - t["planning"],
                         other=max(0.0, t_step - t["motion"] - t["render"] - t["heightmap"])))
        td = td_next
    env.close()
    table = breakdown_table(rows)
    results = dict(decisions=rows, mean_s={p: statistics.fmean(r[p] for r in rows) for p in DECISION_PARTS},
                   median_s={p: statistics.median(r[p] for r in rows) for p in DECISION_PARTS},
                   decisions_per_s=len(rows) / sum(sum(r.values()) for r in rows), table=table)
    out = Path(cfg.out)
    write_report(out, "decision-breakdown", {k: str(v) for k, v in asdict(cfg).items()}, results)
    out.with_suffix(".md").write_text(table + "\n")
    print_machine()
    print(f"{cfg.preset}: {ccfg.heightmap_size} px, {ccfg.num_rotations} rotations, {len(ccfg.primitives)} primitives, "
          f"{cfg.num_objects} objects; {cfg.decisions} greedy decisions, {results['decisions_per_s']:.2f} decisions/s")
    print(table)
    print(f"report: {out}")
    return results


# ============================================================================= batched-decisions
@dataclass(frozen=True)
class BatchedDecisionsBenchConfig:
    """Settings of the batched-decisions benchmark.

    Attributes:
        preset: Clutter recipe preset of the task and the (untrained) actor.
        num_envs: Env counts run on the GPU (each a fresh env); the CPU row always has one env.
        steps: Timed steps per env count (each step is one decision per env), after one untimed step.
        num_objects: Objects in each clutter.
        seed: Seed of the network and the clutters.
        out: JSON report (a Markdown table is written beside it).
    """

    preset: str = DEFAULT_PRESET
    num_envs: tuple[int, ...] = (1, 16)
    steps: int = 3
    num_objects: int = 10
    seed: int = 0
    out: Path = Path("runs/bench/batched_decisions.json")

    def __post_init__(self):
        _check_preset(self.preset)
        object.__setattr__(self, "num_envs", tuple(int(n) for n in self.num_envs))
        if not self.num_envs or min(self.num_envs) < 1:
            raise ValueError(f"num_envs must be positive env counts, got {self.num_envs}")
        require_positive(self, ("steps", "num_objects"))


def _time_decisions(ccfg, steps: int, seed: int, **backend) -> dict:
    """Decisions per second of the exploring actor on the config's task built with ``backend`` options."""
    from maniskill_pnp.agents.pixel.factories import make_env

    torch.manual_seed(seed)
    env = make_env(ccfg, **backend)
    env.set_seed(seed)
    policy = _exploring_pixel_policy(ccfg, env, eps=1.0).to(env.device)
    n = env.batch_size[0] if env.batch_size else 1
    td = env.reset()
    times = []
    for _ in progress_bar(range(steps + 1), desc=f"{backend.get('sim_backend')} x{n}", unit="step"):
        t0 = time.perf_counter()
        with torch.inference_mode():
            td = policy(td)
        td, td_next = env.step_and_maybe_reset(td)
        times.append(time.perf_counter() - t0)
        td = td_next
    env.close()
    timed = times[1:]  # the first step builds the planners and allocates the render buffers
    return {**backend, "num_envs": int(n), "steps": steps, "seconds": sum(timed), "decisions_per_s": n * steps / sum(timed)}


def run_batched_decisions(cfg: BatchedDecisionsBenchConfig) -> dict:
    ccfg = _clutter_config(cfg.preset, num_objects=cfg.num_objects, seed=cfg.seed)
    rows = [_time_decisions(ccfg, cfg.steps, cfg.seed, sim_backend="physx_cpu", render_backend="cpu", num_envs=1)]
    if torch.cuda.is_available():
        for n in cfg.num_envs:
            rows.append(_time_decisions(ccfg, cfg.steps, cfg.seed, sim_backend="physx_cuda", render_backend="sapien_cuda",
                                        num_envs=n))
    else:
        print("no CUDA GPU: only the CPU row is measured")
    cpu = rows[0]["decisions_per_s"]
    lines = ["| simulation | rendering | envs | decisions/s | ÷ CPU |", "|---|---|---|---|---|"]
    for r in rows:
        r["ratio_to_cpu"] = r["decisions_per_s"] / cpu
        lines.append(f"| {r['sim_backend']} | {r['render_backend']} | {r['num_envs']} | {r['decisions_per_s']:.3f} | "
                     f"{r['ratio_to_cpu']:.2f} |")
    table = "\n".join(lines)
    results = dict(rows=rows, table=table)
    out = Path(cfg.out)
    write_report(out, "batched-decisions", {k: str(v) for k, v in asdict(cfg).items()}, results)
    out.with_suffix(".md").write_text(table + "\n")
    print_machine()
    print(f"{cfg.preset}: {ccfg.heightmap_size} px, {ccfg.num_rotations} rotations, {len(ccfg.primitives)} primitives, "
          f"{cfg.num_objects} objects; {cfg.steps} timed steps per row")
    print(table)
    print(f"report: {out}")
    return results


__all__ = [
    "BatchedDecisionsBenchConfig", "run_batched_decisions", "COLLECTION_TASKS", "CollectionBenchConfig", "collection_setup", "DECISION_PARTS", "DecisionBreakdownBenchConfig",
    "EnvOverheadBenchConfig", "breakdown_table", "run_collection", "run_decision_breakdown", "run_env_overhead",
]
