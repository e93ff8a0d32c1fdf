"""TorchRL actors over pixelwise Q maps: greedy argmax of a heightmap Q network, and its ε-greedy exploration.

The env (e.g. ``ClutterGrasp-v1`` through :func:`~maniskill_pnp.torchrl_env.make_torchrl_env`) observes
``"color_heightmap"`` (uint8 ``(*B, H, W, 3)``) and ``"depth_heightmap"`` (float32 ``(*B, H, W)``, metres above the
table). :func:`heightmap_input` turns them into the network input ``(*B, 4, H, W)`` (RGB in 0..1, height), the
``"observation"`` that :class:`~maniskill_pnp.agents.pixel_loss.PixelDQNLoss` and the replay buffer use.

Tensordict keys of the actor:

======================= ============================================================================ ==========
key                     meaning                                                                      read/write
======================= ============================================================================ ==========
``"color_heightmap"``   uint8 ``(*B, H, W, 3)``                                                       read
``"depth_heightmap"``   float32 ``(*B, H, W)``                                                        read
``"action_value"``      the maps flattened row-major: ``(*B, P*R*H*W)``                               written
``"action"``            int64 ``(*B,)``: the argmax flat index (``PixelActionLayout``'s index)         written
``"action_mask"``       bool ``(*B, P*R*H*W)``: the actions allowed (only with an ``action_mask``)      written
======================= ============================================================================ ==========

With an ``action_mask`` (e.g. :class:`~maniskill_pnp.agents.pixel_mask.HeightmapActionMask`) the argmax and the
ε-random action both range over the allowed actions only.

Exploration is TorchRL's :class:`~torchrl.modules.EGreedyModule` over the env's ``Categorical`` action spec: with
probability ε it replaces the action by ``spec.rand()``, a single ``torch.randint`` over the flat index range, so
a 800k-way action costs nothing more than a 2-way one (no one-hot is ever built).
"""

from __future__ import annotations

from typing import Callable

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Categorical, TensorSpec
from torchrl.modules import EGreedyModule

HEIGHTMAP_KEYS = ("color_heightmap", "depth_heightmap")


def heightmap_input(color: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """Network input ``(*B, 4, H, W)`` from colour ``(*B, H, W, 3)`` (uint8 0..255) and height ``(*B, H, W)`` (m)."""
    if color.shape[-1] != 3 or color.shape[:-1] != depth.shape:
        raise ValueError(
            f"need color (*B, H, W, 3) and depth (*B, H, W) of the same H, W; got {tuple(color.shape)}, {tuple(depth.shape)}"
        )
    rgb = color.movedim(-1, -3).to(torch.float32) / 255.0
    return torch.cat([rgb, depth.unsqueeze(-3).to(torch.float32)], dim=-3)


class GreedyPixelActor(nn.Module):
    """Heightmaps -> (flattened maps, argmax flat index) with a pixel Q network.

    Args:
        q_network: ``(N, 4, H, W) -> (N, *action_shape)``, e.g. a
            :class:`~maniskill_pnp.agents.pixel_fcn.MultiPrimitiveQNetwork` (``(N, P, R, H, W)``).
        action_mask: Optional ``height (*B, H, W) -> bool (*B, P*R*H*W)``; the argmax skips masked-out actions
            and the mask is returned as a third output.
    """

    def __init__(self, q_network: nn.Module, action_mask: Callable[[torch.Tensor], torch.Tensor] | None = None):
        super().__init__()
        self.q_network = q_network
        self.action_mask = action_mask

    def forward(self, color: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor, ...]:
        x = heightmap_input(color, depth)
        batch = x.shape[:-3]
        maps = self.q_network(x.reshape(-1, *x.shape[-3:]))
        values = maps.reshape(*batch, -1)
        if self.action_mask is None:
            return values, values.argmax(dim=-1)
        mask = self.action_mask(depth.to(torch.float32))
        return values, values.masked_fill(~mask, float("-inf")).argmax(dim=-1), mask


def make_pixel_policy(
    q_network: nn.Module,
    action_spec: TensorSpec,
    *,
    eps_init: float,
    eps_end: float,
    annealing_num_steps: int,
    action_mask: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> tuple[TensorDictModule, TensorDictSequential, EGreedyModule]:
    """The greedy pixel actor and the same actor with ε-greedy exploration.

    Args:
        q_network: The pixel Q network (shared with the loss, not copied).
        action_spec: The env's ``Categorical`` action spec (batched or unbatched) over the flat pixel index.
        eps_init, eps_end, annealing_num_steps: Linear ε schedule; call ``egreedy.step(frames)`` after each batch.
        action_mask: Optional ``height (*B, H, W) -> bool (*B, P*R*H*W)``: greedy and random actions are drawn
            among the allowed ones (written to ``"action_mask"``, which ``EGreedyModule`` reads).

    Returns:
        ``(greedy, explore, egreedy)``; both policies read :data:`HEIGHTMAP_KEYS` and write ``"action_value"`` and
        ``"action"``.

    Example:
        >>> greedy, explore, egreedy = make_pixel_policy(net, env.action_spec, eps_init=0.3, eps_end=0.1,
        ...                                              annealing_num_steps=1000)  # doctest: +SKIP
        >>> explore(env.reset())["action"]                                            # doctest: +SKIP
    """
    if not isinstance(action_spec, Categorical):
        raise TypeError(f"a pixel policy needs a Categorical action spec, got {type(action_spec).__name__}")
    out_keys = ["action_value", "action"] + (["action_mask"] if action_mask is not None else [])
    greedy = TensorDictModule(GreedyPixelActor(q_network, action_mask), in_keys=list(HEIGHTMAP_KEYS), out_keys=out_keys)
    egreedy = EGreedyModule(
        spec=action_spec.clone(),
        eps_init=float(eps_init),
        eps_end=float(eps_end),
        annealing_num_steps=int(annealing_num_steps),
        action_mask_key="action_mask" if action_mask is not None else None,
    )
    return greedy, TensorDictSequential(greedy, egreedy), egreedy


__all__ = ["HEIGHTMAP_KEYS", "GreedyPixelActor", "heightmap_input", "make_pixel_policy"]
