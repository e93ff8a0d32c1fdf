"""Prioritized replay of pixelwise transitions, with heightmaps stored compactly on disk.

A heightmap ``(..., 4, H, W)`` (RGB in 0..1, height in metres) is stored as ``"color"`` (uint8, ``(..., 3, H, W)``)
and ``"height"`` (float16, ``(..., 1, H, W)``): 5 bytes per pixel instead of 16. :func:`pack` / :func:`unpack`
convert one heightmap batch; :func:`pack_transition` / :func:`unpack_transition` convert the ``"observation"``
and ``("next", "observation")`` entries of a transition tensordict (and the next state's action mask, where there is
one, to bits and back); :func:`to_transitions` turns collector frames into those transitions, and
:class:`NextMaskJoin` gives each the action mask its actor computed in the next state, so that the learner's
bootstrap need not compute it again.

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
#: The next state's action mask of a transition, bool ``(*B, P*R*H*W)`` (the key the DQN loss reads), and the bits
#: it is stored as (uint8 ``(*B, P*R*H*W / 8)``).
NEXT_MASK_KEY = ("next", "action_mask")
_NEXT_MASK_BITS = ("next", "action_mask_bits")
_BIT_WEIGHTS = torch.tensor([128, 64, 32, 16, 8, 4, 2, 1], dtype=torch.uint8)


def to_transitions(batch: TensorDictBase, keep_fit: bool = True) -> TensorDict:
    """Flat collector frames -> the transitions the loss reads (heightmap ``"observation"`` built from the env keys;
    with ``keep_fit``, where the env observes fit heightmaps, the next state's as float16 ``("next", "fit_heightmap")``,
    for a bootstrap that computes the action mask itself)."""
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
    if fit is not None and keep_fit:
        out.set(("next", FIT_KEY), fit.to(torch.float16))
    return out


class NextMaskJoin:
    """Joins each transition with the action mask of its next state: the mask the actor computed when it acted there
    (the root ``"action_mask"`` of the frame whose heightmaps are the transition's next ones, in this batch or a later
    one), so that the bootstrap over the allowed actions needs no mask of its own. The next state of an episode's last
    transition is never acted in; its mask is computed with ``mask``, as is that of a transition that waited for more
    than ``hold`` others.

    Args:
        mask: The action mask the actor acts under (e.g.
            :class:`~maniskill_pnp.agents.pixel.mask.HeightmapActionMask`): ``(height, fit=None) -> bool (*B, A)``.
        hold: Transitions at most waiting for their next frame (a synchronous collector's batch of ``n`` frames
            needs ``n``; an asynchronous one's more).
    """

    def __init__(self, mask, hold: int):
        if hold < 1:
            raise ValueError(f"hold must be >= 1, got {hold!r}")
        self.mask, self.hold = mask, hold
        self.waiting: list[tuple[TensorDict, torch.Tensor | None]] = []  # (transition, its next fit heightmap)

    def push(self, frames: TensorDictBase) -> TensorDict | None:
        """The transitions of flat collector ``frames`` and of the earlier ones that are complete now, each with its
        :data:`NEXT_MASK_KEY` (None when none is)."""
        if "action_mask" not in frames.keys():
            raise KeyError("the frames hold no 'action_mask': the actor acts under no mask, so there is none to join")
        transitions, masks = to_transitions(frames, keep_fit=False), frames.get("action_mask")
        next_fit = frames.get("next").get(FIT_KEY, default=None)
        ready, computed = [], []
        for j in range(frames.batch_size[0]):
            acted_in = transitions[j]["observation"]
            for k, (t, _) in enumerate(self.waiting):  # frame j acts in the state a waiting transition ends in
                if torch.equal(t["next", "observation"], acted_in):
                    ready.append(t.set(NEXT_MASK_KEY, masks[j].reshape(-1)))
                    del self.waiting[k]
                    break
            waiting = (transitions[j], None if next_fit is None else next_fit[j])
            (computed if bool(transitions[j]["next", "done"]) else self.waiting).append(waiting)
        while len(self.waiting) > self.hold:
            computed.append(self.waiting.pop(0))
        return self._stack(ready + self._computed(computed))

    def flush(self) -> TensorDict | None:
        """Every waiting transition, its next mask computed (before a checkpoint, and at the end of a run)."""
        waiting, self.waiting = self.waiting, []
        return self._stack(self._computed(waiting))

    def _computed(self, waiting: list) -> list[TensorDict]:
        if not waiting:
            return []
        height = torch.stack([t["next", "observation"][3] for t, _ in waiting])
        fits = [f for _, f in waiting]
        fit = () if fits[0] is None else (torch.stack(fits).to(torch.float32),)
        masks = self.mask(height, *fit)
        return [t.set(NEXT_MASK_KEY, m.reshape(-1)) for (t, _), m in zip(waiting, masks)]

    @staticmethod
    def _stack(transitions: list[TensorDict]) -> TensorDict | None:
        return torch.stack(transitions) if transitions else None


def pack_bits(mask: torch.Tensor) -> torch.Tensor:
    """uint8 ``(*B, A / 8)`` of bool ``(*B, A)``, 8 flags a byte (most significant first); ``A`` must be a multiple of 8."""
    if mask.shape[-1] % 8:
        raise ValueError(f"a mask of {mask.shape[-1]} actions does not split into bytes (a multiple of 8 is needed)")
    grouped = mask.reshape(*mask.shape[:-1], -1, 8).to(torch.uint8)
    return (grouped * _BIT_WEIGHTS.to(mask.device)).sum(dim=-1, dtype=torch.uint8)


def unpack_bits(bits: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`pack_bits`: bool ``(*B, 8 * bytes)``."""
    flags = bits.unsqueeze(-1).bitwise_and(_BIT_WEIGHTS.to(bits.device)) != 0
    return flags.reshape(*bits.shape[:-1], -1)


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
    """A shallow copy of ``td`` whose ``"observation"`` and ``("next", "observation")`` (where present) are packed,
    and whose :data:`NEXT_MASK_KEY` (where present) is stored as bits."""
    out = td.copy()
    for key in _OBS_KEYS:
        obs = td.get(key, default=None)
        if obs is not None:
            out.set(key, pack(obs))
    mask = td.get(NEXT_MASK_KEY, default=None)
    if mask is not None:
        out.set(_NEXT_MASK_BITS, pack_bits(mask))
        del out[NEXT_MASK_KEY]
    return out


def unpack_transition(td: TensorDictBase) -> TensorDictBase:
    """Inverse of :func:`pack_transition` (other entries, e.g. the buffer's ``"index"``, are kept)."""
    out = td.copy()
    for key in _OBS_KEYS:
        packed = td.get(key, default=None)
        if packed is not None:
            out.set(key, unpack(packed))
    bits = td.get(_NEXT_MASK_BITS, default=None)
    if bits is not None:
        out.set(NEXT_MASK_KEY, unpack_bits(bits))
        del out[_NEXT_MASK_BITS]
    return out


def holds_next_masks(replay) -> bool:
    """Whether ``replay`` may take transitions with their next masks: it is empty, or its transitions have them (a
    run resumed from a replay stored without them goes on computing them in the learner)."""
    return len(replay) == 0 or _NEXT_MASK_BITS in replay[:1].keys(include_nested=True)


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
