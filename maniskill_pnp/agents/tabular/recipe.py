"""Recipe: tabular Q-learning or SARSA on ``ConveyorProximity-v1`` (thesis chapter 4), on TorchRL.

One agent step is a whole phase of one pick (wait and sense → pre-pick coordinate → grasp coordinate), so an
episode is one object and at most three frames. The state id and the coordinate sets come from the task's public
:class:`~maniskill_pnp.tasks.conveyor_config.ConveyorSpec`; the actions valid in the current phase come from the
task itself, as the env's ``"action_mask"`` entry.

Run it with ``python -m maniskill_pnp.cli train-conveyor --algorithm sarsa --seed 1``; a run folder
``<out>/<algorithm>_<reward_scheme>_seed<seed>/`` receives ``config.json``, ``qtable.pt`` and the CSV logs
(``scalars/train/success_rate.csv`` ..., read back by the evaluation's learning curves), or with
``logger="tensorboard"`` a TensorBoard event file instead.

Metric: ``success_rate`` (objects placed in the bin / pick-and-place attempts; see ``docs/metrics.md``). On the
conveyor every episode is one object and one pick-and-place attempt, so it is the fraction of episodes whose object
ended in the bin; during training it is the running mean over the last ``success_window`` episodes of the ε-greedy
behaviour.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv
from torchrl.envs.transforms import ActionMask

from maniskill_pnp.agents.collection import check_collection, make_collector, resolve_backend, streams, sync_weights, worker_seeds
from maniskill_pnp.agents.run_io import (
    RunConfig, atomic_write_bytes, check_logger, make_logger, require_logger, require_positive, write_json,
)
from maniskill_pnp.agents.tabular.qtable import ALGORITHMS, QTable, bootstrap_for, make_qtable_policy, td_update
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, OBJECT_KINDS, PHASES, REWARD_SCHEMES, SPEEDS, ConveyorSpec

ENV_ID = "ConveyorProximity-v1"
QTABLE_FORMAT = "maniskill_pnp.conveyor_qtable/1"


@dataclass(frozen=True)
class ConveyorConfig(RunConfig):
    """Everything a conveyor training run depends on; saved as ``config.json`` in the run folder.

    The thesis (ch. 4) gives no values for α, γ or ε; ε follows its chapter-5 schedule (0.3 → 0.1), α and γ are ours.
    """

    algorithm: str = "qlearning"
    """TD control algorithm: "qlearning" (off-policy, bootstraps the best valid next action) or "sarsa"
    (on-policy, bootstraps the next action the ε-greedy policy actually took)."""
    steps: int = 3000
    """Agent steps (frames) to train for; an episode is 1–3 steps (the thesis' learning curves run 3000)."""
    alpha: float = 0.5
    """TD step size α in (0, 1]."""
    gamma: float = 0.9
    """Discount γ in [0, 1]."""
    eps_start: float = 0.3
    """ε of the ε-greedy behaviour policy at step 0."""
    eps_end: float = 0.1
    """ε after ``eps_decay_steps`` steps (linear decay, then constant)."""
    eps_decay_steps: int = 2000
    """Steps over which ε decays linearly from ``eps_start`` to ``eps_end``."""
    q_init: float = 1.0
    """Initial value of every Q entry; 1.0 (the reward of a placed object) makes the greedy policy try each
    coordinate before settling (optimistic initial values)."""
    reward_scheme: str = "normal"
    """Reward scheme of the task: "normal" (1 / 0.5 / 0), "negative" (−1 on full failure), "bonus" (+1 for the
    hand-marked optimal coordinates) or "negative_bonus" (both)."""
    object_kinds: tuple[str, ...] = OBJECT_KINDS
    """Object kinds drawn at random each episode (subset of cuboid, cylinder, sphere)."""
    alignment: str | None = None
    """Fix the lane ("left", "center", "right"); None draws it at random each episode."""
    speed: str | None = None
    """Fix the belt speed class ("slow", "medium", "fast"); None draws it at random each episode."""
    seed: int = 0
    """Seed of the env's episode draws, the planner and the exploration."""
    workers: int = 1
    """Env workers collecting in parallel (processes, or Ray actors); each has its own seed, recorded in
    train_summary.json."""
    collector: str = "auto"
    """Collector backend: "auto" (direct for one worker, process for more), "direct", "process" or "ray" (needs the
    ray extra, ``pip install maniskill_pnp[ray]``; joins the cluster named by RAY_ADDRESS)."""
    sync: bool = True
    """A multi-worker batch waits for every worker (False: each worker's frames as soon as they are ready)."""
    frames_per_batch: int = 3
    """Frames per worker in a collector batch (one full episode is 3); TD updates follow each batch."""
    success_window: int = 100
    """Episodes in the running success rate shown on the progress bar and logged."""
    log_interval: int = 30
    """Log the training metrics every this many steps."""
    logger: str = "csv"
    """Where the training metrics go: "csv" (CSV files in the run folder, read back by the evaluation/plot commands)
    or "tensorboard" (TorchRL's TensorboardLogger; needs the tensorboard extra,
    ``pip install maniskill_pnp[tensorboard]``)."""
    out: Path = Path("runs/conveyor")
    """Parent folder of the run folder ``<algorithm>_<reward_scheme>_seed<seed>``."""

    def __post_init__(self):
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {self.algorithm!r}; valid: {list(ALGORITHMS)}")
        if self.reward_scheme not in REWARD_SCHEMES:
            raise ValueError(f"unknown reward_scheme {self.reward_scheme!r}; valid: {list(REWARD_SCHEMES)}")
        check_logger(self.logger)
        check_collection(self.workers, self.collector, self.sync)
        kinds = (self.object_kinds,) if isinstance(self.object_kinds, str) else tuple(self.object_kinds)
        if not kinds or any(k not in OBJECT_KINDS for k in kinds):
            raise ValueError(f"object_kinds must be a non-empty subset of {list(OBJECT_KINDS)}, got {list(kinds)}")
        object.__setattr__(self, "object_kinds", kinds)
        object.__setattr__(self, "out", Path(self.out))
        if self.alignment is not None and self.alignment not in ALIGNMENTS:
            raise ValueError(f"unknown alignment {self.alignment!r}; valid: {list(ALIGNMENTS)} or None")
        if self.speed is not None and self.speed not in SPEEDS:
            raise ValueError(f"unknown speed {self.speed!r}; valid: {list(SPEEDS)} or None")
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {self.gamma}")
        if not 0.0 <= self.eps_end <= self.eps_start <= 1.0:
            raise ValueError(f"need 0 <= eps_end <= eps_start <= 1, got {self.eps_start} -> {self.eps_end}")
        require_positive(self, ("steps", "eps_decay_steps", "frames_per_batch", "success_window", "log_interval"))

    @property
    def run_name(self) -> str:
        return f"{self.algorithm}_{self.reward_scheme}_seed{self.seed}"


# ----------------------------------------------------------------------------- factories
def make_worker_env(cfg: ConveyorConfig, seed: int) -> TransformedEnv:
    """The env of one collector worker: the config's task with its episodes and planner seeded by ``seed``."""
    return make_env(replace(cfg, seed=seed))


def make_env(cfg: ConveyorConfig, *, reward_scheme: str | None = None, **task_options) -> TransformedEnv:
    """The conveyor task as a TorchRL env whose action spec follows the task's own action mask.

    Next to the state id the env carries ``"action_mask"`` (bool ``[1, action_n]``: the actions valid in the task's
    current phase, as the task reports them in its info; all False once the episode is over), ``"success"`` and the
    task's outcome flags (``"grasp_success"``, ``"place_success"`` ...). TorchRL's
    :class:`~torchrl.envs.transforms.ActionMask` puts the mask on the action spec, so random actions
    (``env.rand_action``, ``check_env_specs``) respect the phases; the Q-table policies read the same entry.
    ``task_options`` override the config's ``object_kinds`` / ``alignment`` / ``speed``.
    """
    from maniskill_pnp.torchrl_env import make_torchrl_env

    import maniskill_pnp  # noqa: F401  (registers the task ids)

    options = dict(object_kinds=cfg.object_kinds, alignment=cfg.alignment, speed=cfg.speed)
    options.update(task_options)
    base = make_torchrl_env(
        ENV_ID,
        obs_mode="state",
        control_mode="pd_joint_pos",
        sim_backend="physx_cpu",
        render_backend="cpu",
        reward_scheme=reward_scheme or cfg.reward_scheme,
        planner_seed=cfg.seed,
        **options,
    )
    env = TransformedEnv(base, ActionMask())
    env.set_seed(cfg.seed)
    return env


def save_qtable(table: QTable, cfg: ConveyorConfig, path: Path, *, spec: ConveyorSpec, extra: dict | None = None) -> None:
    """``torch.save`` the table with its config and the spec-derived shapes that :func:`load_qtable` checks."""
    payload = dict(
        format=QTABLE_FORMAT,
        values=table.values.clone(),
        config=cfg.to_json(),
        num_states=spec.num_states,
        action_n=spec.action_n,
        phases=list(PHASES),
        **(extra or {}),
    )
    atomic_write_bytes(path, lambda f: torch.save(payload, f))


def qtable_file(path: Path) -> Path:
    """The Q-table file of ``path``: ``qtable.pt`` inside it when it is a run folder, else ``path`` itself."""
    path = Path(path)
    return path / "qtable.pt" if path.is_dir() else path


def load_qtable(path: Path, *, spec: ConveyorSpec | None = None) -> tuple[QTable, ConveyorConfig, dict]:
    """Load a table saved by :func:`save_qtable` (``path``: the file or its run folder); ValueError naming the file
    and the problem if it is unusable."""
    path = qtable_file(path)
    spec = spec or ConveyorSpec()
    if not path.is_file():
        raise FileNotFoundError(f"Q-table file {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for truncated / foreign files
        raise ValueError(f"Q-table file {path} is unreadable (truncated or not a torch.save file): {e}") from e
    if not isinstance(payload, dict) or payload.get("format") != QTABLE_FORMAT:
        raise ValueError(f"Q-table file {path} is not a conveyor Q-table (expected format {QTABLE_FORMAT!r})")
    values = payload.get("values")
    want = (spec.num_states, spec.action_n)
    if not isinstance(values, torch.Tensor) or tuple(values.shape) != want:
        got = tuple(values.shape) if isinstance(values, torch.Tensor) else type(values).__name__
        raise ValueError(f"Q-table file {path} has shape {got}, but the current ConveyorSpec needs {want}")
    if payload.get("phases") != list(PHASES):
        raise ValueError(f"Q-table file {path} was saved for phases {payload.get('phases')}, the task has {list(PHASES)}")
    table = QTable(*want)
    table.values.copy_(values)
    return table, ConveyorConfig.from_json(payload["config"]), payload


# ----------------------------------------------------------------------------- transitions with their next action
class NextActionPairing:
    """Pairs each collected transition with ``"next_action"``, the action the behaviour policy took at ``s'``.

    SARSA bootstraps ``Q(s', a')`` of the action actually taken next, which the collector only records in the next
    frame (possibly in the next batch). A transition is therefore held back until the frame that continues its
    trajectory arrives; a terminal transition is released at once (it bootstraps 0). Each ``a'`` was chosen before
    the held-back ``Q(s, a)`` was updated, as in the online algorithm. A trajectory cut by truncation takes ``a'``
    from the behaviour policy at ``s'`` (the conveyor's episodes, at most 3 steps, are never truncated).
    """

    def __init__(self, policy):
        self.policy = policy
        self.pending: dict = {}  # stream (worker, trajectory) -> its held-back transition

    def __call__(self, batch: TensorDictBase) -> TensorDictBase | None:
        """Takes a collector batch (one env or several workers, see :func:`~maniskill_pnp.agents.collection.streams`);
        returns the transitions whose ``a'`` is known."""
        ready = []
        for stream, frames in streams(batch):
            for i in range(frames.shape[0]):
                frame = frames[i : i + 1].clone()
                pending = self.pending.pop(stream, None)
                if pending is not None:
                    self._check_continues(pending, frame)
                    pending.set("next_action", frame.get("action"))
                    ready.append(pending)
                terminated = bool(frame.get(("next", "terminated")).any())
                truncated = bool(frame.get(("next", "truncated")).any())
                if terminated:
                    frame.set("next_action", torch.zeros_like(frame.get("action")))
                    ready.append(frame)
                elif truncated:
                    with torch.no_grad():
                        follow = self.policy(frame.get("next").exclude("reward", "done", "terminated", "truncated").clone())
                    frame.set("next_action", follow.get("action"))
                    ready.append(frame)
                else:
                    self.pending[stream] = frame
        return torch.cat(ready) if ready else None

    @staticmethod
    def _check_continues(pending: TensorDictBase, frame: TensorDictBase) -> None:
        if not torch.equal(pending.get(("next", "observation")), frame.get("observation")):
            raise RuntimeError("the frame after a non-terminal transition does not start at its next state")


# ----------------------------------------------------------------------------- collection and episode tally
def make_training_collector(cfg: ConveyorConfig, policy, env: TransformedEnv):
    """The collector of a training run (a few frames per worker per batch, exploration on) and its description for
    ``train_summary.json``. With the direct backend it steps ``env``; otherwise ``env`` only gave the specs and is
    closed here, and every worker builds its own."""
    backend = resolve_backend(cfg.collector, cfg.workers)
    collection = dict(backend=backend, workers=cfg.workers, sync=cfg.sync, worker_seeds=worker_seeds(cfg.seed, cfg.workers))
    if backend != "direct":
        env.close()
    collector = make_collector(
        partial(make_worker_env, cfg), policy, seed=cfg.seed, total_frames=cfg.steps, frames_per_worker=cfg.frames_per_batch,
        workers=cfg.workers, backend=backend, sync=cfg.sync, env=env if backend == "direct" else None,
    )
    return collector, collection


class EpisodeTally:
    """Frames, episodes and placed objects so far, and the running ``success_rate`` over the last ``window``
    episodes (one episode is one object and one pick-and-place attempt)."""

    def __init__(self, window: int):
        self.frames = self.episodes = self.placed = 0
        self.recent: deque[bool] = deque(maxlen=window)

    def add(self, batch: TensorDictBase) -> None:
        """Count a flat batch of transitions: its frames, and the episodes that ended in it (placed or not)."""
        self.frames += batch.numel()
        ends = batch.get(("next", "done")).reshape(-1)
        for ok in batch.get(("next", "success")).reshape(-1)[ends].tolist():
            self.recent.append(bool(ok))
            self.episodes, self.placed = self.episodes + 1, self.placed + bool(ok)

    @property
    def success_rate(self) -> float:
        return sum(self.recent) / len(self.recent) if self.recent else 0.0


# ----------------------------------------------------------------------------- main
def main(cfg: ConveyorConfig) -> dict:
    """Train one tabular agent; returns a summary (run folder, files, final running success rate, wall time)."""
    require_logger(cfg.logger)  # a missing tensorboard extra fails before anything is built
    torch.manual_seed(cfg.seed)
    spec = ConveyorSpec()
    run_dir = cfg.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "config.json", cfg.to_json())

    # The env (its "action_mask" entry: the task's valid actions), the Q-table with its greedy and ε-greedy
    # policies, the TD update (Q-learning and SARSA differ only in the bootstrap term), the collector, the logger.
    env = make_env(cfg)
    table = QTable(spec.num_states, spec.action_n, init=cfg.q_init)
    _, explore, egreedy = make_qtable_policy(
        table, env.action_spec_unbatched, eps_init=cfg.eps_start, eps_end=cfg.eps_end, annealing_num_steps=cfg.eps_decay_steps
    )
    bootstrap = bootstrap_for(cfg.algorithm)
    pairing = NextActionPairing(explore)
    collector, collection = make_training_collector(cfg, explore, env)
    logger = make_logger(run_dir, cfg.logger)

    tally = EpisodeTally(cfg.success_window)
    next_log = cfg.log_interval
    t0 = time.perf_counter()
    bar = progress_bar(total=cfg.steps, desc=f"{cfg.algorithm} {cfg.reward_scheme}", unit="step")
    for batch in collector:
        # collect: a few frames of every worker, as one flat batch of transitions
        batch = batch.reshape(-1)
        # update: pair each transition with a', TD-update the table in order, anneal ε, send both to the workers
        ready = pairing(batch)
        if ready is not None:
            td_update(table, ready, alpha=cfg.alpha, gamma=cfg.gamma, bootstrap=bootstrap)
        egreedy.step(batch.numel())
        sync_weights(collector, explore)
        # log: the running success rate of the episodes that ended
        tally.add(batch)
        bar.update(batch.numel())
        bar.set_postfix(success=f"{tally.success_rate:.2f}", eps=f"{egreedy.eps.item():.2f}", episodes=tally.episodes)
        if tally.frames >= next_log or tally.frames >= cfg.steps:
            logger.log_scalar("train/success_rate", tally.success_rate, step=tally.frames)
            logger.log_scalar("train/episodes", tally.episodes, step=tally.frames)
            logger.log_scalar("train/epsilon", egreedy.eps.item(), step=tally.frames)
            logger.log_scalar("time/wall_s", time.perf_counter() - t0, step=tally.frames)
            next_log = tally.frames + cfg.log_interval
    bar.close()
    logger.close()  # flushes TensorBoard's buffered events into the file
    collector.shutdown()
    if collection["backend"] == "direct":
        env.close()

    # checkpoint: the Q-table (atomically, with its config and shapes) and the run's summary
    summary = dict(
        run_dir=str(run_dir), steps=tally.frames, episodes=tally.episodes, placed=tally.placed,
        final_running_success_rate=tally.success_rate, wall_s=time.perf_counter() - t0, collection=collection,
    )
    save_qtable(table, cfg, run_dir / "qtable.pt", spec=spec, extra=dict(train=summary))
    write_json(run_dir / "train_summary.json", summary)
    return summary


__all__ = [
    "ConveyorConfig", "EpisodeTally", "NextActionPairing", "load_qtable", "main", "make_env", "make_training_collector",
    "make_worker_env", "qtable_file", "save_qtable",
]
