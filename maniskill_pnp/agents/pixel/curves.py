"""Training curves of clutter runs: windowed grasp success and success rate from each run's ``actions.csv``.

Every clutter run (:mod:`maniskill_pnp.agents.pixel.recipe`) writes one row per action of its ε-greedy behaviour.
From it this module computes the trailing-window metrics of ``docs/metrics.md`` (``grasp_success``: grasps that
lifted an object / grasp attempts; ``success_rate``: objects placed / actions), the first- and last-window numbers a
learning claim rests on, and one PNG comparing runs against actions and against training minutes (as the thesis'
Figs. 25-28 compare its variants).

Example:
    >>> summary = plot_training_curves({"G&S": "runs/clutter/gs-cpu-small_...", "grasp only": "runs/..."},
    ...                                "curves.png", window=50)  # doctest: +SKIP
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from maniskill_pnp.agents.pixel.eval_figures import save_figure
from maniskill_pnp.agents.pixel.metrics import ACTION_COLUMNS


#: The columns of ``actions.csv`` the curves need (a run folder of an older version, with fewer columns, has them).
CURVE_COLUMNS = ("step", "grasp_attempt", "grasped", "placed")


def load_actions(run_dir: str | Path) -> dict[str, np.ndarray]:
    """The columns of ``<run_dir>/actions.csv`` as float arrays, by header name (normally
    :data:`~maniskill_pnp.agents.pixel.metrics.ACTION_COLUMNS`; an empty cell is NaN).

    Raises:
        FileNotFoundError: the run folder has no ``actions.csv``.
        ValueError: the file lacks a column of :data:`CURVE_COLUMNS` or holds no action.
    """
    path = Path(run_dir) / "actions.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist (is {run_dir} a clutter training run folder?)")
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header = rows[0] if rows else []
    missing = [c for c in CURVE_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path} lacks the columns {missing} (its header should be {','.join(ACTION_COLUMNS)})")
    body = [r for r in rows[1:] if len(r) == len(header)]
    if not body:
        raise ValueError(f"{path} holds no action yet")
    cols = np.array([[float(v) if v != "" else np.nan for v in r] for r in body], dtype=np.float64).T
    return {name: cols[i] for i, name in enumerate(header)}


def trailing_mean(hits: np.ndarray, counts: np.ndarray, window: int) -> np.ndarray:
    """Per action ``i``: ``sum(hits) / sum(counts)`` over the last ``window`` actions up to ``i`` (NaN if no count)."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    h, c = np.cumsum(np.r_[0.0, hits]), np.cumsum(np.r_[0.0, counts])
    lo = np.maximum(np.arange(1, len(hits) + 1) - window, 0)
    num, den = h[1:] - h[lo], c[1:] - c[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.maximum(den, 1e-12), np.nan)


def training_minutes(run_dir: str | Path, steps: np.ndarray) -> np.ndarray | None:
    """Wall-clock minutes of training at each of ``steps``, from the run's logged ``time/wall_s`` (CSV logger),
    linearly interpolated between log points; each resumed session adds to the time of the ones before it. None when
    the run has no such log (a TensorBoard run)."""
    path = Path(run_dir) / "scalars" / "time" / "wall_s.csv"
    if not path.is_file():
        return None
    logged = np.loadtxt(path, delimiter=",", ndmin=2)
    if logged.size == 0:
        return None
    step, wall = logged[:, 0], logged[:, 1].copy()
    offset = 0.0
    for i in range(1, len(wall)):  # a resumed session starts its clock at 0 again
        if wall[i] + offset < wall[i - 1]:
            offset = wall[i - 1]
        wall[i] += offset
    return np.interp(steps, np.r_[0.0, step], np.r_[0.0, wall]) / 60.0


def run_curves(run_dir: str | Path, window: int = 50) -> dict:
    """Windowed curves of one run and its first / last window numbers.

    Returns:
        ``step``, ``grasp_success`` and ``success_rate`` arrays (trailing ``window`` actions), ``minutes`` (the
        training time at each step, :func:`training_minutes`; None without a time log), and ``first`` /
        ``last``: ``grasp_success`` and ``success_rate`` over the first and the last ``window`` actions.
    """
    a = load_actions(run_dir)
    ones = np.ones_like(a["placed"])
    out = dict(
        step=a["step"],
        grasp_success=trailing_mean(a["grasped"], a["grasp_attempt"], window),
        success_rate=trailing_mean(a["placed"], ones, window),
        actions=len(ones),
        minutes=training_minutes(run_dir, a["step"]),
    )
    for name, part in (("first", slice(0, window)), ("last", slice(-window, None))):
        attempts = a["grasp_attempt"][part].sum()
        out[name] = dict(
            grasp_success=float(a["grasped"][part].sum() / attempts) if attempts else float("nan"),
            success_rate=float(a["placed"][part].mean()),
            actions=int(len(a["placed"][part])),
        )
    return out


def plot_training_curves(runs: dict[str, str | Path], out_png: str | Path, window: int = 50) -> dict[str, dict]:
    """One PNG holding every run: grasp success and success rate against actions (top row) and against training
    minutes (bottom row; runs without a time log are left out of it); returns each run's ``first`` / ``last``
    numbers, actions and minutes (see :func:`run_curves`)."""
    import matplotlib.pyplot as plt  # the backend is left to the caller (Agg when there is no display)

    if not runs:
        raise ValueError("give at least one run folder")
    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
    summary = {}
    keys = ("grasp_success", "success_rate")
    for label, run_dir in runs.items():
        c = run_curves(run_dir, window)
        minutes = None if c["minutes"] is None else float(c["minutes"][-1])
        summary[label] = dict(first=c["first"], last=c["last"], actions=c["actions"], minutes=minutes)
        for col, key in enumerate(keys):
            line, = axes[0, col].plot(c["step"], c[key], label=f"{label} (last {window}: {c['last'][key]:.0%})")
            if c["minutes"] is not None:
                axes[1, col].plot(c["minutes"], c[key], color=line.get_color(),
                                  label=f"{label} ({c['actions']} actions in {minutes:.0f} min)")
    titles = ("grasps that lifted an object / grasp attempts", "objects placed / actions")
    for col, (key, title) in enumerate(zip(keys, titles)):
        for row, xlabel in enumerate(("action", "training minutes")):
            ax = axes[row, col]
            ax.set_xlabel(xlabel)
            ax.set_ylabel(f"{key} (trailing {window} actions)")
            ax.set_ylim(0, 1)
            ax.grid(alpha=0.3)
            if ax.lines:
                ax.legend(loc="lower right", fontsize=8)
        axes[0, col].set_title(title)
    save_figure(fig, out_png)
    return summary


__all__ = ["CURVE_COLUMNS", "load_actions", "plot_training_curves", "run_curves", "trailing_mean", "training_minutes"]
