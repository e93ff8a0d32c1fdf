"""The report of ``maniskill-pnp benchmark`` (:mod:`maniskill_pnp.bench.protocol`): ``report.md``, ``scenarios.png``
and ``paired.png`` in the report folder, read from the parts' own ``eval-clutter`` / ``eval-conveyor`` outputs (so a
report can always be rebuilt from the folders)."""

from __future__ import annotations

import datetime
import json
import math
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

from maniskill_pnp.agents.pixel.eval_figures import plot_paired, plot_scenario_metrics
from maniskill_pnp.agents.pixel.evaluate import LOSS_CAUSE_KEYS, METRICS, paired_differences
from maniskill_pnp.bench.common import machine_info

if TYPE_CHECKING:
    from maniskill_pnp.bench.protocol import BenchmarkConfig, Job

#: Column names of the metrics in the report's tables.
METRIC_NAMES = {"success_rate": "success rate", "grasp_success": "grasp success", "completion": "completion",
                "action_efficiency": "action efficiency"}


def _done(job: Job) -> dict:
    try:
        return json.loads((job.folder / "done").read_text())
    except (FileNotFoundError, ValueError):
        return {}


def part_wall_s(job: Job) -> float | None:
    """The wall time a finished part took (None when it has not finished)."""
    wall = _done(job).get("wall_s")
    return None if wall is None else float(wall)


def _pct(value: float, se: float | None = None) -> str:
    return f"{100 * value:.1f}" + ("" if se is None else f" ± {100 * se:.1f}") + "%"


def _points(d: dict) -> str:
    return f"{100 * d['mean']:+.1f} ± {100 * d['se']:.1f}"


def _summary(job: Job) -> dict | None:
    path = job.folder / "eval_summary.json"
    return json.loads(path.read_text()) if job.done and path.is_file() else None


def _row(job: Job, summary: dict) -> dict:
    """The part's one scenario row of eval_summary.json, named after the part."""
    metrics = summary["metrics"][job.part.scenario]
    return dict(scenario=job.part.name, episodes=job.part.episodes, **metrics)


def git_revision() -> str:
    """The package's git revision (short hash, marked when the work tree has uncommitted changes), else "unknown"."""
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True,
                             cwd=Path(__file__).resolve().parent)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True,
                               cwd=Path(__file__).resolve().parent).stdout.strip()
        return out.stdout.strip() + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def clutter_table(rows: list[dict]) -> list[str]:
    """Markdown lines of Table IX per part: the metrics ± SE, lost objects by cause, slides, faults."""
    head = ["part", "scenes", *METRIC_NAMES.values(), "lost / scene (slide / grasp / transit / release)",
            "slides / scene (changed nothing)", "faults / 100 actions"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for r in rows:
        lost = " / ".join(f"{r.get(f'{k}_per_scene', 0):.2f}" for k in LOSS_CAUSE_KEYS)
        lines.append("| " + " | ".join([
            r["scenario"], str(r["episodes"]), *(_pct(r[m], r[f"{m}_se"]) for m in METRICS),
            f"{r['lost_per_scene']:.2f} ({lost})",
            f"{r.get('slides_per_scene', 0):.2f} ({r.get('futile_slides_per_scene', 0):.2f})",
            f"{r['faults_per_100_actions']:.2f}"]) + " |")
    return lines


def paired_table(diffs: dict[str, dict]) -> list[str]:
    """Markdown lines of paired differences per scenario: mean ± SE in points; ``*`` beyond 2 SE."""
    head = ["part", "scenes", *(f"Δ {METRIC_NAMES[m]}" for m in METRICS)]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for name, d in diffs.items():
        cells = [_points(d[m]) + (" *" if abs(d[m]["mean"]) > 2 * d[m]["se"] and d[m]["mean"] != 0 else "")
                 for m in METRICS]
        lines.append(f"| {name} | {d['scenes']} | " + " | ".join(cells) + " |")
    return lines


def _paired(a: list[dict], b: list[dict], name: str) -> dict:
    """Paired differences of two parts' episodes on their shared scenes, under the part's name."""
    strip = lambda eps: [{**e, "scenario": name} for e in eps]  # noqa: E731 (the parts' scenario names may differ)
    return paired_differences(strip(a), strip(b))[name]


def write_report(jobs: list[Job], cfg: BenchmarkConfig, failed: dict[str, str]) -> Path:
    """Write ``report.md`` and the figures into ``cfg.out``; return the report's path."""
    out = cfg.out
    by_agent: dict[str, list[Job]] = {}
    for job in jobs:
        by_agent.setdefault(job.label, []).append(job)
    machine = machine_info()
    done = [d for d in map(_done, jobs) if d]
    walls = [float(d["wall_s"]) for d in done if "wall_s" in d]
    revisions = sorted({str(d.get("revision", "unknown")) for d in done})
    labels = [lb for lb in by_agent if by_agent[lb][0].kind != "conveyor"]  # the clutter agents
    lines = [
        f"# Benchmark report ({'quick' if cfg.quick else 'full'} protocol)", "",
        f"{datetime.date.today().isoformat()}; parts run by maniskill_pnp at {', '.join(revisions) or 'unknown'}; "
        f"{machine['cpus']} CPUs, GPU {machine['gpu'] or 'none'}; torch {machine['versions']['torch']}, mani-skill "
        f"{machine['versions']['mani-skill']}. The parts took {sum(walls) / 60:.1f} min of worker time.", "",
        "Metrics as defined in the package's `docs/metrics.md`; ± the standard error over scenes; paired differences "
        "in points, `*` beyond 2 SE. Scenes from seed 1000 on, at most 3 × objects actions each; the hard sets with "
        "grasps and slides guarded at 20 N. Repeat: `maniskill-pnp benchmark " + " ".join(str(a) for a in cfg.agents)
        + (" --quick" if cfg.quick else "") + "`.", "",
    ]
    if failed:
        lines += ["**Parts that failed** (run the command again to retry them):", ""]
        lines += [f"- {name}: {error}" for name, error in failed.items()] + [""]

    figure_rows: dict[str, list[dict]] = {}
    paired_figure: dict[str, dict] = {}
    episodes_of: dict[tuple[str, str], list[dict]] = {}
    for label, agent_jobs in by_agent.items():
        lines += [f"## {label}", "", f"`{agent_jobs[0].record['agent']}` ({agent_jobs[0].kind})", ""]
        if agent_jobs[0].kind == "conveyor":
            lines += _conveyor_section(agent_jobs)
            continue
        rows, lost, strips = [], [], []
        full, restricted = {}, {}  # the G&S parts' rows, and the grasp-only restrictions', by (scenario, guard)
        for job in agent_jobs:
            summary = _summary(job)
            if summary is None:
                continue
            rows.append(_row(job, summary))
            episodes_of[(label, job.part.name)] = summary["episodes"]
            (restricted if job.part.grasp_only else full)[(job.part.scenario, job.part.guard_force)] = (job, rows[-1])
            lost += [(job.part.name, e) for e in summary["episodes"] if e["lost"]]
            strips += [Path(p) for p in summary.get("strips", [])]
        lines += clutter_table(rows) + [""]
        single = len(labels) == 1
        figure_rows[f"{label} (G&S)" if single and agent_jobs[0].kind == "grasp_slide" else label] = [
            row for _, row in full.values()]
        if single:  # the grasp-only bars beside the G&S ones, under the G&S parts' names
            figure_rows[f"{label}, grasp-only"] = [{**row, "scenario": full[key][0].part.name}
                                                   for key, (_, row) in restricted.items() if key in full]
        diffs = {}
        for key, (job, _) in full.items():
            if key in restricted:
                other = restricted[key][0]
                diffs[job.part.name] = _paired(episodes_of[(label, job.part.name)],
                                               episodes_of[(label, other.part.name)], job.part.name)
        if diffs:
            lines += ["G&S − its grasp-only restriction, paired per scene:", ""] + paired_table(diffs) + [""]
            paired_figure[f"{label}: G&S − grasp-only"] = diffs
        lines += _lost_section(lost) + _strip_section(strips, out)
        lines += ["Wall time per part (min): " + ", ".join(
            f"{j.part.name} {w / 60:.1f}" for j in agent_jobs if (w := part_wall_s(j)) is not None), ""]

    if len(labels) > 1:
        ref = labels[0]
        lines += [f"## Agents compared with {ref}, paired per scene", ""]
        for label in labels[1:]:
            diffs = {part: _paired(eps, episodes_of[(ref, part)], part) for (lb, part), eps in episodes_of.items()
                     if lb == label and (ref, part) in episodes_of}
            if diffs:
                lines += [f"{label} − {ref}:", ""] + paired_table(diffs) + [""]
                paired_figure[f"{label} − {ref}"] = diffs
    if any(figure_rows.values()):
        plot_scenario_metrics({k: v for k, v in figure_rows.items() if v}, out / "scenarios.png")
        lines += ["![completion and efficiency per scenario](scenarios.png)", ""]
    if paired_figure:
        plot_paired(paired_figure, out / "paired.png")
        lines += ["![paired differences](paired.png)", ""]
    report = out / "report.md"
    report.write_text("\n".join(lines))
    (out / "report.json").write_text(json.dumps(dict(
        agents=[str(a) for a in cfg.agents], quick=cfg.quick, failed=failed, machine=machine,
        parts={f"{j.label}/{j.part.name}": dict(folder=str(j.folder), wall_s=part_wall_s(j)) for j in jobs}), indent=2))
    return report


def _lost_section(lost: list[tuple[str, dict]]) -> list[str]:
    if not lost:
        return ["Objects lost: none.", ""]
    lines = [f"Objects lost ({sum(e['lost'] for _, e in lost)}), per episode and cause:", ""]
    for part, e in lost:
        causes = ", ".join(f"{e.get(k, 0)} {k.removeprefix('lost_').replace('_', ' ')}" for k in LOSS_CAUSE_KEYS if e.get(k, 0))
        where = f"seed {e['seed']}" + (f", {e['layout']}" if e.get("layout") else "")
        lines.append(f"- {part}, {where}: {causes or str(e['lost']) + ' (cause not recorded)'}")
    return lines + [""]


def _strip_section(strips: list[Path], out: Path) -> list[str]:
    if not strips:
        return []
    links = [f"[{p.parent.parent.name}/{p.stem}]({p.relative_to(out) if p.is_relative_to(out) else p})" for p in strips]
    return ["Decisions of the worst episodes: " + ", ".join(links), ""]


def _binomial_se(p: float, n: int) -> float:
    """Standard error of a success fraction ``p`` over ``n`` independent episodes."""
    return math.sqrt(p * (1 - p) / n) if n > 1 else 0.0


def _conveyor_section(jobs: list[Job]) -> list[str]:
    lines = []
    for job in jobs:
        path = job.folder / "eval.json"
        if not (job.done and path.is_file()):
            continue
        agents = json.loads(path.read_text())["agents"]
        for name, res in agents.items():
            cases = res["test_cases"]
            lines += [f"Random test cases 1-5, {job.part.episodes} episodes each ({name}; ± binomial standard error):", "",
                      "| test case | success rate | grasp success |", "|---|---|---|"]
            lines += [f"| {case} | {_pct(v['success_rate'], _binomial_se(v['success_rate'], v['episodes']))} | "
                      f"{_pct(v['grasp_success'])} |" for case, v in cases.items()]
            mean, n = res["test_case_average_success_rate"], job.part.episodes * len(cases)
            lines += [f"| average | {_pct(mean, _binomial_se(mean, n))} | |", ""]
    return lines


__all__ = ["clutter_table", "paired_table", "part_wall_s", "write_report"]
