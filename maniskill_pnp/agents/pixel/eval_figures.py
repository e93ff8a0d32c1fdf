"""Figures of clutter evaluations, one implementation each, shared by ``eval-clutter``, ``compare-clutter`` and
``benchmark``:

* :func:`plot_scenario_metrics`: completion and action efficiency per scenario, ± their standard errors over scenes,
  one bar per agent (or evaluation);
* :func:`plot_paired`: paired per-scene differences (A − B) per scenario, with error bars of two standard errors,
  so that a bar whose error bar misses zero is a difference beyond 2 SE.

Both take the per-scenario rows of :func:`~maniskill_pnp.agents.pixel.evaluate.summarize` (as ``eval_summary.json``
holds them) or the output of :func:`~maniskill_pnp.agents.pixel.evaluate.paired_differences`, and write a PNG with
matplotlib's Agg backend (the backend is left to the caller).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: The metrics drawn per scenario, with their axis labels.
FIGURE_METRICS = {"completion": "completion (%)", "action_efficiency": "action efficiency (%)"}
#: The paired differences drawn, with their axis labels.
PAIRED_METRICS = {"completion": "completion", "action_efficiency": "action efficiency", "success_rate": "success rate"}


def _grouped_bars(ax, scenarios: list[str], series: dict[str, tuple[list[float], list[float]]]) -> None:
    """Bars of each series (label -> (values, error bars)) side by side per scenario."""
    width = 0.8 / max(1, len(series))
    x = np.arange(len(scenarios))
    for i, (label, (values, errors)) in enumerate(series.items()):
        ax.bar(x + (i - (len(series) - 1) / 2) * width, values, width, yerr=errors, capsize=3, label=label)
    ax.set_xticks(x, scenarios, rotation=20, ha="right")
    ax.grid(axis="y", alpha=0.3)


def save_figure(fig, path: Path, title: str | None = None) -> Path:
    """Give ``fig`` its ``title`` (if any), write it as a PNG at ``path`` (its folder made) and close it."""
    import matplotlib.pyplot as plt

    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_scenario_metrics(rows: dict[str, list[dict]], path: Path) -> Path:
    """Completion and action efficiency per scenario (%), ± the standard error over scenes, one bar per label.

    Args:
        rows: label -> the per-scenario rows of one evaluation (each with ``scenario``, the metric and ``<metric>_se``).
        path: The PNG to write.
    """
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(r["scenario"] for label_rows in rows.values() for r in label_rows))
    fig, axes = plt.subplots(1, len(FIGURE_METRICS), figsize=(max(6.0, 1.1 * len(scenarios) * len(FIGURE_METRICS) + 3), 3.8),
                             squeeze=False)
    for ax, (metric, name) in zip(axes[0], FIGURE_METRICS.items()):
        series = {}
        for label, label_rows in rows.items():
            by = {r["scenario"]: r for r in label_rows}
            series[label] = ([100 * by[s][metric] if s in by else np.nan for s in scenarios],
                             [100 * by[s][f"{metric}_se"] if s in by else 0.0 for s in scenarios])
        _grouped_bars(ax, scenarios, series)
        ax.set_ylabel(name)
        top = max((v + e for values, errors in series.values() for v, e in zip(values, errors) if v == v), default=100)
        ax.set_ylim(0, max(105.0, top + 5))
    if len(rows) > 1:
        axes[0][-1].legend(fontsize=8, loc="lower right")
    return save_figure(fig, path, "per scenario, ± standard error over scenes")


def plot_paired(diffs: dict[str, dict[str, dict]], path: Path) -> Path:
    """Paired per-scene differences in points per scenario, error bars of two standard errors.

    Args:
        diffs: label (e.g. "A − B") -> :func:`~maniskill_pnp.agents.pixel.evaluate.paired_differences` of one pair.
        path: The PNG to write.
    """
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(s for pair in diffs.values() for s in pair))
    fig, axes = plt.subplots(1, len(PAIRED_METRICS), figsize=(max(7.0, 1.0 * len(scenarios) * len(PAIRED_METRICS) + 3), 3.8),
                             squeeze=False)
    for ax, (metric, name) in zip(axes[0], PAIRED_METRICS.items()):
        series = {label: ([100 * pair[s][metric]["mean"] if s in pair else np.nan for s in scenarios],
                          [200 * pair[s][metric]["se"] if s in pair else 0.0 for s in scenarios])
                  for label, pair in diffs.items()}
        _grouped_bars(ax, scenarios, series)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_ylabel(f"Δ {name} (points)")
    axes[0][-1].legend(fontsize=8)
    return save_figure(fig, path, "paired per-scene differences, error bars ± 2 standard errors")


__all__ = ["FIGURE_METRICS", "PAIRED_METRICS", "plot_paired", "plot_scenario_metrics", "save_figure"]
