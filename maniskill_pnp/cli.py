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


def _bench(args) -> None:
    if args.which == "primitives":
        from maniskill_pnp.bench.primitives import PrimitivesBenchConfig, run

        run(PrimitivesBenchConfig(episodes=args.episodes, out=args.out / "primitives.json"))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="maniskill-pnp", description="Learned industrial pick-and-place on ManiSkill.")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="plan and execute a pick-and-place of a cube with OMPL; save a video and image strip")
    demo.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder (default: %(default)s)")
    demo.add_argument("--seed", type=int, default=0, help="episode seed: cube position and yaw (default: %(default)s)")
    demo.set_defaults(func=_demo)

    bench = sub.add_parser("bench", help="run a benchmark; prints numbers and writes JSON")
    bench.add_argument("which", choices=["primitives"], help="primitives: pick-and-place success, planning and wall time")
    bench.add_argument("--episodes", type=int, default=20, help="seeded episodes (default: %(default)s)")
    bench.add_argument("--out", type=Path, default=Path("runs/bench"), help="folder for the JSON report (default: %(default)s)")
    bench.set_defaults(func=_bench)
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
