"""Recipe: pixelwise DQN agents on the clutter tasks (thesis parts II and III), on TorchRL.

``task="grasp"`` trains one grasp FCN on ``ClutterGrasp-v1``; ``task="grasp_slide"`` trains the G&S agent, three
FCNs (grasp, left slide, right slide) on ``ClutterGraspSlide-v1``, acting by the maximum over all their maps.
One agent step is one whole primitive: the ε-greedy actor picks the argmax flat index over (primitive, rotation,
row, col) of the Q maps of the current heightmaps; the env executes it. After every step the transition goes into
a prioritized replay, ``updates_per_step`` batches are sampled, each followed by one SGD step on the pixelwise loss
(only the executed pixel is trained: the DQN loss, or with ``loss="bce"`` the thesis' binary-classification
baseline) and a refresh of the sampled priorities.

Run it with ``maniskill-pnp train-clutter --preset cpu-small --seed 1`` (``--preset gs-cpu-small`` for G&S); a run folder
``<out>/<run_name>/`` receives ``config.json``, ``checkpoint.pt`` (written atomically every ``checkpoint_interval``
steps and at the end), ``train_summary.json``, ``actions.csv`` (one row per action, see
:data:`~maniskill_pnp.agents.pixel.metrics.ACTION_COLUMNS`) and the CSV logs (``scalars/train/grasp_success.csv``
...; with ``logger="tensorboard"`` a TensorBoard event file instead).
``--resume`` continues from the run folder's checkpoint (model, optimizer, target network, ε, step and episode
counters, RNG states) and, with ``save_replay`` (the default), from the replay buffer saved beside it
(``replay_step<N>/``: TorchRL's ``ReplayBuffer.dumps`` of the storage, priorities and writer; about 40 kB per
transition at 64 px, 0.5 MB at 224 px). The checkpoint names the replay folder of its own step, written before
it, so a crash between the two leaves the previous pair intact.

The learner (network, target network, optimizer) runs on ``device`` ("auto": CUDA when available), each sampled
batch moved there from the replay, which stays on the CPU with the simulation; the direct collector acts on that
device too, worker processes with a CPU copy of the network. Checkpoints load onto the CPU, so a run resumes, and
is evaluated, on any device.

With ``mask_empty`` (the default) the actor and the bootstrap range over the actions that can touch something:
grasps where the heightmap shows material, slides that start on bare table and meet material within half their
length (:class:`~maniskill_pnp.agents.pixel.mask.HeightmapActionMask`). The bootstrap reads each transition's next
mask from the replay: the one the actor computed acting in that state (:class:`Transitions`).

Metrics of the ε-greedy behaviour (``docs/metrics.md``), logged as running values over the last ``success_window``
actions: ``grasp_success`` (grasp attempts that lifted an object / grasp attempts), ``success_rate`` (objects
placed in the bin / actions) and ``faults_per_100_actions`` (steps that ended on a fault of the simulation; the run's
total is in ``train_summary.json``); per finished episode also ``episode/success_rate`` and ``episode/cleared``
(:mod:`~maniskill_pnp.agents.pixel.metrics`).

The pieces live beside this module: the config and presets (:mod:`~maniskill_pnp.agents.pixel.config`), the env,
network, mask and actors (:mod:`~maniskill_pnp.agents.pixel.factories`), checkpoints
(:mod:`~maniskill_pnp.agents.pixel.checkpoint`) and the metrics; :func:`main` only puts them in order.
"""

from __future__ import annotations

import math
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import torch
from torchrl.objectives import HardUpdate

from maniskill_pnp.agents.collection import make_collector, resolve_backend, seed_process, sync_weights, worker_seeds
from maniskill_pnp.agents.pixel.checkpoint import load_checkpoint, restore, write_checkpoint
from maniskill_pnp.agents.pixel.config import ARCHITECTURE_FIELDS, ClutterConfig
from maniskill_pnp.agents.pixel.factories import make_action_mask, make_env, make_model, make_policy, make_worker_env
from maniskill_pnp.agents.pixel.loss import PixelBCELoss, PixelDQNLoss
from maniskill_pnp.agents.pixel.metrics import OutcomeTracker, log_episodes, log_scalars
from maniskill_pnp.agents.pixel.replay import (NextMaskJoin, holds_next_masks, make_pixel_replay, pack_transition,
                                               to_transitions, unpack_transition)
from maniskill_pnp.agents.run_io import make_logger, require_logger, write_json
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.runtime import resolve_device


def main(cfg: ClutterConfig) -> dict:
    """Train one pixelwise DQN agent; returns a summary (run folder, steps, episodes, grasp success)."""
    require_logger(cfg.logger)  # a missing tensorboard extra fails before anything is built
    device = learner_device(cfg.device)  # so does a missing GPU
    payload = resume_payload(cfg)
    counters = dict(steps=0, episodes=0, updates=0, grasps=0, faults=0)
    counters.update(payload["counters"] if payload else {})  # a checkpoint of an older version has no "faults"
    seed_process(cfg.seed)  # torch, numpy (TorchRL's prioritized sampler draws from numpy's global RNG) and random
    run_dir = cfg.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "config.json", cfg.to_json())

    # build: env (a fresh episode seed on resume, so finished episodes are not replayed), network, actors, replay,
    # learner; on resume all of them continue from the checkpoint
    env_seed = cfg.seed + counters["episodes"]
    env = make_env(cfg)
    env.set_seed(env_seed)
    model = make_model(cfg).to(device)
    _, explore, egreedy = make_policy(cfg, model, env.action_spec)
    explore.to(device)  # ε and the actor's other buffers beside the network (the action spec stays on the CPU)
    replay = make_run_replay(cfg)
    learner = Learner(cfg, model, device)
    state = dict(model=model, loss=learner.loss, optimizer=learner.optimizer, egreedy=egreedy)
    if payload is not None:
        restore(payload, run_dir, replay=replay, **state)
    summary = dict(run_dir=str(run_dir), start_step=counters["steps"], device=str(device),
                   collection=collection_summary(cfg, env_seed))
    if trained_enough(cfg, counters):
        env.close()
        return dict(summary, **counters, note="nothing left to train")
    monitor = Monitor(cfg, counters, env.base_env.primitive_names)
    store = Transitions(cfg, replay)
    collector, env = start_collector(cfg, explore, env, env_seed, frames=cfg.steps - counters["steps"], device=device)

    # loop: collect one action per worker, store it, update, log, checkpoint; with a worker process the update on
    # one batch runs while the workers collect the next (see Overlap)
    model.eval()  # acting uses BatchNorm's running statistics; the updates switch to train mode and back
    overlap = Overlap(learner, enabled=overlapped(cfg))
    t0, out_of_time = time.perf_counter(), False
    for batch in collector:
        counters["updates"] += overlap.wait()  # the model and the replay are the loop's again
        n = batch.numel()
        egreedy.step(n)
        store.add(batch.reshape(-1))
        monitor.record(batch, counters)
        if overlap.enabled:
            sync_weights(collector, explore)  # the next batch is collected with the weights before this update
        if len(replay) >= cfg.learning_starts:
            counters["updates"] += overlap.start(replay, cfg.updates_per_step * n)
        if not overlap.enabled:
            sync_weights(collector, explore)  # the workers act with the new weights and ε
        wall = time.perf_counter() - t0
        out_of_time = bool(cfg.max_minutes) and wall >= 60 * cfg.max_minutes
        done = out_of_time or trained_enough(cfg, counters)
        monitor.show(n, counters, egreedy.eps.item(), learner.last_loss)
        logs = crossed(counters["steps"], n, cfg.log_interval) or done
        saves = crossed(counters["steps"], n, cfg.checkpoint_interval) or done
        if logs or saves:
            counters["updates"] += overlap.wait()
        if logs:
            monitor.log(counters, egreedy.eps.item(), learner.last_loss, batch, wall)
        if saves:
            store.flush()  # the checkpoint's replay holds every action counted
            write_checkpoint(run_dir, cfg=cfg, replay=replay, counters=counters, **state)
            monitor.logger.flush()  # the logs reach the disk with every checkpoint
        if done:
            break
    counters["updates"] += overlap.wait()
    overlap.close()

    # close and summarize (the loop wrote the final checkpoint)
    monitor.close()
    collector.shutdown()
    if env is not None:
        env.close()
    summary.update(counters, running_grasp_success=monitor.tracker.grasp_success,
                   running_success_rate=monitor.tracker.success_rate,
                   faults_per_100_actions=100.0 * counters["faults"] / max(counters["steps"], 1), wall_s=time.perf_counter() - t0,
                   stopped_by_time=out_of_time)
    write_json(run_dir / "train_summary.json", summary)
    return summary


def resume_payload(cfg: ClutterConfig) -> dict | None:
    """The checkpoint a ``resume`` run continues from (None for a fresh run); ValueError when its architecture
    fields differ from ``cfg``'s."""
    if not cfg.resume:
        return None
    ckpt = cfg.run_dir / "checkpoint.pt"
    payload = load_checkpoint(ckpt)
    saved = ClutterConfig.from_json(payload["config"])
    changed = [f for f in ARCHITECTURE_FIELDS if getattr(saved, f) != getattr(cfg, f)]
    if changed:
        raise ValueError(f"cannot resume {ckpt}: {changed} differ from the checkpoint's config")
    return payload


def learner_device(name: str) -> torch.device:
    """The device of a config's ``device`` (see :func:`~maniskill_pnp.runtime.resolve_device`), a CUDA device with
    its index; ValueError when this machine has no such device."""
    device = resolve_device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device {name!r}: CUDA is not available on this machine (use 'auto' or 'cpu')")
        index = torch.cuda.current_device() if device.index is None else device.index
        if index >= torch.cuda.device_count():
            raise ValueError(f"device {name!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")
        device = torch.device("cuda", index)
    return device


def trained_enough(cfg: ClutterConfig, counters: dict) -> bool:
    """Whether the run has reached its ``steps``, or its ``episodes`` when that is set."""
    return counters["steps"] >= cfg.steps or bool(cfg.episodes and counters["episodes"] >= cfg.episodes)


def crossed(step: int, n: int, interval: int) -> bool:
    """Whether the last ``n`` steps, ending at ``step``, passed a multiple of ``interval``."""
    return step // interval > (step - n) // interval


def backend(cfg: ClutterConfig) -> str:
    """The run's collector backend: "auto" is a worker process even for one worker, so that the simulator and the
    learner work on separate cores."""
    return resolve_backend(cfg.collector, cfg.workers, single="process")


def overlapped(cfg: ClutterConfig) -> bool:
    """Whether the learner updates while the workers collect: with the process backend's synchronous batches."""
    return backend(cfg) == "process" and cfg.sync


def collection_summary(cfg: ClutterConfig, env_seed: int) -> dict:
    """How the run collects: backend, workers, sync, overlap and each worker's env seed (recorded in the summary)."""
    return dict(backend=backend(cfg), workers=cfg.workers, sync=cfg.sync, overlap=overlapped(cfg),
                worker_seeds=worker_seeds(env_seed, cfg.workers))


def start_collector(cfg: ClutterConfig, explore, env, env_seed: int, frames: int, device: torch.device | None = None):
    """The collector of ``frames`` more actions of the ε-greedy actor ``explore`` (on ``device``, default the CPU),
    and the env the caller still has to close: ``env`` itself with the direct backend, which acts with ``explore`` on
    its device, else None (``env`` only gave the specs; it is closed here and every worker builds its own and acts
    with a CPU copy of ``explore``)."""
    kind = backend(cfg)
    if kind != "direct":
        env.close()
        env = None
    collector = make_collector(partial(make_worker_env, cfg), explore, seed=env_seed, total_frames=frames,
                               workers=cfg.workers, backend=kind, sync=cfg.sync, env=env,
                               policy_device=device if kind == "direct" else None)
    return collector, env


class Overlap:
    """The learner's updates on one batch, run in a thread while the collector's workers collect the next batch.

    A synchronous process collector asks its workers for the next batch only when the loop asks it for one, and the
    workers act with their own copy of the policy, which :func:`~maniskill_pnp.agents.collection.sync_weights`
    overwrites while they wait between batches; so the loop syncs the weights before it starts an update
    (:meth:`start`) and takes the update back (:meth:`wait`) before it touches the model or the replay again. Batch
    ``k + 1`` is then always collected with the weights and ε of after batch ``k - 1``'s updates, one batch stale and
    the same in every run of a seed; torch runs the update outside the GIL while the loop waits for the workers. Not
    enabled, :meth:`start` updates at once, as the direct and asynchronous collectors need.
    """

    def __init__(self, learner: "Learner", enabled: bool):
        self.learner, self.enabled = learner, enabled
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="learner") if enabled else None
        self.pending = None

    def start(self, replay, steps: int) -> int:
        """Start ``steps`` updates; the updates done now (``steps``, or 0 when they run until :meth:`wait`)."""
        if self.pool is None:
            return self.learner.update(replay, steps)
        self.pending = self.pool.submit(self.learner.update, replay, steps)
        return 0

    def wait(self) -> int:
        """Wait for the running updates (their error raised here); how many they were."""
        pending, self.pending = self.pending, None
        return 0 if pending is None else pending.result()

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True)


class Transitions:
    """Stores the collected frames in the replay as transitions. Where the actor acts under an action mask, each goes
    in with its next state's mask (:class:`~maniskill_pnp.agents.pixel.replay.NextMaskJoin`: the one the actor
    computed there, so the learner's bootstrap computes none), one batch later, unless the replay is still short of
    ``learning_starts`` (then at once, so that learning starts at the action it would without); a run resumed from a
    replay stored without next masks goes on without (its learner computes them)."""

    def __init__(self, cfg: ClutterConfig, replay):
        self.replay, self.learning_starts = replay, cfg.learning_starts
        mask = make_action_mask(cfg) if cfg.loss == "dqn" else None
        actions = len(cfg.primitives) * cfg.num_rotations * cfg.heightmap_size ** 2
        joins = mask is not None and holds_next_masks(replay) and actions % 8 == 0  # bits stored 8 to a byte
        self.join = NextMaskJoin(mask, hold=4 * cfg.workers) if joins else None

    def add(self, frames) -> None:
        """Store flat collector ``frames`` (and the earlier frames whose next masks they complete)."""
        self._store(to_transitions(frames) if self.join is None else self.join.push(frames))
        if len(self.replay) < self.learning_starts:
            self.flush()

    def flush(self) -> None:
        """Store the frames still waiting for their next masks, with masks computed here."""
        if self.join is not None:
            self._store(self.join.flush())

    def _store(self, transitions) -> None:
        if transitions is not None:
            self.replay.extend(pack_transition(transitions))


class Monitor:
    """What a run shows and records of its actions: the running metrics and ``actions.csv``
    (:class:`~maniskill_pnp.agents.pixel.metrics.OutcomeTracker`), the logger (CSV or TensorBoard) and the progress
    bar."""

    def __init__(self, cfg: ClutterConfig, counters: dict, primitives: tuple[str, ...]):
        self.tracker = OutcomeTracker(primitives, cfg.success_window, log_path=cfg.run_dir / "actions.csv",
                                      start_step=counters["steps"])
        self.logger = make_logger(cfg.run_dir, cfg.logger)
        self.bar = progress_bar(total=cfg.steps, initial=counters["steps"], desc=f"{cfg.task} {cfg.run_name}", unit="action")

    def record(self, batch, counters: dict) -> None:
        """Record a collector batch (metrics, ``actions.csv``, finished episodes) and count it into ``counters``."""
        finished = self.tracker.add_batch(batch)
        log_episodes(self.logger, finished, first=counters["episodes"] + 1)
        counters.update(steps=counters["steps"] + batch.numel(), episodes=counters["episodes"] + len(finished),
                        grasps=counters["grasps"] + self.tracker.last_grasps,
                        faults=counters["faults"] + self.tracker.last_faults)

    def show(self, n: int, counters: dict, eps: float, loss: float) -> None:
        t = self.tracker
        self.bar.update(n)
        self.bar.set_postfix(grasp=f"{t.grasp_success:.2f}", success=f"{t.success_rate:.2f}", eps=f"{eps:.2f}",
                             loss=f"{loss:.3g}", episodes=counters["episodes"])

    def log(self, counters: dict, eps: float, loss: float, batch, wall: float) -> None:
        """Log the training metrics at the current step."""
        log_scalars(self.logger, counters["steps"], {
            "train/loss": loss, "train/epsilon": eps, "train/reward": float(batch.get(("next", "reward")).mean()),
            "train/grasp_success": self.tracker.grasp_success, "train/success_rate": self.tracker.success_rate,
            "train/faults_per_100_actions": self.tracker.faults_per_100_actions, "train/episodes": counters["episodes"],
            "time/wall_s": wall})

    def close(self) -> None:
        self.bar.close()
        self.tracker.close()
        self.logger.close()  # flushes TensorBoard's buffered events into the file


def make_run_replay(cfg: ClutterConfig):
    """The run's prioritized replay: packed heightmaps, memory-mapped in the run folder's scratch ``replay/``."""
    shutil.rmtree(cfg.run_dir / "replay", ignore_errors=True)
    return make_pixel_replay(cfg.replay_capacity, cfg.run_dir / "replay", cfg.replay_alpha, cfg.replay_beta,
                             batch_size=cfg.batch_size)


class Learner:
    """The config's loss (pixelwise DQN, or the binary-classification baseline), its target-network updater and the
    optimizer; :meth:`update` runs SGD steps on prioritized replay batches. ``model`` must already be on ``device``,
    where the target network and the optimizer state then are too, and each sampled batch is moved (the replay stays
    on the CPU)."""

    def __init__(self, cfg: ClutterConfig, model: torch.nn.Module, device: torch.device = torch.device("cpu")):
        self.model, self.device = model, torch.device(device)
        if cfg.loss == "bce":
            self.loss, self.key = PixelBCELoss(model), "loss_bce"
        else:
            mask = make_action_mask(cfg)  # the bootstrap ranges over the actions the actor may take
            self.loss, self.key = PixelDQNLoss(model, gamma=cfg.gamma, delay_value=cfg.delay_value, double_dqn=cfg.double_dqn,
                                               action_mask=None if mask is None else mask.from_observation), "loss_qvalue"
        self.updater = HardUpdate(self.loss, value_network_update_interval=cfg.target_update_interval) if cfg.delay_value else None
        if cfg.optimizer == "adam":
            self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        else:
            self.optimizer = torch.optim.SGD(self.loss.parameters(), lr=cfg.lr, momentum=cfg.momentum,
                                             weight_decay=cfg.weight_decay)
        self.last_loss = math.nan

    def update(self, replay, steps: int) -> int:
        """``steps`` SGD steps, each on a fresh prioritized batch whose priorities it then refreshes (the network in
        train mode meanwhile); returns ``steps``."""
        self.model.train()
        priority = self.loss.tensor_keys.priority
        for _ in range(steps):
            sample = unpack_transition(replay.sample())
            batch = sample if self.device.type == "cpu" else sample.to(self.device)
            loss = self.loss(batch)[self.key]
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            if self.updater is not None:
                self.updater.step()
            if batch is not sample:  # the loss wrote the batch's TD errors on the device
                sample.set(priority, batch.get(priority).cpu())
            replay.update_tensordict_priority(sample)
            self.last_loss = loss.item()
        self.model.eval()
        return steps


__all__ = ["Learner", "Monitor", "Overlap", "Transitions", "backend", "collection_summary", "crossed", "learner_device", "main",
           "make_run_replay", "overlapped", "resume_payload", "start_collector", "trained_enough"]
