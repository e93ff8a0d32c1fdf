"""Checkpoints of a pixelwise DQN run: what a resumed run needs, written so that a crash never leaves half a file.

A run folder holds ``checkpoint.pt`` (``torch.save`` of a dict in the format :data:`CHECKPOINT_FORMAT`: config,
network, loss (with its target network), optimizer, ε schedule, counters, RNG states and the name of the replay
folder) and, with ``save_replay``, ``replay_step<N>/``: TorchRL's ``ReplayBuffer.dumps`` of the replay's storage,
priorities and writer at step ``N``. :func:`write_checkpoint` dumps the replay first, then replaces the checkpoint
atomically, then deletes older replay folders, so a crash at any moment leaves a checkpoint and the replay folder
it names.

:func:`export_weights` makes a shareable agent of a checkpoint: config, counters and network weights only.
"""

from __future__ import annotations

import dataclasses
import random
import shutil
from pathlib import Path

import numpy as np
import torch

from maniskill_pnp.agents.run_io import atomic_write_bytes

CHECKPOINT_FORMAT = "maniskill_pnp.clutter_dqn/1"
#: The checkpoint file's name inside a run folder.
CHECKPOINT_NAME = "checkpoint.pt"


def checkpoint_file(path: Path) -> Path:
    """The checkpoint file of ``path``: ``checkpoint.pt`` inside it when it is a run folder, else ``path`` itself."""
    path = Path(path)
    return path / CHECKPOINT_NAME if path.is_dir() else path


def rng_state() -> dict:
    """The states of torch's, Python's and numpy's global RNGs (tensors and plain values: ``weights_only`` loadable)."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    return dict(
        torch=torch.get_rng_state(), python=random.getstate(),
        numpy=dict(kind=kind, keys=torch.from_numpy(keys.astype(np.int64)), pos=pos, has_gauss=has_gauss, cached=cached),
    )


def set_rng_state(state: dict) -> None:
    """Restore the global RNGs from :func:`rng_state`."""
    torch.set_rng_state(state["torch"])
    random.setstate(state["python"])
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"]))


def save_checkpoint(path: Path, *, cfg, model, loss, optimizer, egreedy, counters: dict, replay_meta: dict) -> None:
    """``torch.save`` everything a resumed run needs, atomically (temp file + ``os.replace``)."""
    payload = dict(
        format=CHECKPOINT_FORMAT, config=cfg.to_json(), model=model.state_dict(), loss=loss.state_dict(),
        optimizer=optimizer.state_dict(), egreedy=egreedy.state_dict(), counters=dict(counters),
        rng=rng_state(), replay=dict(replay_meta),
    )
    atomic_write_bytes(path, lambda f: torch.save(payload, f))


def load_checkpoint(path: Path) -> dict:
    """The payload of :func:`save_checkpoint` (``path``: the file or its run folder); ValueError naming the file if
    it is not one."""
    path = checkpoint_file(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for truncated / foreign files
        first_line = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise ValueError(f"checkpoint {path} is unreadable (truncated or not a torch.save file): {first_line}") from e
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"checkpoint {path} is not a clutter DQN checkpoint (expected format {CHECKPOINT_FORMAT!r})")
    return payload


def write_checkpoint(run_dir: Path, *, cfg, replay, counters: dict, model, loss, optimizer, egreedy) -> None:
    """The run's checkpoint: with ``cfg.save_replay`` the replay's contents into ``replay_step<N>/`` first, then
    ``checkpoint.pt`` (naming that folder), then the older replay folders are removed."""
    replay_meta = dict(size=len(replay), capacity=cfg.replay_capacity, dir=None)
    if cfg.save_replay:
        replay_meta["dir"] = f"replay_step{counters['steps']}"
        shutil.rmtree(run_dir / replay_meta["dir"], ignore_errors=True)
        replay.dumps(run_dir / replay_meta["dir"])
    save_checkpoint(run_dir / CHECKPOINT_NAME, cfg=cfg, model=model, loss=loss, optimizer=optimizer, egreedy=egreedy,
                    counters=counters, replay_meta=replay_meta)
    for old in run_dir.glob("replay_step*"):
        if old.name != replay_meta["dir"]:
            shutil.rmtree(old, ignore_errors=True)


def restore(payload: dict, run_dir: Path, *, replay, model, loss, optimizer, egreedy) -> None:
    """Load a checkpoint's state into a freshly built run: the replay folder it names (ValueError if that is
    missing), network, loss, optimizer, ε schedule and the global RNG states."""
    saved_replay = payload["replay"].get("dir")
    if saved_replay:
        if not (run_dir / saved_replay).is_dir():
            raise ValueError(f"cannot resume {run_dir / CHECKPOINT_NAME}: its replay folder {run_dir / saved_replay} is missing")
        replay.loads(run_dir / saved_replay)
    model.load_state_dict(payload["model"])
    loss.load_state_dict(payload["loss"])
    optimizer.load_state_dict(payload["optimizer"])
    egreedy.load_state_dict(payload["egreedy"])
    set_rng_state(payload["rng"])


#: Config fields an exported agent may change: how it acts, not what it learned.
ACTING_FIELDS = ("slide_margin", "mask_grasp_fit", "mask_fit_scale", "mask_keep_in", "mask_reach")


def export_weights(checkpoint: Path, dest: Path, half: bool = True, **acting) -> Path:
    """A shareable agent from a training checkpoint: only its config, counters and network weights (float16 with
    ``half``), in the checkpoint format, so ``eval-clutter`` and ``record-clutter`` load it like the original.
    Optimizer, target network, RNG and replay are dropped: it cannot be resumed. ``acting`` sets fields of
    :data:`ACTING_FIELDS` in the exported config (e.g. ``slide_margin=0.5``), so the agent acts that way by default.

    Raises:
        ValueError: a field outside :data:`ACTING_FIELDS`, or a value its config rejects.
    """
    from maniskill_pnp.agents.pixel.config import ClutterConfig

    unknown = sorted(set(acting) - set(ACTING_FIELDS))
    if unknown:
        raise ValueError(f"an exported agent may change only {ACTING_FIELDS}, got {unknown}")
    payload = load_checkpoint(checkpoint)
    config = payload["config"]
    if acting:
        config = dataclasses.replace(ClutterConfig.from_json(config), **acting).to_json()
    model = {k: v.half() if half and v.is_floating_point() else v for k, v in payload["model"].items()}
    slim = dict(format=CHECKPOINT_FORMAT, config=config, model=model, counters=payload.get("counters", {}))
    atomic_write_bytes(Path(dest), lambda f: torch.save(slim, f))
    return Path(dest)


__all__ = [
    "ACTING_FIELDS", "CHECKPOINT_FORMAT", "CHECKPOINT_NAME", "checkpoint_file", "export_weights", "load_checkpoint", "restore",
    "rng_state", "save_checkpoint", "set_rng_state", "write_checkpoint",
]
