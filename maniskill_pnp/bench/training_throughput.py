"""Training actions per wall-clock hour of clutter recipe variants, measured side by side in one run.

Each variant is a preset with optional field overrides, written ``PRESET[,FIELD=VALUE...]`` (values in YAML syntax),
e.g. ``gs-cpu-equi,collector=direct`` (the simulator in the learner's process) against ``gs-cpu-equi`` (the default:
the learner updating while a worker process steps the simulator), or ``gs-thesis,device=cuda`` (the learner on the
GPU; each turn records the device its learner used). Every variant trains for real
(:func:`maniskill_pnp.agents.pixel.recipe.main`: env, ε-greedy actor, prioritized replay, ``updates_per_step`` SGD
steps per action, checkpoints) for ``minutes`` of
wall-clock time from its first action, in a scratch run folder; the variants take turns (A B A B ... with
``repeats``) so a drift in the machine's load touches all of them. Reported per variant: actions, updates, actions per
hour (the median over its turns) and the ratio to the first variant's, plus the start-up time (env and network
construction) that the rate leaves out.

Run it with ``maniskill-pnp bench training-throughput --variants gs-cpu-equi,collector=direct gs-cpu-equi``.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import yaml

from maniskill_pnp.agents.run_io import require_positive
from maniskill_pnp.bench.common import print_machine, write_report

DEFAULT_VARIANTS = ("gs-cpu-equi,collector=direct", "gs-cpu-equi")


def parse_variant(spec: str) -> tuple[str, dict]:
    """``"PRESET[,FIELD=VALUE...]"`` -> (preset, overrides), the overrides checked against the config's fields."""
    from maniskill_pnp.agents.pixel.config import ClutterConfig, presets

    preset, *pairs = [part.strip() for part in spec.split(",")]
    if preset not in presets():
        raise ValueError(f"variant {spec!r}: unknown preset {preset!r}; valid: {list(presets())}")
    overrides = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name:
            raise ValueError(f"variant {spec!r}: {pair!r} is not FIELD=VALUE")
        overrides[name.strip().replace("-", "_")] = yaml.safe_load(value)
    try:
        ClutterConfig._check_values(overrides)
        ClutterConfig.from_preset(preset, **overrides)  # the values too (e.g. a device), before any variant trains
    except ValueError as e:
        raise ValueError(f"variant {spec!r}: {e}") from e
    return preset, overrides


@dataclass(frozen=True)
class TrainingThroughputBenchConfig:
    """Settings of ``bench training-throughput`` (see the module docstring)."""

    variants: tuple[str, ...] = DEFAULT_VARIANTS
    """Variants ``PRESET[,FIELD=VALUE...]``; ratios are against the first."""
    minutes: float = 5.0
    """Training time of each turn of each variant, from its first action."""
    repeats: int = 1
    """Turns of each variant (A B A B ...)."""
    updates_per_step: int = 2
    """SGD updates per action for every variant (a variant's own ``updates_per_step=`` wins)."""
    seed: int = 0
    out: Path = Path("runs/bench/training_throughput.json")

    def __post_init__(self):
        if not self.variants:
            raise ValueError("give at least one variant")
        for spec in self.variants:
            parse_variant(spec)
        if not self.minutes > 0:
            raise ValueError(f"minutes must be > 0, got {self.minutes!r}")
        require_positive(self, ("repeats", "updates_per_step"))


def run_variant(spec: str, cfg: TrainingThroughputBenchConfig, out: Path) -> dict:
    """Train ``spec`` for ``cfg.minutes`` in ``out``; its learner's device, actions, updates, rate and start-up time."""
    from maniskill_pnp.agents.pixel.config import ClutterConfig
    from maniskill_pnp.agents.pixel.recipe import main

    preset, overrides = parse_variant(spec)
    values = dict(updates_per_step=cfg.updates_per_step, seed=cfg.seed, steps=10**9, max_minutes=cfg.minutes,
                  save_replay=False, out=out)
    config = ClutterConfig.from_preset(preset, **{**values, **overrides})
    t0 = time.perf_counter()
    summary = main(config)
    total = time.perf_counter() - t0
    actions, wall = summary["steps"], summary["wall_s"]
    return dict(device=summary["device"], actions=actions, updates=summary["updates"], train_s=wall,
                startup_s=total - wall, actions_per_hour=3600.0 * actions / wall, s_per_action=wall / max(actions, 1))


def run(cfg: TrainingThroughputBenchConfig) -> dict:
    """Run every variant ``repeats`` times in turn; print the table and write the JSON report."""
    print_machine()
    print(f"training throughput: {len(cfg.variants)} variants x {cfg.repeats} turns of {cfg.minutes:g} min, "
          f"{cfg.updates_per_step} updates per action")
    turns = {spec: [] for spec in cfg.variants}
    with tempfile.TemporaryDirectory(prefix="training_throughput_") as scratch:
        for r in range(cfg.repeats):
            for i, spec in enumerate(cfg.variants):
                result = run_variant(spec, cfg, Path(scratch) / f"turn{r}_variant{i}")
                turns[spec].append(result)
                print(f"  turn {r + 1}, {spec} on {result['device']}: {result['actions']} actions in "
                      f"{result['train_s'] / 60:.1f} min "
                      f"({result['actions_per_hour']:.0f}/h, {result['s_per_action']:.2f} s/action, start-up "
                      f"{result['startup_s']:.0f} s)", flush=True)
    base = statistics.median(t["actions_per_hour"] for t in turns[cfg.variants[0]])
    results = {}
    print(f"{'variant':<48} {'actions/h':>10} {'s/action':>9} {'ratio':>7}")
    for spec, runs in turns.items():
        rate = statistics.median(t["actions_per_hour"] for t in runs)
        results[spec] = dict(turns=runs, actions_per_hour=rate, s_per_action=3600.0 / rate, ratio=rate / base)
        print(f"{spec:<48} {rate:>10.0f} {3600.0 / rate:>9.2f} {rate / base:>7.2f}")
    path = write_report(cfg.out, "training-throughput", {k: str(v) if isinstance(v, Path) else v for k, v in asdict(cfg).items()},
                        results)
    print(f"wrote {path}")
    return results


__all__ = ["DEFAULT_VARIANTS", "TrainingThroughputBenchConfig", "parse_variant", "run", "run_variant"]
