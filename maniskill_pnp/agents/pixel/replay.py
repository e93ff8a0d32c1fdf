"""Prioritized replay of pixelwise transitions, with heightmaps stored compactly on disk.

A heightmap ``(..., 4, H, W)`` (RGB in 0..1, height in metres) is stored as ``"color"`` (uint8, ``(..., 3, H, W)``)
and ``"height"`` (float16, ``(..., 1, H, W)``): 5 bytes per pixel instead of 16. :func:`pack` / :func:`unpack`
convert one heightmap batch; :func:`pack_transition` / :func:`unpack_transition` convert the ``"observation"``
and ``("next", "observation")`` entries of a transition tensordict; :func:`to_transitions` turns collector frames
into those transitions.

Example:
    >>> rb = make_pixel_replay(capacity=1000, scratch_dir=tmp, batch_size=8)  # doctest: +SKIP
    >>> rb.extend(pack_transition(transitions))                            # doctest: +SKIP
    >>> batch = unpack_transition(rb.sample())                              # doctest: +SKIP
    >>> loss(batch); rb.update_tensordict_priority(batch)                   # doctest: +SKIP
"""

from __future__ import annotations

import os

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import LazyMemmapStorage, TensorDictPrioritizedReplayBuffer

from maniskill_pnp.agents.pixel.policy import FIT_KEY, heightmap_input

_OBS_KEYS = ("observation", ("next", "observation"))


def to_transitions(batch: TensorDictBase) -> TensorDict:
    """Flat collector frames -> the transitions the loss reads (heightmap ``"observation"`` built from the env keys;
    where the env observes fit heightmaps, the next state's as float16 ``("next", "fit_heightmap")``, for the
    bootstrap's action mask)."""
    nxt = batch.get("next")
    n = batch.batch_size[0]
    out = TensorDict(
        {
            "observation": heightmap_input(batch.get("color_heightmap"), batch.get("depth_heightmap")),
            "action": batch.get("action").reshape(n),
            "next": {
                "observation": heightmap_input(nxt.get("color_heightmap"), nxt.get("depth_heightmap")),
                "reward": nxt.get("reward").reshape(n),
                "terminated": nxt.get("terminated").reshape(n),
                "done": nxt.get("done").reshape(n),
            },
        },
        batch_size=[n],
    )
    fit = nxt.get(FIT_KEY, default=None)
    if fit is not None:
        out.set(("next", FIT_KEY), fit.to(torch.float16))
    return out


def pack(obs: torch.Tensor) -> TensorDict:
    """Compact form of heightmaps ``(*B, 4, H, W)``: ``{"color": uint8 (*B, 3, H, W), "height": float16 (*B, 1, H, W)}``.

    Colours are clamped to 0..1 and rounded to 1/255; heights keep float16 precision (about 1e-4 m at 0.3 m).
    """
    if obs.ndim < 3 or obs.shape[-3] != 4:
        raise ValueError(f"heightmaps must be (..., 4, H, W) (RGB + height), got {tuple(obs.shape)}")
    color = (obs[..., :3, :, :].clamp(0.0, 1.0) * 255.0).round().to(torch.uint8)
    height = obs[..., 3:, :, :].to(torch.float16)
    return TensorDict(color=color, height=height, batch_size=obs.shape[:-3])


def unpack(td: TensorDictBase) -> torch.Tensor:
    """Float32 heightmaps ``(*B, 4, H, W)`` of a :func:`pack` tensordict."""
    color = td.get("color").to(torch.float32) / 255.0
    return torch.cat([color, td.get("height").to(torch.float32)], dim=-3)


def pack_transition(td: TensorDictBase) -> TensorDictBase:
    """A shallow copy of ``td`` whose ``"observation"`` and ``("next", "observation")`` (where present) are packed."""
    out = td.copy()
    for key in _OBS_KEYS:
        obs = td.get(key, default=None)
        if obs is not None:
            out.set(key, pack(obs))
    return out


def unpack_transition(td: TensorDictBase) -> TensorDictBase:
    """Inverse of :func:`pack_transition` (other entries, e.g. the buffer's ``"index"``, are kept)."""
    out = td.copy()
    for key in _OBS_KEYS:
        packed = td.get(key, default=None)
        if packed is not None:
            out.set(key, unpack(packed))
    return out


def make_pixel_replay(
    capacity: int,
    scratch_dir: str | os.PathLike | None,
    alpha: float = 0.6,
    beta: float = 0.4,
    *,
    batch_size: int,
    priority_key: str = "td_error",
) -> TensorDictPrioritizedReplayBuffer:
    """A prioritized replay buffer (Schaul et al.) over a memory-mapped storage of packed transitions.

    Args:
        capacity: Maximum number of transitions kept (oldest overwritten first).
        scratch_dir: Directory of the memory-mapped files (None: a temporary directory).
        alpha: Priority exponent (0: uniform sampling).
        beta: Importance-sampling exponent of the ``"priority_weight"`` the buffer returns.
        batch_size: Transitions per ``sample()``.
        priority_key: Key the loss writes the TD error to; ``update_tensordict_priority`` reads it.
    """
    if capacity <= 0:
        raise ValueError(f"capacity must be positive, got {capacity!r}")
    if batch_size <= 0:
        raise ValueError(f"batch_size must be positive, got {batch_size!r}")
    if alpha < 0:
        raise ValueError(f"alpha must be >= 0, got {alpha!r}")
    if beta < 0:
        raise ValueError(f"beta must be >= 0, got {beta!r}")
    storage = LazyMemmapStorage(capacity, scratch_dir=scratch_dir)
    return TensorDictPrioritizedReplayBuffer(
        alpha=alpha, beta=beta, storage=storage, batch_size=batch_size, priority_key=priority_key
    )
