"""The ``maniskill-pnp`` command line: one entry point with a subcommand per job."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _demo(args) -> None:
    from maniskill_pnp.demo import DemoConfig, run_demo

    summary = run_demo(DemoConfig(out=args.out, seed=args.seed))
    print(json.dumps({k: summary[k] for k in ("success", "sim_steps", "planning_time_s", "wall_time_s_incl_rendering")}, indent=2))
    print(f"video: {summary['video']}\nimage strip: {summary['strip']}\nsummary: {args.out / 'summary.json'}")
    if not summary["success"]:
        raise SystemExit("demo pick-and-place failed: " + json.dumps(summary["stages"]))


def _quickstart(args) -> None:
    from maniskill_pnp.quickstart import report

    print(report(_run_job(args, "maniskill_pnp.quickstart", "QuickstartConfig", "quickstart")))


def _export_clutter(args) -> None:
    from maniskill_pnp.agents.clutter_recipe import checkpoint_file, export_weights

    try:
        path = export_weights(checkpoint_file(args.checkpoint), args.out, half=args.half)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"export-clutter: {e}") from e
    print(f"agent: {path} ({path.stat().st_size / 2**20:.1f} MiB)")


def _bench(args) -> None:
    if args.which == "primitives":
        from maniskill_pnp.bench.primitives import PrimitivesBenchConfig, run

        run(PrimitivesBenchConfig(episodes=args.episodes, out=args.out / "primitives.json"))
    elif args.which == "clutter-oracle":
        from maniskill_pnp.bench.clutter_oracle import ClutterOracleBenchConfig, run as run_oracle

        run_oracle(ClutterOracleBenchConfig(scenes=args.episodes, out=args.out / "clutter_oracle.json"))
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


def _bench_pixel_dqn(args) -> None:
    """pixel-memory and decision-cost: the size options given on the command line override the configs' defaults."""
    from maniskill_pnp.bench import pixel_dqn

    given = dict(backbone=args.backbone, num_rotations=args.rotations, heightmap_size=args.heightmap_size,
                 repeats=args.repeats, device=args.device, threads=args.threads)
    given = {k: v for k, v in given.items() if v is not None}
    try:
        if args.which == "pixel-memory":
            if args.num_primitives is not None and len(args.num_primitives) != 1:
                raise ValueError(f"pixel-memory measures one network: give one --num-primitives, got {args.num_primitives}")
            extra = dict(num_primitives=args.num_primitives[0]) if args.num_primitives else {}
            if args.max_rss_gb is not None:
                extra["max_rss_gb"] = args.max_rss_gb
            cfg = pixel_dqn.PixelMemoryBenchConfig(**given, **extra, out=args.out / "pixel_memory.json")
            run = pixel_dqn.run_pixel_memory
        else:
            extra = dict(num_primitives=tuple(args.num_primitives)) if args.num_primitives else {}
            if args.warmup is not None:
                extra["warmup"] = args.warmup
            cfg = pixel_dqn.DecisionCostBenchConfig(**given, **extra, out=args.out / "decision_cost.json")
            run = pixel_dqn.run_decision_cost
    except ValueError as e:
        raise SystemExit(f"bench {args.which}: {e}") from e
    run(cfg)


def _add_pixel_bench_args(bench: argparse.ArgumentParser) -> None:
    """The size options of ``bench pixel-memory`` and ``bench decision-cost``; defaults shown from their configs."""
    import dataclasses

    from maniskill_pnp.agents.pixel_fcn import BACKBONES
    from maniskill_pnp.bench.pixel_dqn import DecisionCostBenchConfig, PixelMemoryBenchConfig

    mem = {f.name: f.default for f in dataclasses.fields(PixelMemoryBenchConfig)}
    dec = {f.name: f.default for f in dataclasses.fields(DecisionCostBenchConfig)}
    pixel = "pixel-memory, decision-cost: "

    def default(name: str) -> str:
        if mem.get(name) == dec.get(name) or name not in mem or name not in dec:
            return f"(default: {mem.get(name, dec.get(name))})"
        return f"(default: {mem[name]} / {dec[name]})"

    bench.add_argument("--backbone", choices=sorted(BACKBONES), default=None,
                       help=pixel + "trunk of the Q networks; pixel-memory takes densenet121 only " + default("backbone"))
    bench.add_argument("--rotations", type=int, default=None, help=pixel + "rotations per primitive " + default("num_rotations"))
    bench.add_argument("--heightmap-size", type=int, default=None,
                       help=pixel + "heightmap pixels per side " + default("heightmap_size"))
    bench.add_argument("--num-primitives", type=int, nargs="+", default=None,
                       help=pixel + "network sizes, each the first N of grasp, left_slide, right_slide; pixel-memory takes "
                       "one N, decision-cost one or more " + default("num_primitives"))
    bench.add_argument("--repeats", type=int, default=None,
                       help=pixel + "training steps per variant / timed decisions and trunk passes " + default("repeats"))
    bench.add_argument("--warmup", type=int, default=None, help="decision-cost: untimed warm-up rounds " + default("warmup")
                       + "; soak: actions before the memory baseline (default: 200)")
    bench.add_argument("--device", default=None, help=pixel + "torch device; auto: CUDA when available " + default("device"))
    bench.add_argument("--threads", type=int, default=None,
                       help=pixel + "CPU threads of torch; 1 keeps timings steady while other jobs share the cores "
                       "(default: torch's own)")
    bench.add_argument("--max-rss-gb", type=float, default=None,
                       help="pixel-memory: kill a variant whose resident memory passes this many GiB and report it as "
                       "exceeded (default: 90%% of the memory available at the start)")


def _train_conveyor(args) -> None:
    from maniskill_pnp.agents.conveyor_recipe import ConveyorConfig, main

    fields = {f: getattr(args, f) for f in _conveyor_fields()}
    try:
        summary = main(ConveyorConfig(**fields))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"train-conveyor: {e}") from e
    print(json.dumps(summary, indent=2))


def _eval_conveyor(args) -> None:
    from maniskill_pnp.agents.conveyor_eval import EvalConfig, run

    try:
        run(EvalConfig(checkpoints=tuple(args.checkpoints), iterations=args.iterations, category_iterations=args.category_iterations,
                       out=args.out, seed=args.seed, curves=tuple(args.curves or ())))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"eval-conveyor: {e}") from e


def _train_clutter(args) -> None:
    import dataclasses

    from maniskill_pnp.agents.clutter_recipe import ClutterConfig, main

    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(ClutterConfig)
                 if f.name != "preset" and getattr(args, f.name, None) is not None}
    try:
        values = ClutterConfig.values_from_file(args.config) if args.config else {}
        preset = args.preset or values.pop("preset", "cpu-small")
        values.pop("preset", None)
        cfg = ClutterConfig.from_preset(preset, **{**values, **overrides})
        summary = main(cfg)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"train-clutter: {e}") from e
    print(json.dumps(summary, indent=2))


def _run_job(args, module: str, config: str, command: str) -> dict:
    """Build the dataclass ``config`` of ``module`` from the parsed options and call the module's ``run``; a missing
    file or a bad value ends the command with one line naming the problem."""
    import dataclasses
    import importlib

    mod = importlib.import_module(module)
    cls = getattr(mod, config)
    try:
        return mod.run(cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(cls)}))
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"{command}: {e}") from e


def _eval_clutter(args) -> None:
    summary = _run_job(args, "maniskill_pnp.agents.clutter_eval", "ClutterEvalConfig", "eval-clutter")
    print(json.dumps(summary["metrics"], indent=2))
    print("\n".join(f"{k}: {v}" for k, v in summary["files"].items()))


def _plot_clutter(args) -> None:
    from maniskill_pnp.agents.clutter_curves import plot_training_curves

    labels = args.labels or [r.name for r in args.runs]
    if len(labels) != len(args.runs):
        raise SystemExit(f"plot-clutter: {len(labels)} labels for {len(args.runs)} runs")
    try:
        summary = plot_training_curves(dict(zip(labels, args.runs)), args.out, window=args.window)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"plot-clutter: {e}") from e
    print(json.dumps(summary, indent=2))
    print(f"curves: {args.out}")


def _add_config_args(parser: argparse.ArgumentParser, config_cls) -> None:
    """One option per field of the config dataclass ``config_cls`` (a ``checkpoint`` field becomes the positional
    argument); help = field docstring. Used by the commands that _run_job runs."""
    import dataclasses

    from maniskill_pnp.agents.run_io import field_docs

    docs = field_docs(config_cls)
    if any(f.name == "checkpoint" for f in dataclasses.fields(config_cls)):
        parser.add_argument("checkpoint", type=Path, help=docs["checkpoint"])
    for f in dataclasses.fields(config_cls):
        if f.name == "checkpoint":
            continue
        help_text = docs[f.name].replace("%", "%%") + " (default: %(default)s)"
        flag = "--" + f.name.replace("_", "-")
        if f.name == "scenarios":
            parser.add_argument(flag, nargs="+", default=list(f.default), help=help_text)
        elif isinstance(f.default, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default, help=help_text)
        else:
            optional = str if "str" in str(f.type) else int  # a None default: the annotation says the type
            kind = Path if f.name == "out" else optional if f.default is None else type(f.default)
            parser.add_argument(flag, type=kind, default=f.default, help=help_text)


def _record_conveyor(args) -> None:
    summary = _run_job(args, "maniskill_pnp.agents.conveyor_video", "ConveyorVideoConfig", "record-conveyor")
    steps = ", ".join(f"{d['phase']} -> {d['action']}" for d in summary["decisions"])
    print(f"{steps}; placed: {summary['placed']}; {summary['frames']} frames")
    print("\n".join(f"{k}: {v}" for k, v in summary["files"].items()))


def _record_clutter(args) -> None:
    summary = _run_job(args, "maniskill_pnp.agents.clutter_video", "ClutterVideoConfig", "record-clutter")
    print(f"{len(summary['decisions'])} decisions, {summary['placed']} of {summary['objects']} objects placed, "
          f"{summary['frames']} frames")
    print("\n".join(f"{k}: {v}" for k, v in summary["files"].items()))


def _add_clutter_train_args(parser: argparse.ArgumentParser) -> None:
    """``--preset`` and one option per ClutterConfig field (default: the preset's value); help = field docstring."""
    import dataclasses

    from maniskill_pnp.agents.clutter_recipe import LOSSES, OPTIMIZERS, PRESETS, TASKS, ClutterConfig
    from maniskill_pnp.agents.run_io import LOGGERS, field_docs
    from maniskill_pnp.agents.pixel_fcn import BACKBONES

    docs = field_docs(ClutterConfig)
    parser.add_argument("--preset", choices=list(PRESETS), default=None,
                        help=docs["preset"] + " (default: the config file's, else cpu-small)")
    parser.add_argument("--config", type=Path, default=None,
                        help="YAML or JSON file of config fields (e.g. a run's config.json); the preset's values, then "
                        "the file's, then the options given here")
    for f in dataclasses.fields(ClutterConfig):
        if f.name == "preset":
            continue
        flag = "--" + f.name.replace("_", "-")
        help_text = docs.get(f.name, "").replace("%", "%%") + " (default: the preset's value)"
        if isinstance(f.default, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=None, help=help_text)
        elif f.name == "out":
            parser.add_argument(flag, type=Path, default=None, help=help_text)
        elif f.name == "pretrained_path":
            parser.add_argument(flag, type=str, default=None, help=help_text)
        elif f.name == "explore_weights":
            parser.add_argument(flag, type=float, nargs="+", default=None, help=help_text)
        else:
            choices = dict(backbone=sorted(BACKBONES), task=list(TASKS), loss=list(LOSSES), optimizer=list(OPTIMIZERS),
                           reward_scheme=["default", "no_slide_reward"], logger=list(LOGGERS)).get(f.name)
            parser.add_argument(flag, type=type(f.default), choices=choices, default=None, help=help_text)


def _conveyor_fields() -> list[str]:
    from maniskill_pnp.agents.conveyor_recipe import ConveyorConfig
    import dataclasses

    return [f.name for f in dataclasses.fields(ConveyorConfig)]


def _add_conveyor_train_args(parser: argparse.ArgumentParser) -> None:
    """One option per ConveyorConfig field; the help text is the field's docstring."""
    import dataclasses

    from maniskill_pnp.agents.conveyor_recipe import ConveyorConfig
    from maniskill_pnp.agents.run_io import LOGGERS, field_docs
    from maniskill_pnp.agents.tabular import ALGORITHMS
    from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, OBJECT_KINDS, REWARD_SCHEMES, SPEEDS

    choices = dict(algorithm=ALGORITHMS, reward_scheme=REWARD_SCHEMES, alignment=ALIGNMENTS, speed=SPEEDS, logger=LOGGERS)
    docs = field_docs(ConveyorConfig)
    for f in dataclasses.fields(ConveyorConfig):
        flag = "--" + f.name.replace("_", "-")
        help_text = docs.get(f.name, "").replace("%", "%%") + " (default: %(default)s)"
        if f.name == "object_kinds":
            parser.add_argument(flag, nargs="+", choices=OBJECT_KINDS, default=list(f.default), help=help_text)
        elif f.name in ("alignment", "speed"):
            parser.add_argument(flag, choices=choices[f.name], default=None, help=help_text)
        elif f.name == "out":
            parser.add_argument(flag, type=Path, default=f.default, help=help_text)
        else:
            parser.add_argument(flag, type=type(f.default), choices=choices.get(f.name), default=f.default, help=help_text)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="maniskill-pnp", description="Learned industrial pick-and-place on ManiSkill.")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="plan and execute a pick-and-place of a cube with OMPL; save a video and image strip")
    demo.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder (default: %(default)s)")
    demo.add_argument("--seed", type=int, default=0, help="episode seed: cube position and yaw (default: %(default)s)")
    demo.set_defaults(func=_demo)

    quick = sub.add_parser("quickstart", help="the README's main job: train and evaluate the conveyor Q-learning agent, "
                           "then film one ClutterGraspSlide-v1 episode of the bundled gs-cpu-small agent (~10 min on 2 cores)")
    from maniskill_pnp.quickstart import QuickstartConfig

    _add_config_args(quick, QuickstartConfig)
    quick.set_defaults(func=_quickstart)

    bench = sub.add_parser("bench", help="run a benchmark; prints numbers and writes JSON")
    bench.add_argument(
        "which", choices=["primitives", "clutter-oracle", "conveyor", "pixel-memory", "decision-cost", "soak",
                          "env-overhead", "collection", "decision-breakdown", "batched-decisions"],
        help="primitives: pick-and-place success, planning and wall time; "
        "clutter-oracle: ClutterGrasp-v1 cleared by the scripted heightmap oracle (10 objects, --episodes scenes); "
        "conveyor: train Q-learning and SARSA with the default config, then the random test cases; "
        "pixel-memory: peak memory and time of one training step of a pixel Q network, DenseNet memory_efficient "
        "on vs off, each in a fresh process; decision-cost: time of one greedy decision / time of its bare trunk "
        "forwards (target <= 1.3); both sized by the options below; soak: --actions random primitive actions on "
        "ClutterGraspSlide-v1, memory growth after --warmup and leaked scene objects across resets; "
        "env-overhead: sim steps/s of ClutterGrasp-v1's primitives (--actions of them) / a bare PickCube-v1; "
        "collection: transitions/s of --task with each of --workers env processes; decision-breakdown: render, "
        "heightmap, network, planning and execution time of --actions greedy decisions of --preset; "
        "batched-decisions: decisions/s of --preset's task on the GPU simulation with each of --num-envs envs "
        "(--actions timed steps each) / the one-env CPU path",
    )
    bench.add_argument("--episodes", type=int, default=20, help="seeded episodes (primitives) or scenes (clutter-oracle) (default: %(default)s)")
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
    bench.add_argument("--preset", default="gs-cpu-small",
                       help="decision-breakdown, batched-decisions: clutter recipe preset (default: %(default)s)")
    bench.add_argument("--num-envs", type=int, nargs="+", default=[1, 16],
                       help="batched-decisions: env counts run on the GPU (default: 1 16)")
    bench.add_argument("--iterations", type=int, default=50, help="conveyor: iterations per random test case (default: %(default)s)")
    _add_pixel_bench_args(bench)
    bench.set_defaults(func=_bench)

    train = sub.add_parser("train-conveyor", help="train tabular Q-learning or SARSA on ConveyorProximity-v1 (thesis ch. 4)")
    _add_conveyor_train_args(train)
    train.set_defaults(func=_train_conveyor)

    clutter = sub.add_parser("train-clutter", help="train a pixelwise DQN agent: grasping on ClutterGrasp-v1 (thesis part II, "
                             "presets cpu-small, thesis) or G&S on ClutterGraspSlide-v1 (part III, presets gs-*)")
    _add_clutter_train_args(clutter)
    clutter.set_defaults(func=_train_clutter)

    ev = sub.add_parser("eval-conveyor", help="greedy evaluation of saved conveyor Q-tables: per-category tables, random test cases 1-5, curves")
    ev.add_argument("checkpoints", nargs="+", type=Path, help="qtable.pt files (or run folders holding one) to evaluate")
    ev.add_argument("--iterations", type=int, default=50, help="episodes per random test case (default: %(default)s)")
    ev.add_argument("--category-iterations", type=int, default=0,
                    help="episodes per (object kind, alignment, speed) cell of the per-category tables; 0 skips them (default: %(default)s)")
    ev.add_argument("--out", type=Path, default=Path("runs/conveyor_eval"), help="folder for tables (Markdown, CSV, JSON) and plots (default: %(default)s)")
    ev.add_argument("--seed", type=int, default=12345, help="seed of the test-case draws and episodes (default: %(default)s)")
    ev.add_argument("--curves", nargs="*", type=Path,
                    help="run folders whose CSV logs to plot as learning curves (default: the checkpoints' run folders)")
    ev.set_defaults(func=_eval_conveyor)

    evc = sub.add_parser("eval-clutter", help="greedy evaluation of a clutter DQN checkpoint per scenario: DESIGN.md metrics, "
                         "Table IX (Markdown, CSV), Q-map figure")
    from maniskill_pnp.agents.clutter_eval import ClutterEvalConfig
    from maniskill_pnp.agents.clutter_video import ClutterVideoConfig

    _add_config_args(evc, ClutterEvalConfig)
    evc.set_defaults(func=_eval_clutter)

    rec = sub.add_parser("record-clutter", help="film one greedy episode of a clutter DQN checkpoint: MP4 of the arm's "
                         "motion beside each decision, and a strip of heightmap -> Q map -> action per decision")
    _add_config_args(rec, ClutterVideoConfig)
    rec.set_defaults(func=_record_clutter)

    from maniskill_pnp.agents.conveyor_video import ConveyorVideoConfig

    recc = sub.add_parser("record-conveyor", help="film one greedy ConveyorProximity-v1 episode of a saved Q-table: the belt, "
                          "the sensed state and the planned pre-pick, grasp and place, as MP4")
    _add_config_args(recc, ConveyorVideoConfig)
    recc.set_defaults(func=_record_conveyor)

    export = sub.add_parser("export-clutter", help="a shareable agent from a clutter DQN checkpoint: config and network "
                            "weights only (float16), loadable by eval-clutter and record-clutter")
    export.add_argument("checkpoint", type=Path, help="checkpoint.pt of a train-clutter run, or the run folder holding it")
    export.add_argument("--out", type=Path, required=True, help="file to write (e.g. my-agent.pt)")
    export.add_argument("--half", action=argparse.BooleanOptionalAction, default=True,
                        help="store floating-point weights as float16 (default: %(default)s)")
    export.set_defaults(func=_export_clutter)

    plot = sub.add_parser("plot-clutter", help="training curves (grasp success, success rate) of clutter runs in one PNG, "
                          "with first / last window numbers")
    plot.add_argument("runs", nargs="+", type=Path, help="run folders of train-clutter (each holds actions.csv)")
    plot.add_argument("--labels", nargs="+", help="legend label per run (default: the run folder names)")
    plot.add_argument("--window", type=int, default=50, help="trailing window in actions (default: %(default)s)")
    plot.add_argument("--out", type=Path, default=Path("runs/clutter_curves.png"), help="PNG to write (default: %(default)s)")
    plot.set_defaults(func=_plot_clutter)
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
