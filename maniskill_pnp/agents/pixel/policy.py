"""TorchRL actors over pixelwise Q maps: greedy argmax of a heightmap Q network, and its ε-greedy exploration.

The env (e.g. ``ClutterGrasp-v1`` through :func:`~maniskill_pnp.torchrl_env.make_torchrl_env`) observes
``"color_heightmap"`` (uint8 ``(*B, H, W, 3)``) and ``"depth_heightmap"`` (float32 ``(*B, H, W)``, metres above the
table). :func:`heightmap_input` turns them into the network input ``(*B, 4, H, W)`` (RGB in 0..1, height), the
``"observation"`` that :class:`~maniskill_pnp.agents.pixel.loss.PixelDQNLoss` and the replay buffer use.

Tensordict keys of the actor:

======================= ============================================================================ ==========
key                     meaning                                                                      read/write
======================= ============================================================================ ==========
``"color_heightmap"``   uint8 ``(*B, H, W, 3)``                                                       read
``"depth_heightmap"``   float32 ``(*B, H, W)``                                                        read
``"fit_heightmap"``     float32 ``(*B, k·H, k·W)``: the grasp-fit test's finer heights (only with       read
                        ``fit_heightmap=True``)
``"action_value"``      the maps flattened row-major: ``(*B, P*R*H*W)``                               written
``"action"``            int64 ``(*B,)``: the argmax flat index (``PixelActionLayout``'s index)         written
``"action_mask"``       bool ``(*B, P*R*H*W)``: the actions allowed (only with an ``action_mask``)      written
``"explore_mask"``      bool ``(*B, P*R*H*W)``: the allowed actions of the drawn primitive (only with  written
                        ``explore_weights``)
======================= ============================================================================ ==========

With an ``action_mask`` (e.g. :class:`~maniskill_pnp.agents.pixel.mask.HeightmapActionMask`) the argmax and the
ε-random action both range over the allowed actions only.

A uniform draw over the allowed actions gives each primitive a share proportional to its count of allowed pixels:
in a ``ClutterGraspSlide-v1`` scene about four random actions in five are slides. ``explore_weights`` (one weight
per primitive) sets the shares instead: :class:`PrimitiveExploreMask` first draws the primitive of each env by these
weights (among the primitives that have an allowed action), then ``EGreedyModule`` draws uniformly among that
primitive's allowed actions (the ``"explore_mask"`` it reads). The greedy action is untouched.

Exploration is TorchRL's :class:`~torchrl.modules.EGreedyModule` over the env's ``Categorical`` action spec: with
probability ε it replaces the action by ``spec.rand()``, a single ``torch.randint`` over the flat index range, so
a 800k-way action costs nothing more than a 2-way one (no one-hot is ever built).
"""

from __future__ import annotations

from typing import Callable, Sequence

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Categorical, TensorSpec
from torchrl.modules import EGreedyModule

HEIGHTMAP_KEYS = ("color_heightmap", "depth_heightmap")
#: The env's finer heights for the grasp-fit test (a workspace ``fit_scale`` above 1).
FIT_KEY = "fit_heightmap"


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
            :class:`~maniskill_pnp.agents.pixel.fcn.MultiPrimitiveQNetwork` (``(N, P, R, H, W)``).
        action_mask: Optional ``height (*B, H, W) -> bool (*B, P*R*H*W)`` (or ``(height, fit) -> ...`` when the actor
            is given fit heightmaps); the argmax skips masked-out actions and the mask is returned as a third output.
        primitive_margins: Optional margin per primitive (the leading axis of the flat ``(P, R, H, W)`` index),
            subtracted from that primitive's Q values for the argmax only (the returned values are the network's):
            with ``(0, m, m)`` a G&S agent slides only where a slide's Q beats the best grasp's by more than ``m``.
    """

    def __init__(self, q_network: nn.Module, action_mask: Callable[[torch.Tensor], torch.Tensor] | None = None,
                 primitive_margins: Sequence[float] | None = None):
        super().__init__()
        self.q_network = q_network
        self.action_mask = action_mask
        try:
            margins = torch.as_tensor([float(m) for m in (primitive_margins or ())], dtype=torch.float32)
        except (TypeError, ValueError):
            margins = torch.tensor([float("nan")])
        if not torch.isfinite(margins).all():
            raise ValueError(f"primitive margins must be finite numbers, one per primitive, got {primitive_margins!r}")
        self.register_buffer("primitive_margins", margins if margins.any() else None, persistent=False)

    def choice_values(self, values: torch.Tensor) -> torch.Tensor:
        """``values`` less each primitive's margin (the values the argmax ranks)."""
        if self.primitive_margins is None:
            return values
        p = len(self.primitive_margins)
        if values.shape[-1] % p:
            raise ValueError(f"{values.shape[-1]} actions do not split into the {p} primitives of the margins")
        blocks = values.reshape(*values.shape[:-1], p, -1) - self.primitive_margins.to(values.device)[:, None]
        return blocks.reshape(values.shape)

    def forward(self, color: torch.Tensor, depth: torch.Tensor, fit: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:
        x = heightmap_input(color, depth)
        batch = x.shape[:-3]
        maps = self.q_network(x.reshape(-1, *x.shape[-3:]))
        values = maps.reshape(*batch, -1)
        ranked = self.choice_values(values)
        if self.action_mask is None:
            return values, ranked.argmax(dim=-1)
        height = depth.to(torch.float32)
        mask = self.action_mask(height) if fit is None else self.action_mask(height, fit.to(torch.float32))
        return values, ranked.masked_fill(~mask, float("-inf")).argmax(dim=-1), mask


class PrimitiveExploreMask(nn.Module):
    """The allowed actions of one primitive per env, drawn with probabilities proportional to ``weights``.

    Args:
        weights: One non-negative weight per primitive (the leading axis of the flat ``(P, R, H, W)`` index), not
            all zero; normalised over the primitives that have an allowed action in each env.

    ``forward(values, mask=None)`` takes the flat maps ``(*B, A)`` (for the shape) and the allowed actions (``None``:
    all) and returns ``bool (*B, A)``. An env whose weighted primitives have no allowed action keeps its whole mask.
    """

    def __init__(self, weights: Sequence[float]):
        super().__init__()
        w = torch.as_tensor([float(x) for x in weights], dtype=torch.float32)
        if w.ndim != 1 or len(w) == 0 or not torch.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
            raise ValueError(f"explore weights must be finite, non-negative and not all zero, got {list(weights)}")
        self.register_buffer("weights", w)

    def forward(self, values: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        p = len(self.weights)
        if values.shape[-1] % p:
            raise ValueError(f"{values.shape[-1]} actions do not split into {p} primitives")
        allowed = torch.ones_like(values, dtype=torch.bool) if mask is None else mask
        blocks = allowed.reshape(*allowed.shape[:-1], p, -1)
        w = self.weights.to(values.device) * blocks.any(-1)  # (*B, P)
        flat_w = w.reshape(-1, p)
        empty = flat_w.sum(-1) == 0
        drawn = torch.multinomial(torch.where(empty[:, None], 1.0, flat_w), 1).reshape(w.shape[:-1])
        keep = (torch.arange(p, device=values.device) == drawn[..., None]) | empty.reshape(w.shape[:-1])[..., None]
        return (blocks & keep[..., None]).reshape(allowed.shape)


def make_pixel_policy(
    q_network: nn.Module,
    action_spec: TensorSpec,
    *,
    eps_init: float,
    eps_end: float,
    annealing_num_steps: int,
    action_mask: Callable[[torch.Tensor], torch.Tensor] | None = None,
    explore_weights: Sequence[float] | None = None,
    primitive_margins: Sequence[float] | None = None,
    fit_heightmap: bool = False,
) -> tuple[TensorDictModule, TensorDictSequential, EGreedyModule]:
    """The greedy pixel actor and the same actor with ε-greedy exploration.

    Args:
        q_network: The pixel Q network (shared with the loss, not copied).
        action_spec: The env's ``Categorical`` action spec (batched or unbatched) over the flat pixel index.
        eps_init, eps_end, annealing_num_steps: Linear ε schedule; call ``egreedy.step(frames)`` after each batch.
        action_mask: Optional ``height (*B, H, W) -> bool (*B, P*R*H*W)``: greedy and random actions are drawn
            among the allowed ones (written to ``"action_mask"``, which ``EGreedyModule`` reads).
        explore_weights: Optional share of each primitive among the random actions (see
            :class:`PrimitiveExploreMask`); ``None`` draws uniformly over the allowed actions.
        primitive_margins: Optional margin per primitive for the greedy choice (see :class:`GreedyPixelActor`).
        fit_heightmap: The actor also reads :data:`FIT_KEY` and hands it to ``action_mask``.

    Returns:
        ``(greedy, explore, egreedy)``; both policies read :data:`HEIGHTMAP_KEYS` (and :data:`FIT_KEY`) and write
        ``"action_value"`` and ``"action"``.

    Example:
        >>> greedy, explore, egreedy = make_pixel_policy(net, env.action_spec, eps_init=0.3, eps_end=0.1,
        ...                                              annealing_num_steps=1000)  # doctest: +SKIP
        >>> explore(env.reset())["action"]                                            # doctest: +SKIP
    """
    if not isinstance(action_spec, Categorical):
        raise TypeError(f"a pixel policy needs a Categorical action spec, got {type(action_spec).__name__}")
    out_keys = ["action_value", "action"] + (["action_mask"] if action_mask is not None else [])
    in_keys = list(HEIGHTMAP_KEYS) + ([FIT_KEY] if fit_heightmap else [])
    greedy = TensorDictModule(GreedyPixelActor(q_network, action_mask, primitive_margins), in_keys=in_keys, out_keys=out_keys)
    mask_key = "action_mask" if action_mask is not None else None
    steps = [greedy]
    if explore_weights is not None:
        steps.append(TensorDictModule(PrimitiveExploreMask(explore_weights),
                                      in_keys=["action_value"] + ([mask_key] if mask_key else []), out_keys=["explore_mask"]))
        mask_key = "explore_mask"
    egreedy = EGreedyModule(
        spec=action_spec.clone(),
        eps_init=float(eps_init),
        eps_end=float(eps_end),
        annealing_num_steps=int(annealing_num_steps),
        action_mask_key=mask_key,
    )
    return greedy, TensorDictSequential(*steps, egreedy), egreedy


__all__ = ["FIT_KEY", "HEIGHTMAP_KEYS", "GreedyPixelActor", "PrimitiveExploreMask", "heightmap_input", "make_pixel_policy"]
