"""Where a recipe's transitions come from: one env in this process, several env processes, or Ray workers.

All three are TorchRL collectors built by :func:`make_collector`, so a recipe's loop is the same for each:

========== ============================================================== ===============================
backend    what runs the envs                                             TorchRL class
========== ============================================================== ===============================
direct     one env in the learner's process (``workers`` must be 1)       ``Collector``
process    ``workers`` env processes on this machine                      ``MultiSyncCollector`` /
                                                                          ``MultiAsyncCollector``
ray        ``workers`` Ray actors, on this machine or across a cluster    ``RayCollector``
========== ============================================================== ===============================

Every worker builds its own env from a picklable ``make_env(seed)`` and seeds it (and its process' torch, numpy and
``random``) with its own seed from :func:`worker_seeds`, so workers draw different clutters and different ε-random
actions; the recipes record the seeds in their ``train_summary.json``. With ``sync`` (the default) each batch
holds ``frames_per_worker`` frames of every worker, stacked as rows; without it, each batch is one worker's frames
as soon as they are ready (fresher data, less reproducible). The workers act with their own copy of the policy, on
the CPU whatever device the learner's is on (TorchRL puts a process collector's policy in shared memory, which the
workers read as they act); the learner copies its weights and buffers (the ε of the exploration module among them)
into that copy with :func:`sync_weights`, so its updates reach the workers only then: between two synchronous
batches, while the workers wait (without ``sync`` the workers act on while it is written). The direct backend acts
with the learner's policy itself, on its device.

A Ray run joins the cluster named by the ``RAY_ADDRESS`` environment variable (``ray.init``'s rule) or starts a
local Ray instance; see the README's "Scaling out".
"""

from __future__ import annotations

import copy
import os
import random
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.collectors import BaseCollector, Collector, MultiAsyncCollector, MultiSyncCollector
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType

from maniskill_pnp.agents.run_io import MissingExtraError

#: Collector backends: the three of the table above, and "auto" (a recipe's choice, see :func:`resolve_backend`).
BACKENDS = ("auto", "direct", "process", "ray")
#: Seeds of two workers differ by this much, so the episodes of one never repeat those of another.
WORKER_SEED_STRIDE = 100_003

TRAJ_KEY = ("collector", "traj_ids")
#: ``ray.init`` keywords of the ray backend: no dashboard, workers' output not forwarded to the learner's console.
RAY_INIT = dict(address=None, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)


def check_collection(workers: int, backend: str, sync: bool = True) -> None:
    """ValueError naming the problem for a worker count / backend pair that cannot run."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if backend not in BACKENDS:
        raise ValueError(f"unknown collector backend {backend!r}; valid: {list(BACKENDS)}")
    if backend == "direct" and workers != 1:
        raise ValueError(f"the direct collector runs one env in this process; use backend 'process' or 'ray' for "
                         f"workers={workers}")
    if backend == "ray" and not sync:
        raise ValueError("the ray backend needs sync=True (each Ray worker numbers its trajectories on its own, so "
                         "only the rows of a synchronous batch tell the workers apart)")


def resolve_backend(backend: str, workers: int, single: str = "direct") -> str:
    """The backend "auto" stands for with ``workers`` workers: ``single`` for one (a recipe whose simulator costs more
    than its learner passes "process", so that the two work on separate cores), "process" for more; any other name
    unchanged."""
    if backend == "auto":
        return single if workers == 1 else "process"
    return backend


def worker_seeds(seed: int, workers: int) -> list[int]:
    """The env seed of each worker: ``seed``, ``seed + WORKER_SEED_STRIDE``, ..."""
    return [int(seed) + WORKER_SEED_STRIDE * i for i in range(workers)]


def seed_process(seed: int) -> None:
    """Seed torch, numpy and ``random`` of the calling process."""
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)


def _process_id() -> tuple[str, int]:
    return socket.gethostname(), os.getpid()


@dataclass(frozen=True)
class WorkerEnv:
    """Picklable constructor of one worker's env: seeds the worker process, builds ``make_env(seed)``, seeds it.

    In a worker (a spawned process or a Ray actor) it seeds that process' torch, numpy and ``random`` too; called in
    the learner's own process (TorchRL may build one env there to read specs) it leaves the learner's RNGs alone.
    """

    make_env: Callable[[int], EnvBase]
    seed: int
    learner: tuple[str, int] = field(default_factory=_process_id)

    def __call__(self) -> EnvBase:
        if _process_id() != self.learner:
            seed_process(self.seed)
        env = self.make_env(self.seed)
        env.set_seed(self.seed)
        return env


def make_collector(
    make_env: Callable[[int], EnvBase],
    policy,
    *,
    seed: int,
    total_frames: int,
    frames_per_worker: int = 1,
    workers: int = 1,
    backend: str = "direct",
    sync: bool = True,
    env: EnvBase | None = None,
    policy_device: torch.device | str | None = None,
) -> BaseCollector:
    """A TorchRL collector of ``policy`` (exploration on) over ``workers`` envs built by ``make_env(seed)``.

    Args:
        make_env: Picklable (a module-level function or a ``functools.partial`` of one): seed -> TorchRL env.
        policy: The acting policy (ε-greedy); its weights and buffers are copied to the workers.
        seed: Seed of the first worker (see :func:`worker_seeds`).
        total_frames: Frames to collect over all workers (rounded up to whole batches by TorchRL).
        frames_per_worker: Frames each worker adds to a batch.
        workers, backend, sync: See the module docstring; checked by :func:`check_collection`.
        env: With the direct backend, an env already built (and seeded) by the caller; otherwise it is built here.
        policy_device: With the direct backend, the device ``policy`` is wholly on (e.g. a CUDA learner's): each
            observation is moved there to act, the action back to the env's device, where the batches stay. The
            other backends act with a CPU copy of ``policy``, whatever its device.
    """
    check_collection(workers, backend, sync)
    backend = resolve_backend(backend, workers)
    common = dict(total_frames=total_frames, exploration_type=ExplorationType.RANDOM)
    if backend == "direct":
        if env is None:
            env = make_env(seed)
            env.set_seed(seed)
        devices = {}
        if policy_device is not None and torch.device(policy_device) != env.device:
            devices = dict(policy_device=torch.device(policy_device), env_device=env.device, storing_device=env.device)
        collector = Collector(env, policy, frames_per_batch=frames_per_worker, auto_register_policy_transforms=False,
                              **devices, **common)
        if collector.policy is not policy:  # TorchRL acts with a copy of a policy that is not wholly on policy_device
            raise RuntimeError(f"the direct collector must act with the learner's policy itself: move it wholly to "
                               f"{policy_device} first")
        return collector
    factories = [WorkerEnv(make_env, s) for s in worker_seeds(seed, workers)]
    policy = copy.deepcopy(policy).cpu()  # the workers' copy (CPU); the learner's tensors stay out of shared memory
    if backend == "process":
        collector = Collector(factories, policy, backend="process", sync=sync, frames_per_batch=frames_per_worker * workers,
                              cat_results="stack", auto_register_policy_transforms=False, **common)
    else:
        try:
            import ray
        except ImportError as e:
            raise MissingExtraError("the ray backend needs Ray: pip install 'maniskill_pnp[ray]'") from e
        # Ray schedules the workers by CPUs only (TorchRL's default also reserves 2 GiB each; a 224 px clutter env
        # needs about 1.4 GB); ray.init joins RAY_ADDRESS's cluster when that is set, else starts a local instance.
        collector = Collector(factories, policy, backend="ray", sync=True, frames_per_batch=frames_per_worker * workers,
                              remote_configs=dict(num_cpus=1), ray_init_config=RAY_INIT,
                              collector_kwargs=dict(auto_register_policy_transforms=False), **common)
        # Every worker has built its env before the first weight sync: TorchRL's rendezvous gives the workers 60 s from
        # its start, which a worker's start-up on a loaded machine can exceed.
        ray.get([worker.__ray_ready__.remote() for worker in collector.remote_collectors])
    collector.update_policy_weights_()  # the workers start from the learner's weights, not their pickled copy
    return collector


def sync_weights(collector: BaseCollector, policy: torch.nn.Module) -> None:
    """Copy the learner's ``policy`` weights and buffers (ε included) into the workers' copy, on the CPU (from a CUDA
    learner too); nothing to do for ``direct``, which acts with ``policy`` itself.

    Process workers act with that copy's shared memory, so the copy is all they need: a synchronous collector's
    workers are idle between batches and read it when the next batch is asked for (TorchRL's own
    ``update_policy_weights_`` would add a round trip of about 20 ms to tell them so). Ray workers get the copy sent.
    """
    if type(collector) is Collector:
        return
    with torch.no_grad():
        TensorDict.from_module(collector.policy).update_(TensorDict.from_module(policy).apply(torch.Tensor.cpu))
    if not isinstance(collector, (MultiSyncCollector, MultiAsyncCollector)):
        collector.update_policy_weights_()


def streams(batch: TensorDictBase) -> Iterator[tuple[tuple[int, int], TensorDictBase]]:
    """Split a collector batch into runs of consecutive frames of one trajectory, in time order.

    Yields ``((row, traj_id), frames)``: ``row`` is the batch row (the worker, in a synchronous multi-worker batch;
    0 otherwise) and ``traj_id`` TorchRL's trajectory id, so the pair names one episode of one worker even when
    Ray workers number their trajectories independently. ``frames`` is flat (1-D).
    """
    rows = batch.reshape(-1, batch.shape[-1]) if batch.ndim > 1 else batch.reshape(1, -1)
    for r in range(rows.shape[0]):
        row = rows[r]
        ids = row.get(TRAJ_KEY) if TRAJ_KEY in row.keys(True) else torch.zeros(row.shape[0], dtype=torch.long)
        start = 0
        for i in range(1, row.shape[0] + 1):
            if i == row.shape[0] or ids[i] != ids[start]:
                yield (r, int(ids[start])), row[start:i]
                start = i


__all__ = [
    "BACKENDS", "WORKER_SEED_STRIDE", "WorkerEnv", "check_collection", "make_collector", "resolve_backend", "seed_process",
    "streams",
    "sync_weights", "worker_seeds",
]
