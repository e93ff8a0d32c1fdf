"""Any benchmark side by side against another revision of this package, in one run on one machine.

``maniskill-pnp bench WHICH ... --against REF`` checks revision ``REF`` of this git checkout out into a worktree
(kept in the package cache, one per commit) and runs the same ``bench WHICH ...`` command ``rounds`` times on each
side, in turns (REF, this checkout, REF, ...), each in a fresh process with the same interpreter and the same installed
dependencies: only the package's own code differs. A drift of the machine's load then touches both sides, and the
median over turns drops a turn that paid cold file caches (the first one often does). It prints
each side's headline figures (the median over its turns) and their ratio, and writes them as JSON beside the reports
of every turn.

The headline figures of each benchmark are named in :data:`HEADLINES`; a benchmark without an entry there cannot be
compared this way.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from maniskill_pnp.bench.common import print_machine, write_report
from maniskill_pnp.cache import cache_dir

#: Per benchmark: its report's file name in ``--out`` and the figures compared, as ``(label, path in the report's
#: results)``; a path part ``*`` stands for every key at that level (e.g. every variant of training-throughput).
HEADLINES: dict[str, tuple[str, tuple[tuple[str, tuple[str, ...]], ...]]] = {
    "decision-breakdown": ("decision_breakdown.json", (
        ("decisions/s", ("decisions_per_s",)),
        *((f"{part} median s", ("median_s", part)) for part in ("render", "heightmap", "network", "planning", "execution", "other")),
    )),
    "primitives": ("primitives.json", (
        ("episodes/s", ("episodes_per_s_incl_reset",)),
        ("successes", ("successes",)),
        ("sim steps (median)", ("pick_and_place_sim_steps_median",)),
        ("ManiSkill mplib episodes/s", ("maniskill_mplib_pickcube", "episodes_per_s_incl_reset")),
        ("ratio to ManiSkill", ("episodes_per_s_ratio_ours_over_maniskill",)),
    )),
    "clutter-oracle": ("clutter_oracle.json", (
        ("grasp success", ("grasp_success",)),
        ("completion", ("completion",)),
        ("success rate", ("success_rate",)),
        ("step s (median)", ("step_time_s_median", "step")),
    )),
    "env-overhead": ("env_overhead.json", (
        ("executing / PickCube env.step", ("ratio_execution_vs_env_step",)),
        ("executing / PickCube control step", ("ratio_execution_vs_control_step",)),
    )),
    "training-throughput": ("training_throughput.json", (
        ("actions/h", ("*", "actions_per_hour")),
    )),
}


@dataclass(frozen=True)
class AgainstConfig:
    """Settings of a side-by-side run.

    Attributes:
        which: The benchmark (a key of :data:`HEADLINES`).
        argv: The ``bench`` command line of one turn, without ``--out`` and ``--against``.
        ref: The git revision compared against (a branch, tag or commit of this checkout).
        rounds: Turns of each side.
        out: Folder of the turns' reports and of ``against.json``.
    """

    which: str
    argv: tuple[str, ...]
    ref: str
    rounds: int = 3
    out: Path = Path("runs/bench/against")

    def __post_init__(self):
        if self.which not in HEADLINES:
            raise ValueError(f"bench {self.which} has no headline figures to compare; --against works with {sorted(HEADLINES)}")
        if self.rounds < 1:
            raise ValueError(f"rounds must be >= 1, got {self.rounds}")


def _git(repo: Path, *args: str) -> str:
    done = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise ValueError(f"git {' '.join(args)} failed in {repo}: {done.stderr.strip()}")
    return done.stdout.strip()


def checkout_root() -> Path:
    """The git checkout this package is imported from (``--against`` compares revisions of it)."""
    package = Path(__file__).resolve().parents[1]
    try:
        return Path(_git(package.parent, "rev-parse", "--show-toplevel"))
    except (ValueError, FileNotFoundError) as e:
        raise ValueError(f"--against compares git revisions, but {package} is not in a git checkout ({e})") from e


def worktree(root: Path, ref: str) -> tuple[Path, str]:
    """A worktree of revision ``ref`` of checkout ``root`` (made once per commit, in the package cache), and the
    revision's commit."""
    commit = _git(root, "rev-parse", "--verify", f"{ref}^{{commit}}")
    path = cache_dir("bench-against") / commit[:12]
    if not (path / "maniskill_pnp" / "__init__.py").exists():
        _git(root, "worktree", "prune")
        _git(root, "worktree", "add", "--force", "--detach", str(path), commit)
    return path, commit


def headline(which: str, report: dict) -> dict[str, float]:
    """The headline figures of one turn's report (see :data:`HEADLINES`)."""
    figures = {}
    for label, path in HEADLINES[which][1]:
        nodes = [("", report["results"])]
        for part in path:
            if part == "*":
                nodes = [(f"{name}{key} ", value) for name, node in nodes if isinstance(node, dict)
                         for key, value in node.items() if isinstance(value, dict)]
            else:
                nodes = [(name, node[part]) for name, node in nodes if isinstance(node, dict) and part in node]
        for name, value in nodes:
            if isinstance(value, (int, float)):
                figures[f"{name}{label}"] = float(value)
    return figures


def _turn(cfg: AgainstConfig, side: str, source: Path | None, i: int) -> dict[str, float]:
    out = Path(cfg.out) / f"{side}_{i}"
    env = dict(os.environ)
    if source is not None:  # the baseline's package shadows this checkout's (PYTHONPATH precedes an editable install)
        env["PYTHONPATH"] = os.pathsep.join([str(source), *filter(None, [env.get("PYTHONPATH")])])
    cmd = [sys.executable, "-m", "maniskill_pnp.cli", "bench", cfg.which, *cfg.argv, "--out", str(out)]
    print(f"--- {side}, turn {i + 1}/{cfg.rounds}: {' '.join(cmd[2:])}", flush=True)
    done = subprocess.run(cmd, env=env, cwd=None if source is None else source)
    if done.returncode != 0:
        raise RuntimeError(f"bench {cfg.which} on {side} (turn {i + 1}) exited with {done.returncode}")
    return headline(cfg.which, json.loads((out.resolve() / HEADLINES[cfg.which][0]).read_text()))


def run_against(cfg: AgainstConfig) -> dict:
    """Run ``cfg.rounds`` turns of each side in alternation; print and return each side's median figures and the
    ratios (this checkout / ``ref``)."""
    root = checkout_root()
    base, commit = worktree(root, cfg.ref)
    load = os.getloadavg()
    cfg = AgainstConfig(cfg.which, cfg.argv, cfg.ref, cfg.rounds, Path(cfg.out).resolve())
    turns = {"ref": [], "this": []}
    for i in range(cfg.rounds):
        turns["ref"].append(_turn(cfg, "ref", base, i))
        turns["this"].append(_turn(cfg, "this", None, i))
    labels = [k for k in turns["ref"][0] if all(k in t for side in turns.values() for t in side)]
    median = {side: {k: statistics.median(t[k] for t in ts) for k in labels} for side, ts in turns.items()}
    ratio = {k: median["this"][k] / median["ref"][k] if median["ref"][k] else float("nan") for k in labels}
    dirty = bool(_git(root, "status", "--porcelain", "--untracked-files=no"))
    results = dict(ref=cfg.ref, ref_commit=commit, this_uncommitted_changes=dirty, turns=turns, median=median, ratio=ratio)
    write_report(cfg.out / "against.json", f"{cfg.which} against {cfg.ref}", dict(argv=list(cfg.argv), rounds=cfg.rounds), results)
    print_machine(load)
    this = "this checkout" + (" (with uncommitted changes)" if dirty else "")
    print(f"bench {cfg.which} {' '.join(cfg.argv)}: {cfg.ref} ({commit[:12]}) against {this}, median of {cfg.rounds} turns each")
    width = max(len(k) for k in labels)
    print(f"{'figure':<{width}} {cfg.ref:>14} {'this':>14} {'this / ref':>11}")
    for k in labels:
        print(f"{k:<{width}} {median['ref'][k]:>14.4g} {median['this'][k]:>14.4g} {ratio[k]:>11.3f}")
    print(f"report: {cfg.out / 'against.json'}")
    return results
