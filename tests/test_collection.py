"""Collection with several env workers: TorchRL's process collectors over every task, the Ray collector with 2 local
workers, and both recipes learning from multi-worker batches (seeds per worker recorded)."""

from __future__ import annotations

import json
from functools import partial

import pytest
import torch
from tensordict import TensorDict

from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.metrics import ACTION_COLUMNS
from maniskill_pnp.agents.pixel.recipe import main as train_clutter
from maniskill_pnp.agents.collection import (
    WORKER_SEED_STRIDE, check_collection, make_collector, resolve_backend, streams, sync_weights, worker_seeds,
)
from maniskill_pnp.agents.pixel.factories import make_action_mask, make_env, make_model, make_policy, make_worker_env
from maniskill_pnp.agents.pixel.replay import NEXT_MASK_KEY, NextMaskJoin
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, load_qtable
from maniskill_pnp.agents.tabular.recipe import main as train_conveyor
from maniskill_pnp.bench.scale import COLLECTION_TASKS, collection_setup

TINY = dict(heightmap_size=32, num_rotations=2, num_objects=2)


@pytest.mark.parametrize("workers, backend, sync, message", [
    (0, "auto", True, "workers must be an integer >= 1, got 0"),
    (2, "mpi", True, "unknown collector backend 'mpi'"),
    (2, "direct", True, "the direct collector runs one env in this process"),
    (2, "ray", False, "the ray backend needs sync=True"),
])
def test_bad_collection_settings_name_the_problem(workers, backend, sync, message):
    with pytest.raises(ValueError, match=message):
        check_collection(workers, backend, sync)
    with pytest.raises(ValueError, match=message):  # the recipes check before building anything
        ConveyorConfig(workers=workers, collector=backend, sync=sync)


def test_backend_and_worker_seeds():
    assert resolve_backend("auto", 1) == "direct" and resolve_backend("auto", 2) == "process"
    assert resolve_backend("auto", 1, single="process") == "process"
    assert resolve_backend("direct", 1, single="process") == "direct"
    assert resolve_backend("ray", 1) == "ray"
    assert worker_seeds(5, 3) == [5, 5 + WORKER_SEED_STRIDE, 5 + 2 * WORKER_SEED_STRIDE]


def test_streams_tell_workers_and_episodes_apart():
    # two workers of a synchronous batch, numbering their trajectories independently (as Ray workers do);
    # worker 1 starts a new episode at its third frame
    ids = torch.tensor([[0, 0, 0, 0], [0, 0, 1, 1]])
    batch = TensorDict({"x": torch.arange(8).reshape(2, 4), "collector": {"traj_ids": ids}}, [2, 4])
    assert [(k, f["x"].tolist()) for k, f in streams(batch)] == [((0, 0), [0, 1, 2, 3]), ((1, 0), [4, 5]),
                                                                 ((1, 1), [6, 7])]
    flat = TensorDict({"x": torch.arange(3)}, [3])  # no trajectory ids: one stream
    assert [(k, f["x"].tolist()) for k, f in streams(flat)] == [((0, 0), [0, 1, 2])]


@pytest.mark.parametrize("task", COLLECTION_TASKS)
def test_two_worker_processes_give_well_formed_batches(task):
    make_env, policy = collection_setup(task, seed=3, **TINY)
    collector = make_collector(make_env, policy, seed=3, total_frames=4, workers=2, backend="process")
    try:
        batches = [b.clone() for b in collector]
    finally:
        collector.shutdown()
    assert len(batches) == 2
    obs_keys = ("observation",) if task == "conveyor" else ("color_heightmap", "depth_heightmap")
    for batch in batches:
        assert batch.shape[0] == 2 and batch.numel() == 2  # one frame of each worker
        for key in ("action", ("next", "reward"), ("next", "done"), ("collector", "traj_ids"), *obs_keys,
                    *(("next", k) for k in obs_keys)):
            assert key in batch.keys(True), key
        assert torch.isfinite(batch.get(("next", "reward")).float()).all()
        assert (batch.get("action") >= 0).all()
    first = batches[0]
    ids = first.get(("collector", "traj_ids")).reshape(2)
    assert ids[0] != ids[1]  # the process workers share one trajectory counter
    if task != "conveyor":  # different seeds, different clutters
        depth = first.get("depth_heightmap").reshape(2, -1)
        assert not torch.equal(depth[0], depth[1])
        assert depth.shape[1] == TINY["heightmap_size"] ** 2
        assert_transitions_join_the_masks_their_actors_computed(task, batches)


def assert_transitions_join_the_masks_their_actors_computed(task: str, batches: list) -> None:
    """Each transition of the workers' batches goes into the replay with its next state's action mask: the one the
    worker's actor computed acting there (a continuing episode's, found in the next batch), computed only for the
    ends of episodes and the last batch; either way the mask of the next heightmap."""
    mask = make_action_mask(ClutterConfig.from_preset("cpu-small" if task == "clutter" else "gs-cpu-small", **TINY))
    computed = []
    join = NextMaskJoin(lambda height, *fit: computed.append(len(height)) or mask(height, *fit), hold=2)
    joined = [join.push(batches[0].reshape(-1)), join.push(batches[1].reshape(-1)), join.flush()]
    joined = torch.cat([t for t in joined if t is not None])
    assert joined.numel() == 4 and sum(computed) == 2 + int(batches[0].get(("next", "done")).sum())
    assert torch.equal(joined[NEXT_MASK_KEY], mask.from_observation(joined["next", "observation"]))


def test_conveyor_recipe_learns_from_two_worker_processes(tmp_path):
    cfg = ConveyorConfig(steps=12, frames_per_batch=3, workers=2, log_interval=6, seed=2, out=tmp_path)
    summary = train_conveyor(cfg)
    assert summary["steps"] == 12 and summary["episodes"] >= 2
    assert summary["collection"] == dict(backend="process", workers=2, sync=True, worker_seeds=[2, 2 + WORKER_SEED_STRIDE])
    table, _, _ = load_qtable(cfg.run_dir)
    assert (table.values != cfg.q_init).any()  # the TD updates reached the table
    assert json.loads((cfg.run_dir / "train_summary.json").read_text())["collection"]["workers"] == 2


def test_clutter_recipe_with_two_workers_then_resumed_with_one(tmp_path):
    cfg = ClutterConfig.from_preset("gs-cpu-small", **TINY, steps=4, workers=2, checkpoint_interval=3, log_interval=1,
                                    out=tmp_path)
    summary = train_clutter(cfg)
    assert summary["steps"] == 4 and summary["updates"] == 4 * cfg.updates_per_step
    assert summary["collection"]["worker_seeds"] == [0, WORKER_SEED_STRIDE]
    rows = (cfg.run_dir / "actions.csv").read_text().splitlines()
    assert rows[0] == ",".join(ACTION_COLUMNS) and [int(r.split(",")[0]) for r in rows[1:]] == [1, 2, 3, 4]
    resumed = train_clutter(ClutterConfig.from_json({**cfg.to_json(), "steps": 6, "workers": 1, "resume": True}))
    assert resumed["start_step"] == 4 and resumed["steps"] == 6 and resumed["collection"]["backend"] == "process"
    assert len((cfg.run_dir / "actions.csv").read_text().splitlines()) == 1 + 6


def _worker_actions(flip_after: int | None) -> list[int]:
    """Actions of a one-worker process collector of an untrained gs-cpu-equi actor over 6 batches; with
    ``flip_after``, the learner's weights are negated after that many batches and pushed with sync_weights after
    batch 3 (what the workers see of learner updates that are not yet synced, and of a sync)."""
    cfg = ClutterConfig.from_preset("gs-cpu-equi", **TINY)
    torch.manual_seed(0)
    env = make_env(cfg)
    _, explore, _ = make_policy(cfg, make_model(cfg).eval(), env.action_spec)
    env.close()
    collector = make_collector(partial(make_worker_env, cfg), explore, seed=0, total_frames=6, workers=1,
                               backend="process")
    actions = []
    try:
        for i, batch in enumerate(collector):
            actions.append(int(batch.get("action").reshape(-1)[0]))
            if i + 1 == flip_after:
                with torch.no_grad():
                    for p in explore.parameters():
                        p.neg_()
            elif flip_after is not None and i + 1 == 3:
                sync_weights(collector, explore)
    finally:
        collector.shutdown()
    return actions


def test_process_workers_act_with_the_weights_of_the_last_sync():
    base, flipped = _worker_actions(None), _worker_actions(1)
    assert flipped[:3] == base[:3]  # negated in the learner after batch 1: batches 2 and 3 still use the old copy
    assert flipped[3:] != base[3:]  # synced after batch 3: batches 4 to 6 act with the negated weights


def test_default_clutter_collection_overlaps_learning_and_repeats_from_its_seed(tmp_path):
    """The default collector of a clutter run: one worker process, the learner updating on each batch while the
    worker collects the next; two runs of one seed take the same actions and learn the same weights."""
    runs = []
    for name in ("a", "b"):
        cfg = ClutterConfig.from_preset("gs-cpu-equi", **TINY, steps=6, learning_starts=1, checkpoint_interval=6,
                                        out=tmp_path / name)
        summary = train_clutter(cfg)
        runs.append((summary, (cfg.run_dir / "actions.csv").read_text(), torch.load(cfg.run_dir / "checkpoint.pt",
                                                                                     weights_only=False)["model"]))
    (a, actions_a, model_a), (b, actions_b, model_b) = runs
    assert a["collection"] == dict(backend="process", workers=1, sync=True, overlap=True, worker_seeds=[0])
    assert a["updates"] == b["updates"] == 6 * cfg.updates_per_step  # every update ran, the last one's included
    assert actions_a == actions_b and len(actions_a.splitlines()) == 7
    assert model_a.keys() == model_b.keys() and all(torch.equal(model_a[k], model_b[k]) for k in model_a)


@pytest.mark.ray
def test_ray_collects_from_two_local_workers(tmp_path):
    import ray

    cfg = ConveyorConfig(steps=12, frames_per_batch=3, workers=2, collector="ray", log_interval=6, seed=4, out=tmp_path)
    try:
        summary = train_conveyor(cfg)
    finally:
        ray.shutdown()
    assert summary["steps"] == 12 and summary["episodes"] >= 2
    assert summary["collection"] == dict(backend="ray", workers=2, sync=True, worker_seeds=[4, 4 + WORKER_SEED_STRIDE])
    table, _, _ = load_qtable(cfg.run_dir)
    assert (table.values != cfg.q_init).any()
