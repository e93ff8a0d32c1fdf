"""Training metrics of a pixelwise DQN run: running values over the last actions, and one ``actions.csv`` row per
action, read from the outcome the env reports for every step (``info`` keys
:data:`~maniskill_pnp.tasks.OUTCOME_KEYS`, which the TorchRL env exposes as ``("next", key)`` entries).

Definitions (those of ``docs/metrics.md``): a grasp attempt is an action whose primitive is named ``"grasp"``
(:func:`is_grasp_attempt`); ``grasp_success`` = grasp attempts that lifted an object (``info["grasp_success"]``) /
grasp attempts; ``success_rate`` = objects placed in the bin (``info["placed_objects"]``, two for a grasp that
carries two) / actions; ``faults_per_100_actions`` = actions that ended on a fault of the simulation
(``info["fault"]``) per 100 actions. Per finished episode: ``episode/success_rate`` (its placed objects / its
actions), ``episode/cleared`` (1 when its workspace was emptied, whether into the bin or not) and
``episode/actions``. The greedy evaluation (:mod:`~maniskill_pnp.agents.pixel.evaluate`) counts
with the same rule from the same keys.

``actions.csv`` (columns :data:`ACTION_COLUMNS`) is what :mod:`~maniskill_pnp.agents.pixel.curves` plots; on resume
the rows past the checkpoint's step are dropped first, so the file always matches the checkpoint's history.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

from tensordict import TensorDictBase

from maniskill_pnp.agents.collection import streams

#: Columns of a run's ``actions.csv``: one row per action of the ε-greedy behaviour. ``primitive`` is the index of
#: the primitive that ran (-1: none, an invalid action); ``placed`` is the number of objects the action put into the
#: bin; ``grasp_attempt``, ``grasped``, ``slide_changed``, ``fault`` and ``episode_end`` are 0/1.
ACTION_COLUMNS = ("step", "primitive", "action", "reward", "grasp_attempt", "grasped", "placed", "episode_end",
                  "slide_changed", "fault")
#: The per-step entries of a collector batch (under ``"next"``) the metrics read.
OUTCOME_ENTRIES = ("primitive_index", "reward", "grasp_success", "placed_objects", "slide_changed", "fault", "done",
                   "terminated")


def is_grasp_attempt(primitives: tuple[str, ...], primitive_index: int) -> bool:
    """Whether the primitive that ran (``info["primitive_index"]``; -1: none ran) is the grasp."""
    return 0 <= primitive_index < len(primitives) and primitives[primitive_index] == "grasp"


class OutcomeTracker:
    """Running metrics of the actions taken (see the module docstring), and the ``actions.csv`` writer.

    Args:
        primitives: The task's primitive names, in primitive-index order (``env.primitive_names``).
        window: Actions in the running ``grasp_success`` / ``success_rate``.
        log_path: Optional per-action CSV (``actions.csv``).
        start_step: Actions already taken (the checkpoint's step counter) when resuming.
    """

    def __init__(self, primitives: tuple[str, ...], window: int, log_path: Path | None = None, start_step: int = 0):
        self.primitives = tuple(primitives)
        self.grasps: deque[bool] = deque(maxlen=window)
        self.placed: deque[int] = deque(maxlen=window)
        self.faulted: deque[bool] = deque(maxlen=window)
        self.last_grasps = 0
        self.last_faults = 0
        self.step = int(start_step)
        self._episodes: dict = {}  # stream (worker, trajectory) -> actions and placed objects so far
        self._log = None if log_path is None else _open_action_log(Path(log_path), self.step)

    def add_batch(self, batch: TensorDictBase) -> list[dict]:
        """Record a collector batch, stream by stream (per worker and episode, in time order, see
        :func:`~maniskill_pnp.agents.collection.streams`); returns the episodes it finished."""
        finished, grasps, faults = [], 0, 0
        for stream, frames in streams(batch):
            finished += self.add(frames, stream)
            grasps += self.last_grasps
            faults += self.last_faults
        self.last_grasps, self.last_faults = grasps, faults
        return finished

    def add(self, frames: TensorDictBase, stream=0) -> list[dict]:
        """Record consecutive frames of one env (flat, in time order; ``stream`` names the env's episode when several
        workers interleave); returns the episodes they finished."""
        nxt = frames.get("next")
        columns = [frames.get("action").reshape(-1).tolist()] + [nxt.get(key).reshape(-1).tolist() for key in OUTCOME_ENTRIES]
        finished, self.last_grasps, self.last_faults = [], 0, 0
        for a, p, r, grasped, placed, changed, fault, d, t in zip(*columns):
            attempt = is_grasp_attempt(self.primitives, p)
            if attempt:
                self.grasps.append(bool(grasped))
            self.last_grasps += int(grasped)
            self.placed.append(int(placed))
            self.faulted.append(bool(fault))
            self.last_faults += int(fault)
            self.step += 1
            if self._log is not None:
                self._log.write(f"{self.step},{p},{a},{r:.4g},{int(attempt)},{int(grasped)},{int(placed)},{int(d)},"
                                f"{int(changed)},{int(fault)}\n")
            e = self._episodes.setdefault(stream, dict(actions=0, placed=0))
            e["actions"] += 1
            e["placed"] += int(placed)
            if d:
                finished.append(dict(e, success_rate=e["placed"] / e["actions"], cleared=bool(t)))
                del self._episodes[stream]
        if self._log is not None:
            self._log.flush()
        return finished

    def close(self) -> None:
        if self._log is not None:
            self._log.close()

    @property
    def grasp_success(self) -> float:
        """Grasp attempts that lifted an object / grasp attempts, over the window (0 before any attempt)."""
        return sum(self.grasps) / len(self.grasps) if self.grasps else 0.0

    @property
    def success_rate(self) -> float:
        """Objects placed / actions, over the window."""
        return sum(self.placed) / len(self.placed) if self.placed else 0.0

    @property
    def faults_per_100_actions(self) -> float:
        """Actions that ended on a fault of the simulation (``info["fault"]``) per 100 actions, over the window."""
        return 100.0 * sum(self.faulted) / len(self.faulted) if self.faulted else 0.0


def log_scalars(logger, step: int, scalars: dict[str, float]) -> None:
    """Log every ``name: value`` of ``scalars`` at ``step``."""
    for name, value in scalars.items():
        logger.log_scalar(name, value, step=step)


def log_episodes(logger, episodes: list[dict], first: int) -> None:
    """Log finished episodes (from :meth:`OutcomeTracker.add`), numbered from ``first``: ``episode/success_rate``,
    ``episode/cleared`` and ``episode/actions``."""
    for number, e in enumerate(episodes, start=first):
        log_scalars(logger, number, {"episode/success_rate": e["success_rate"], "episode/cleared": float(e["cleared"]),
                                     "episode/actions": e["actions"]})


def _open_action_log(path: Path, start_step: int):
    """Open ``path`` for appending, after dropping the rows past ``start_step`` (and any torn last line). Rows of a
    file with other columns (an older run) keep the columns of :data:`ACTION_COLUMNS` they have; the others stay
    empty."""
    keep = []
    if path.is_file() and start_step > 0:
        lines = path.read_text().splitlines()
        header = lines[0].split(",") if lines else []
        for line in lines[1:]:
            parts = line.split(",")
            if len(parts) == len(header) and parts[0].isdigit() and int(parts[0]) <= start_step:
                row = dict(zip(header, parts))
                keep.append(",".join(row.get(column, "") for column in ACTION_COLUMNS))
    with open(path, "w") as f:
        f.write(",".join(ACTION_COLUMNS) + "\n" + "".join(line + "\n" for line in keep))
    return open(path, "a")


__all__ = ["ACTION_COLUMNS", "OUTCOME_ENTRIES", "OutcomeTracker", "is_grasp_attempt", "log_episodes", "log_scalars"]
