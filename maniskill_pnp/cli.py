"""The ``maniskill-pnp`` command line: one entry point with a subcommand per job."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import types
import typing
from pathlib import Path


def _demo(args) -> None:
    from maniskill_pnp.demo import DemoConfig, run_demo

    cfg = DemoConfig(**_config_values(args, DemoConfig))
    summary = run_demo(cfg)
    print(json.dumps({k: summary[k] for k in ("success", "sim_steps", "planning_time_s", "wall_time_s_incl_rendering")}, indent=2))
    print(f"video: {summary['video']}\nimage strip: {summary['strip']}\nsummary: {cfg.out / 'summary.json'}")
    if not summary["success"]:
        raise SystemExit("demo pick-and-place failed: " + json.dumps(summary["stages"]))


def _quickstart(args) -> None:
    from maniskill_pnp.quickstart import report

    print(report(_run_job(args, "maniskill_pnp.quickstart", "QuickstartConfig", "quickstart")))


def _export_clutter(args) -> None:
    from maniskill_pnp.agents.pixel.checkpoint import checkpoint_file, export_weights

    try:
        acting = {k: v for k, v in dict(slide_margin=args.slide_margin, mask_grasp_fit=args.mask_grasp_fit,
                                       mask_fit_scale=args.mask_fit_scale, mask_keep_in=args.mask_keep_in,
                                       mask_reach=args.mask_reach).items()
                  if v is not None}
        path = export_weights(checkpoint_file(args.checkpoint), args.out, half=args.half, **acting)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"export-clutter: {e}") from e
    print(f"agent: {path} ({path.stat().st_size / 2**20:.1f} MiB)")


def _check_scene(args) -> None:
    from maniskill_pnp.scenes.grasp_feasibility import check_scene_file, format_report
    from maniskill_pnp.scenes.scene_file import SceneFileError

    from maniskill_pnp.agents.pixel.factories import FILE_SCENARIOS, scenario_layout_files

    files = []
    for path in args.files:  # a scenario's name stands for its scene files
        named = str(path) in FILE_SCENARIOS and not path.exists()
        files.extend(scenario_layout_files(str(path)) if named else [path])
    total = locked = half_locked = 0
    for path in files:
        try:
            grasps = check_scene_file(path, yaw_step_deg=args.yaw_step, position_step=args.position_step / 1000)
        except (FileNotFoundError, SceneFileError, ValueError) as e:
            raise SystemExit(f"check-scene: {e}") from e
        print(format_report(str(path), grasps))
        scene_locked = sum(g.locked for g in grasps)
        total += len(grasps)
        locked += scene_locked
        half_locked += 2 * scene_locked >= len(grasps)
    if len(files) > 1:
        print(f"all {len(files)} scenes: {total} objects, {locked} locked; {half_locked} scenes with at least half of "
              "their objects locked")


def _strip_options(argv: list[str], names: tuple[str, ...]) -> list[str]:
    """``argv`` without the options ``names`` (each with its one value, as ``--name V`` or ``--name=V``)."""
    out, skip = [], False
    for token in argv:
        if skip:
            skip = False
        elif token in names:
            skip = True
        elif not any(token.startswith(f"{n}=") for n in names):
            out.append(token)
    return out


def _bench_against(args) -> None:
    """``bench WHICH ... --against REF``: the same benchmark on revision REF and on this checkout, in turns."""
    from maniskill_pnp.bench.against import AgainstConfig, run_against

    tokens = _strip_options(args.raw_argv[args.raw_argv.index("bench") + 1 :], ("--against", "--rounds", "--out"))
    tokens.remove(args.which)
    try:
        cfg = AgainstConfig(args.which, tuple(tokens), args.against, rounds=args.rounds, out=args.out / f"against_{args.which}")
        run_against(cfg)
    except ValueError as e:
        raise SystemExit(f"bench {args.which} --against {args.against}: {e}") from e


def _bench(args) -> None:
    if args.against is not None:
        _bench_against(args)
    elif args.which == "primitives":
        from maniskill_pnp.bench.primitives import PrimitivesBenchConfig, run

        run(PrimitivesBenchConfig(episodes=args.episodes, out=args.out / "primitives.json"))
    elif args.which == "scene-counts":
        from maniskill_pnp.bench.scene_counts import SceneCountsBenchConfig, run as run_counts

        try:
            cfg = SceneCountsBenchConfig(scenes=_given(args.scenes, 100), out=args.out / "scene_counts.json")
        except ValueError as e:
            raise SystemExit(f"bench scene-counts: {e}") from e
        run_counts(cfg)
    elif args.which == "clutter-oracle":
        from maniskill_pnp.bench.clutter_oracle import ClutterOracleBenchConfig, run as run_oracle

        try:
            cfg = ClutterOracleBenchConfig(scenes=args.episodes, scenario=args.scenario, guard_force=args.guard_force,
                                           oracle=args.oracle, out=args.out / "clutter_oracle.json")
            run_oracle(cfg)
        except ValueError as e:
            raise SystemExit(f"bench clutter-oracle: {e}") from e
    elif args.which == "conveyor":
        from maniskill_pnp.bench.conveyor import ConveyorBenchConfig, run as run_conveyor

        run_conveyor(ConveyorBenchConfig(iterations=args.iterations, steps=args.steps, out=args.out))
    elif args.which in ("pixel-memory", "decision-cost"):
        _bench_pixel_dqn(args)
    elif args.which == "soak":
        from maniskill_pnp.bench.soak import SoakBenchConfig, run as run_soak

        try:
            cfg = SoakBenchConfig(actions=_given(args.actions, 2000), warmup=200 if args.warmup is None else args.warmup,
                                  out=args.out / "soak.json")
        except ValueError as e:
            raise SystemExit(f"bench soak: {e}") from e
        run_soak(cfg)
    elif args.which == "training-throughput":
        from maniskill_pnp.bench.training_throughput import TrainingThroughputBenchConfig, run as run_throughput

        try:
            given = _config_values(args, TrainingThroughputBenchConfig, only=THROUGHPUT_BENCH_OPTIONS, given_only=True)
            cfg = TrainingThroughputBenchConfig(**given, out=args.out / "training_throughput.json")
        except ValueError as e:
            raise SystemExit(f"bench training-throughput: {e}") from e
        run_throughput(cfg)
    else:
        _bench_scale(args)


def _given(value, default):
    """``value`` unless the option was left out (None)."""
    return default if value is None else value


def _bench_scale(args) -> None:
    """``bench env-overhead``, ``collection``, ``decision-breakdown`` and ``batched-decisions`` (maniskill_pnp.bench.scale)."""
    from maniskill_pnp.bench import scale

    try:
        if args.which == "env-overhead":
            cfg = scale.EnvOverheadBenchConfig(actions=_given(args.actions, 8), out=args.out / "env_overhead.json")
            run = scale.run_env_overhead
        elif args.which == "collection":
            cfg = scale.CollectionBenchConfig(task=args.task, workers=tuple(args.workers), frames=args.frames,
                                              out=args.out / f"collection_{args.task}.json")
            run = scale.run_collection
        elif args.which == "batched-decisions":
            cfg = scale.BatchedDecisionsBenchConfig(preset=args.preset, num_envs=tuple(args.num_envs),
                                                    steps=_given(args.actions, 3), out=args.out / "batched_decisions.json")
            run = scale.run_batched_decisions
        else:
            cfg = scale.DecisionBreakdownBenchConfig(preset=args.preset, decisions=_given(args.actions, 10),
                                                     out=args.out / "decision_breakdown.json")
            run = scale.run_decision_breakdown
    except ValueError as e:
        raise SystemExit(f"bench {args.which}: {e}") from e
    run(cfg)


#: The sizing options of ``bench pixel-memory`` and ``bench decision-cost`` (fields of their configs; ``warmup`` is
#: soak's too).
#: The scenarios that play scene files (agents.pixel.factories.FILE_SCENARIOS, written out here so that building the
#: parser imports no torch; a test keeps the two equal).
FILE_SCENARIO_NAMES = ("hard", "hard_unseen", "anywhere")
PIXEL_BENCH_OPTIONS = ("backbone", "num_rotations", "heightmap_size", "num_primitives", "repeats", "warmup", "device",
                       "threads", "max_rss_gb")

#: The options of ``bench training-throughput`` (fields of its config).
THROUGHPUT_BENCH_OPTIONS = ("variants", "minutes", "repeats", "updates_per_step")


def _bench_pixel_dqn(args) -> None:
    """pixel-memory and decision-cost: the size options given on the command line override the configs' defaults."""
    from maniskill_pnp.bench import pixel_dqn

    memory = args.which == "pixel-memory"
    config = pixel_dqn.PixelMemoryBenchConfig if memory else pixel_dqn.DecisionCostBenchConfig
    try:
        given = _config_values(args, config, only=PIXEL_BENCH_OPTIONS, given_only=True)
        if memory and "num_primitives" in given:
            if len(given["num_primitives"]) != 1:
                raise ValueError(f"pixel-memory measures one network: give one --num-primitives, got {given['num_primitives']}")
            given["num_primitives"] = given["num_primitives"][0]
        cfg = config(**given, out=args.out / ("pixel_memory.json" if memory else "decision_cost.json"))
    except ValueError as e:
        raise SystemExit(f"bench {args.which}: {e}") from e
    (pixel_dqn.run_pixel_memory if memory else pixel_dqn.run_decision_cost)(cfg)


def _train_conveyor(args) -> None:
    from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, main

    try:
        summary = main(ConveyorConfig(**_config_values(args, ConveyorConfig)))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"train-conveyor: {e}") from e
    print(json.dumps(summary, indent=2))


def _eval_conveyor(args) -> None:
    _run_job(args, "maniskill_pnp.agents.tabular.evaluate", "EvalConfig", "eval-conveyor")


def _train_clutter(args) -> None:
    from maniskill_pnp.agents.pixel.config import ClutterConfig
    from maniskill_pnp.agents.pixel.recipe import main

    try:
        values = ClutterConfig.values_from_file(args.config) if args.config else {}
        preset = args.preset or values.get("preset", "cpu-small")
        values.pop("preset", None)
        overrides = _config_values(args, ClutterConfig, given_only=True)
        overrides.pop("preset", None)
        summary = main(ClutterConfig.from_preset(preset, **{**values, **overrides}))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"train-clutter: {e}") from e
    print(json.dumps(summary, indent=2))


def _presets_epilog(descriptions: dict[str, str]) -> str:
    """The end of ``train-clutter --help``: each preset with its one line, and where the other recipes are."""
    width = max(map(len, descriptions)) + 2
    lines = [f"  {name:<{width}}{text}" for name, text in descriptions.items()]
    return "\n".join(["presets (--preset NAME):", *lines, "",
                      "The recipes of single experiments (the hard-clutter series gs-cpu-equi-hard, -keep, -fine, -each;",
                      "the Part II comparisons; more thesis-size comparisons) are config files in the repository's",
                      "docs/configs/: --config docs/configs/NAME.yaml trains one, in a run folder named as before."])


def _run_job(args, module: str, config: str, command: str) -> dict:
    """Build the dataclass ``config`` of ``module`` from the parsed options and call the module's ``run``; a missing
    file or a bad value ends the command with one line naming the problem."""
    import importlib

    mod = importlib.import_module(module)
    cls = getattr(mod, config)
    try:
        return mod.run(cls(**_config_values(args, cls)))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"{command}: {e}") from e


def _eval_clutter(args) -> None:
    summary = _run_job(args, "maniskill_pnp.agents.pixel.evaluate", "ClutterEvalConfig", "eval-clutter")
    print(json.dumps(summary["metrics"], indent=2))
    print("\n".join(f"{k}: {v}" for k, v in summary["files"].items()))


def _benchmark(args) -> None:
    from maniskill_pnp.bench.protocol import BenchmarkConfig, run

    try:
        result = run(BenchmarkConfig(**_config_values(args, BenchmarkConfig)))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"benchmark: {e}") from e
    if result["failed"]:
        raise SystemExit(f"benchmark: {len(result['failed'])} part(s) failed: {', '.join(result['failed'])}; "
                         "run the command again to retry them")


def _compare_clutter(args) -> None:
    from maniskill_pnp.agents.pixel.evaluate import comparison_table

    try:
        table = comparison_table(args.eval_a, args.eval_b, plot=args.plot)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"compare-clutter: {e}") from e
    print(table)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(table + "\n")
        print(f"wrote {args.out}")


def _plot_clutter(args) -> None:
    from maniskill_pnp.agents.pixel.curves import plot_training_curves

    labels = args.labels or [r.name for r in args.runs]
    if len(labels) != len(args.runs):
        raise SystemExit(f"plot-clutter: {len(labels)} labels for {len(args.runs)} runs")
    try:
        summary = plot_training_curves(dict(zip(labels, args.runs)), args.out, window=args.window)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"plot-clutter: {e}") from e
    print(json.dumps(summary, indent=2))
    print(f"curves: {args.out}")


def _record_conveyor(args) -> None:
    summary = _run_job(args, "maniskill_pnp.agents.tabular.video", "ConveyorVideoConfig", "record-conveyor")
    steps = ", ".join(f"{d['phase']} -> {d['action']}" for d in summary["decisions"])
    print(f"{steps}; placed: {summary['placed']}; {summary['frames']} frames")
    print("\n".join(f"{k}: {v}" for k, v in summary["files"].items()))


def _record_clutter(args) -> None:
    summary = _run_job(args, "maniskill_pnp.agents.pixel.video", "ClutterVideoConfig", "record-clutter")
    print(f"{len(summary['decisions'])} decisions, {summary['placed']} of {summary['objects']} objects placed, "
          f"{summary['frames']} frames")
    print("\n".join(f"{k}: {v}" for k, v in summary["files"].items()))


# ----------------------------------------------------------------------------- options from config dataclasses
def add_config_options(parser: argparse.ArgumentParser, configs, *, only=None, skip=(), positional=(), flags=None,
                       choices=None, unset: str | bool = False) -> None:
    """One option per field of a config dataclass: how every config-driven command gets its options.

    The option of field ``name`` is ``--name-with-dashes`` (or ``--`` + ``flags[name]``), stored as ``args.name``; its
    help is the field's description (:func:`~maniskill_pnp.agents.run_io.field_docs`); its form follows the field's
    annotation: a ``bool`` is an on/off switch (``--x`` / ``--no-x``), a ``tuple[T, ...]`` takes several values
    (``nargs="+"``, or ``"*"`` when the default is empty), ``T | None`` takes a ``T``. A field without a default, or
    named in ``positional``, is a positional argument.

    Args:
        configs: The config dataclass, or ``{label: dataclass}`` when the options feed several configs (the fields of
            one name share one option, whose help gives each config's text and default after its label).
        only, skip: The fields to offer (default: all; with several configs, a collection or ``{label: fields}``) /
            to leave out.
        flags: ``{field: flag name}`` for options named otherwise than their field.
        choices: ``{field: valid values}`` (checked by argparse, listed in the help).
        unset: False: an option left out gives the field's default (shown in the help). True, or a text: every
            option defaults to None, so only the options given override what else supplies the values (a preset, a
            file, the config's own default); the help shows the configs' defaults, or the text (e.g. "the preset's
            value").
    """
    from maniskill_pnp.agents.run_io import field_docs

    labelled = configs if isinstance(configs, dict) else {None: configs}
    options: dict[str, list] = {}  # field name -> [(label, field, annotation, description)], in the configs' order
    for label, cls in labelled.items():
        docs, hints = field_docs(cls), typing.get_type_hints(cls)
        wanted = only.get(label) if isinstance(only, dict) else only
        for f in dataclasses.fields(cls):
            if (wanted is None or f.name in wanted) and f.name not in skip:
                options.setdefault(f.name, []).append((label, f, hints[f.name], docs.get(f.name, "")))
    for name, entries in options.items():
        kind, many = _option_type([hint for _, _, hint, _ in entries])
        first = entries[0][1]
        has_default = first.default is not dataclasses.MISSING or first.default_factory is not dataclasses.MISSING
        default = _field_default(first) if has_default else None
        positional_arg = not has_default or name in positional
        kwargs = dict(choices=(choices or {}).get(name))
        if kind is bool:
            kwargs = dict(action=argparse.BooleanOptionalAction)
        else:
            kwargs["type"] = kind
            if many:
                kwargs["nargs"] = "*" if not positional_arg and not default else "+"
        if positional_arg:
            parser.add_argument(name, help=_escape(entries[0][3]), **kwargs)
            continue
        if unset is False:
            value = list(default) if isinstance(default, tuple) else default
            shown = "%(default)s"
        else:
            value = None
            shown = unset if isinstance(unset, str) else ""
        flag = (flags or {}).get(name, name)
        if flag != name and kind is not bool:
            kwargs["metavar"] = flag.upper()
        parser.add_argument("--" + flag.replace("_", "-"), dest=name, default=value, help=_help_text(entries, shown),
                            **kwargs)


def _option_type(hints: list) -> tuple[type, bool]:
    """The value type of an option whose fields are annotated ``hints``, and whether it takes several values."""
    kind, many = None, False
    for hint in hints:
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if typing.get_origin(hint) in (typing.Union, types.UnionType):
            hint, args = args[0], list(typing.get_args(args[0]))
        if typing.get_origin(hint) is tuple:
            hint, many = args[0], True
        kind = kind or hint
    return kind, many


def _field_default(f: dataclasses.Field):
    return f.default_factory() if f.default is dataclasses.MISSING else f.default


def _escape(text: str) -> str:
    return text.replace("%", "%%")


def _help_text(entries: list, shown: str | None) -> str:
    """The help of one option: each config's description and default (``shown``, or "" for the field's own), the
    configs with the same text and default under one label list."""
    parts: dict[tuple[str, str], list] = {}
    for label, f, _, doc in entries:
        default = _escape(str(_field_default(f))) if shown == "" else shown
        parts.setdefault((_escape(doc), default), []).append(label)
    texts = [(f"{', '.join(labels)}: " if labels != [None] else "") + doc + (f" (default: {default})" if default else "")
             for (doc, default), labels in parts.items()]
    return "; ".join(texts)


def _config_values(args, config, *, only=None, given_only: bool = False) -> dict:
    """The values of ``config``'s fields among the parsed options (only those given, with ``given_only``)."""
    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(config)
              if hasattr(args, f.name) and (only is None or f.name in only)}
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}  # several values: the fields' tuples
    return {k: v for k, v in values.items() if v is not None} if given_only else values


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="maniskill-pnp", description="Learned industrial pick-and-place on ManiSkill.")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="plan and execute a pick-and-place of a cube with OMPL; save a video and image strip")
    from maniskill_pnp.demo import DemoConfig

    add_config_options(demo, DemoConfig)
    demo.set_defaults(func=_demo)

    quick = sub.add_parser("quickstart", help="the README's main job: train and evaluate the conveyor Q-learning agent, "
                           "then film one ClutterGraspSlide-v1 episode of the bundled gs-cpu-equi-fit agent (~10 min on 2 cores)")
    from maniskill_pnp.quickstart import QuickstartConfig

    add_config_options(quick, QuickstartConfig)
    quick.set_defaults(func=_quickstart)

    bench = sub.add_parser("bench", help="run a benchmark; prints numbers and writes JSON")
    bench.add_argument(
        "which", choices=["primitives", "clutter-oracle", "conveyor", "pixel-memory", "decision-cost", "soak",
                          "env-overhead", "collection", "decision-breakdown", "batched-decisions", "training-throughput", "scene-counts"],
        help="primitives: pick-and-place success, planning and wall time; "
        "clutter-oracle: clutter cleared by a scripted --oracle (10 objects, --episodes scenes); "
        "conveyor: train Q-learning and SARSA with the default config, then the random test cases; "
        "pixel-memory: peak memory and time of one training step of a pixel Q network, DenseNet memory_efficient "
        "on vs off, each in a fresh process; decision-cost: time of one greedy decision / time of its bare trunk "
        "forwards (target <= 1.3); both sized by the options below; soak: --actions random primitive actions on "
        "ClutterGraspSlide-v1, memory growth after --warmup and leaked scene objects across resets; "
        "env-overhead: sim steps/s of ClutterGrasp-v1's primitives (--actions of them) / a bare PickCube-v1; "
        "collection: transitions/s of --task with each of --workers env processes; decision-breakdown: render, "
        "heightmap, network, planning and execution time of --actions greedy decisions of --preset; "
        "batched-decisions: decisions/s of --preset's task on the GPU simulation with each of --num-envs envs "
        "(--actions timed steps each) / the one-env CPU path; training-throughput: training actions per hour of each of "
        "--variants (PRESET[,FIELD=VALUE...]), trained in turn for --minutes each, ratios against the first; scene-counts: "
        "objects each density's seeded scenes start with (--scenes per density), with and without the re-drop of "
        "objects that settle outside the workspace",
    )
    bench.add_argument("--episodes", type=int, default=20, help="seeded episodes (primitives) or scenes (clutter-oracle) (default: %(default)s)")
    bench.add_argument("--scenes", type=int, default=None, help="scene-counts: seeded scenes per density (default: 100)")
    bench.add_argument("--out", type=Path, default=Path("runs/bench"), help="folder for the JSON report (default: %(default)s)")
    bench.add_argument("--steps", type=int, default=3000, help="conveyor: training steps of each agent (default: %(default)s)")
    bench.add_argument("--actions", type=int, default=None,
                       help="soak: primitive actions in all (default: 2000); env-overhead: primitives timed (default: 8); "
                       "decision-breakdown: decisions timed (default: 10); batched-decisions: timed steps per env count "
                       "(default: 3)")
    bench.add_argument("--task", choices=["conveyor", "clutter", "clutter-slide"], default="conveyor",
                       help="collection: the task collected from (default: %(default)s)")
    bench.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                       help="collection: worker counts measured, ratios against the first (default: 1 2)")
    bench.add_argument("--frames", type=int, default=24, help="collection: timed transitions per worker count (default: %(default)s)")
    from maniskill_pnp.bench.scale import DEFAULT_PRESET

    bench.add_argument("--preset", default=DEFAULT_PRESET,
                       help="decision-breakdown, batched-decisions: clutter recipe preset (default: %(default)s)")
    bench.add_argument("--num-envs", type=int, nargs="+", default=[1, 16],
                       help="batched-decisions: env counts run on the GPU (default: 1 16)")
    bench.add_argument("--scenario", choices=FILE_SCENARIO_NAMES, default=None,
                       help="clutter-oracle: play the scene files of the hard test set or of the held-out families "
                            "instead of random clutter")
    bench.add_argument("--guard-force", type=float, default=None,
                       help="clutter-oracle: guarded grasps, descents stop on an upward contact force above this (N)")
    bench.add_argument("--oracle", choices=["heightmap", "grasp-only", "slide-then-grasp"], default="heightmap",
                       help="clutter-oracle: the heightmap oracle (ClutterGrasp-v1), or the oracles that see the objects' "
                       "shapes: grasps where the grasp check finds one, and slides that free a locked object where it "
                       "finds none (ClutterGraspSlide-v1) (default: %(default)s)")
    bench.add_argument("--against", metavar="REF", default=None,
                       help="run the benchmark on git revision REF of this checkout and on the checkout itself, in turns "
                       "(--rounds each), and print both sides' headline figures and their ratio")
    bench.add_argument("--rounds", type=int, default=3, help="--against: turns of each side (default: %(default)s)")
    bench.add_argument("--iterations", type=int, default=50, help="conveyor: iterations per random test case (default: %(default)s)")
    from maniskill_pnp.agents.pixel.config import CHOICES as CLUTTER_CHOICES, ClutterConfig, presets
    from maniskill_pnp.bench.pixel_dqn import DecisionCostBenchConfig, PixelMemoryBenchConfig
    from maniskill_pnp.bench.soak import SoakBenchConfig
    from maniskill_pnp.bench.training_throughput import TrainingThroughputBenchConfig

    add_config_options(bench, {"pixel-memory": PixelMemoryBenchConfig, "decision-cost": DecisionCostBenchConfig,
                               "soak": SoakBenchConfig, "training-throughput": TrainingThroughputBenchConfig},
                       only={"pixel-memory": PIXEL_BENCH_OPTIONS, "decision-cost": PIXEL_BENCH_OPTIONS, "soak": ("warmup",),
                             "training-throughput": THROUGHPUT_BENCH_OPTIONS},
                       flags=dict(num_rotations="rotations"), choices=dict(backbone=CLUTTER_CHOICES["backbone"]), unset=True)
    bench.set_defaults(func=_bench)

    train = sub.add_parser("train-conveyor", help="train tabular Q-learning or SARSA on ConveyorProximity-v1 (thesis ch. 4)")
    from maniskill_pnp.agents.run_io import LOGGERS
    from maniskill_pnp.agents.tabular.qtable import ALGORITHMS
    from maniskill_pnp.agents.tabular.recipe import ConveyorConfig
    from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, OBJECT_KINDS, REWARD_SCHEMES, SPEEDS

    add_config_options(train, ConveyorConfig, choices=dict(algorithm=ALGORITHMS, reward_scheme=REWARD_SCHEMES, alignment=ALIGNMENTS,
                                                           speed=SPEEDS, object_kinds=OBJECT_KINDS, logger=LOGGERS))
    train.set_defaults(func=_train_conveyor)

    from maniskill_pnp.agents.pixel.config import preset_descriptions

    clutter = sub.add_parser("train-clutter", help="train a pixelwise DQN agent: grasping on ClutterGrasp-v1 (thesis part II; "
                             "its default agent: --preset cpu-equi) or G&S on ClutterGraspSlide-v1 (part III; the bundled "
                             "agent's recipe: --preset gs-cpu-equi-fit)", epilog=_presets_epilog(preset_descriptions()),
                             formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_options(clutter, ClutterConfig, only=("preset",), choices=dict(preset=list(presets())),
                       unset="the config file's, else cpu-small")
    clutter.add_argument("--config", type=Path, default=None,
                         help="YAML or JSON file of config fields (e.g. a run's config.json, or one of docs/configs/); "
                         "its base preset's values (its 'preset'), then the file's, then the options given here")
    add_config_options(clutter, ClutterConfig, skip=("preset",), choices=CLUTTER_CHOICES, unset="the preset's value")
    clutter.set_defaults(func=_train_clutter)

    ev = sub.add_parser("eval-conveyor", help="greedy evaluation of saved conveyor Q-tables: per-category tables, random test cases 1-5, curves")
    from maniskill_pnp.agents.tabular.evaluate import EvalConfig

    add_config_options(ev, EvalConfig, positional=("checkpoints",))
    ev.set_defaults(func=_eval_conveyor)

    evc = sub.add_parser("eval-clutter", help="greedy evaluation of a clutter DQN checkpoint per scenario: success rate, "
                         "grasp success, completion, action efficiency; Table IX (Markdown, CSV), Q-map figure")
    from maniskill_pnp.agents.pixel.evaluate import ClutterEvalConfig
    from maniskill_pnp.agents.pixel.video import ClutterVideoConfig

    add_config_options(evc, ClutterEvalConfig)
    evc.set_defaults(func=_eval_clutter)

    bm = sub.add_parser("benchmark", help="the whole evaluation protocol of one or more agents in one command, both "
                        "cores, resumable: Table IX per scenario, the hard sets guarded, G&S - grasp-only paired per "
                        "scene, lost objects by cause, figures and the worst episodes' decisions in one report folder")
    from maniskill_pnp.bench.protocol import BenchmarkConfig

    add_config_options(bm, BenchmarkConfig, positional=("agents",))
    bm.set_defaults(func=_benchmark)

    cmp = sub.add_parser("compare-clutter", help="paired per-scene differences of two eval-clutter runs on the same "
                         "scenes (e.g. a G&S agent against its --grasp-only restriction): A - B of every metric, ± its "
                         "standard error, per scenario")
    cmp.add_argument("eval_a", type=Path, help="eval-clutter output folder (or its eval_summary.json) of A")
    cmp.add_argument("eval_b", type=Path, help="eval-clutter output folder (or its eval_summary.json) of B")
    cmp.add_argument("--out", type=Path, default=None, help="also write the Markdown table to this file")
    cmp.add_argument("--plot", type=Path, default=None, help="also draw the differences per scenario (± 2 SE) as this PNG")
    cmp.set_defaults(func=_compare_clutter)

    rec = sub.add_parser("record-clutter", help="film one greedy episode of a clutter DQN checkpoint: MP4 of the arm's "
                         "motion beside each decision, and a strip of heightmap -> Q map -> action per decision")
    add_config_options(rec, ClutterVideoConfig)
    rec.set_defaults(func=_record_clutter)

    from maniskill_pnp.agents.tabular.video import ConveyorVideoConfig

    recc = sub.add_parser("record-conveyor", help="film one greedy ConveyorProximity-v1 episode of a saved Q-table: the belt, "
                          "the sensed state and the planned pre-pick, grasp and place, as MP4")
    add_config_options(recc, ConveyorVideoConfig)
    recc.set_defaults(func=_record_conveyor)

    export = sub.add_parser("export-clutter", help="a shareable agent from a clutter DQN checkpoint: config and network "
                            "weights only (float16), loadable by eval-clutter and record-clutter")
    export.add_argument("checkpoint", type=Path, help="checkpoint.pt of a train-clutter run, or the run folder holding it")
    export.add_argument("--out", type=Path, required=True, help="file to write (e.g. my-agent.pt)")
    export.add_argument("--half", action=argparse.BooleanOptionalAction, default=True,
                        help="store floating-point weights as float16 (default: %(default)s)")
    export.add_argument("--slide-margin", type=float, default=None, help="the agent slides only where a slide's Q "
                        "beats the best grasp's by more than this (default: the run's own)")
    export.add_argument("--mask-grasp-fit", action=argparse.BooleanOptionalAction, default=None,
                        help="the agent grasps only where a grasp fits the heightmap (default: as the run was trained)")
    export.add_argument("--mask-fit-scale", type=int, default=None, help="test the grasp fit on a heightmap this many "
                        "times finer than the network's (needs the fit test; default: as the run was trained)")
    export.add_argument("--mask-keep-in", action=argparse.BooleanOptionalAction, default=None,
                        help="the agent slides only where the push keeps what it carries on the heightmap "
                        "(default: as the run was trained)")
    export.add_argument("--mask-reach", action=argparse.BooleanOptionalAction, default=None,
                        help="the agent acts only where the arm reaches (default: as the run was trained)")
    export.set_defaults(func=_export_clutter)

    check = sub.add_parser("check-scene", help="which objects of scene files no top-down grasp can take (locked): "
                           "per scene its objects, locked count and feasible grasps per object")
    check.add_argument("files", type=Path, nargs="+", help="scene files (YAML or JSON), or the name of a scenario "
                       f"that plays scene files ({', '.join(FILE_SCENARIO_NAMES)}) for all of its files")
    check.add_argument("--yaw-step", type=float, default=15.0, help="jaw orientations every this many degrees over 180 "
                       "(default: %(default)s)")
    check.add_argument("--position-step", type=float, default=3.0, help="grasp positions every this many mm over each "
                       "object (default: %(default)s)")
    check.set_defaults(func=_check_scene)

    plot = sub.add_parser("plot-clutter", help="training curves (grasp success, success rate) of clutter runs in one PNG, "
                          "with first / last window numbers")
    plot.add_argument("runs", nargs="+", type=Path, help="run folders of train-clutter (each holds actions.csv)")
    plot.add_argument("--labels", nargs="+", help="legend label per run (default: the run folder names)")
    plot.add_argument("--window", type=int, default=50, help="trailing window in actions (default: %(default)s)")
    plot.add_argument("--out", type=Path, default=Path("runs/clutter_curves.png"), help="PNG to write (default: %(default)s)")
    plot.set_defaults(func=_plot_clutter)
    return parser


def main(argv: list[str] | None = None) -> None:
    raw = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(raw)
    args.raw_argv = raw
    args.func(args)


if __name__ == "__main__":
    main()
