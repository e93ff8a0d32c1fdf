"""Losses of the pixelwise agents: a DQN loss on the executed pixel and the binary-classification baseline.

Both losses take a Q network mapping heightmaps ``(B, 4, H, W)`` to maps ``(B, *action_shape)`` (a
:class:`~maniskill_pnp.agents.pixel.fcn.PixelQNetwork` gives ``(R, H, W)``, a
:class:`~maniskill_pnp.agents.pixel.fcn.MultiPrimitiveQNetwork` ``(P, R, H, W)``); the action is the row-major flat
index of those maps, i.e. :class:`~maniskill_pnp.cell.pixel_action.PixelActionLayout`'s index.

Only the executed pixel enters the loss, so every other pixel of the maps gets exactly zero gradient (thesis).

Tensordict keys (configurable with ``set_keys``):

=========================== ===================================================================== =========
key                         meaning                                                               read/write
=========================== ===================================================================== =========
``"observation"``           heightmap ``(*B, 4, H, W)``: RGB 0..1 and height above the table (m)    read
``"action"``                flat pixel action index ``(*B,)`` or ``(*B, 1)``                        read
``("next", "reward")``      reward of the step ``(*B,)`` or ``(*B, 1)``                            read
``("next", "terminated")``  true end of the MDP: no bootstrap (falls back to ``("next","done")``)  read (DQN)
``("next", "observation")`` next heightmap                                                        read (DQN)
``("next", "action_mask")`` the next state's allowed actions (bool ``(*B, A)``), where stored        read (DQN)
``"priority_weight"``       importance weights from a prioritized buffer (used when present)      read
``"td_error"``              ``|target - Q(s, a)|`` (DQN) or ``|label - p|`` (BCE), for PER        written
=========================== ===================================================================== =========

Target networks: with ``delay_value=True`` the DQN loss keeps a copy of the parameters
(``target_value_network_params``) that a TorchRL ``HardUpdate``/``SoftUpdate`` syncs; the loss never updates it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.utils import NestedKey
from torch import nn
from torchrl.objectives import LossModule
from maniskill_pnp.agents.pixel.policy import FIT_KEY

_REDUCTIONS = ("mean", "sum", "none")


def executed_values(maps: torch.Tensor, action: torch.Tensor, batch_numel: int) -> torch.Tensor:
    """Values of ``maps`` (``(N, *action_shape)``) at the flat action indices ``action`` (N entries): ``(N,)``.

    Raises:
        ValueError: an index is outside ``0..prod(action_shape)-1`` or the action is not integral.
    """
    if action.dtype.is_floating_point or action.dtype == torch.bool:
        raise ValueError(f"actions must be integer flat pixel indices, got dtype {action.dtype}")
    flat = maps.reshape(batch_numel, -1)
    a = action.reshape(batch_numel).long()
    if a.numel() and (int(a.min()) < 0 or int(a.max()) >= flat.shape[1]):
        raise ValueError(f"action index out of range 0..{flat.shape[1] - 1}: got {int(a.min())}..{int(a.max())}")
    return flat.gather(1, a.unsqueeze(1)).squeeze(1)


class _PixelLoss(LossModule):
    """Shared part of the pixel losses: the functional network, reductions and importance weights."""

    @dataclass
    class _AcceptedKeys:
        """Tensordict keys of the pixel losses (see the module docstring)."""

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        action_mask: NestedKey = "action_mask"
        priority: NestedKey = "td_error"
        priority_weight: NestedKey = "priority_weight"

    tensor_keys: _AcceptedKeys
    default_keys = _AcceptedKeys
    value_network: nn.Module
    value_network_params: TensorDictParams
    target_value_network_params: TensorDictParams

    def __init__(self, value_network: nn.Module, *, delay_value: bool, reduction: str, use_prioritized_weights: bool,
                 executed_only: bool):
        if not isinstance(value_network, nn.Module):
            raise ValueError(f"value_network must be an nn.Module, got {type(value_network).__name__}")
        if reduction not in _REDUCTIONS:
            raise ValueError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}")
        super().__init__()
        self.delay_value = delay_value
        self.reduction = reduction
        self.use_prioritized_weights = use_prioritized_weights
        self.executed_only = executed_only
        self.convert_to_functional(value_network, "value_network", create_target_params=delay_value)

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass  # no value estimator: the bootstrap is computed in forward

    def _maps(self, observation: torch.Tensor, params: TensorDictBase) -> torch.Tensor:
        with params.to_module(self.value_network):
            return self.value_network(observation)

    def _executed(self, observation: torch.Tensor, action: torch.Tensor, n: int) -> torch.Tensor:
        """Online ``Q(s, a)`` ``(n,)``; only the executed maps are computed when the network offers
        ``executed_values`` (e.g. :class:`~maniskill_pnp.agents.pixel.fcn.MultiPrimitiveQNetwork`)."""
        if self.executed_only and hasattr(self.value_network, "executed_values"):
            with self.value_network_params.to_module(self.value_network):
                return self.value_network.executed_values(observation, action.reshape(n))
        return executed_values(self._maps(observation, self.value_network_params), action, n)

    def _batch(self, tensordict: TensorDictBase) -> int:
        if tensordict.batch_dims == 0:
            raise ValueError("the pixel losses need a batched tensordict (batch_size=[B]), got an empty batch size")
        return tensordict.batch_size.numel()

    def _reduce(self, loss: torch.Tensor, tensordict: TensorDictBase) -> torch.Tensor:
        if self.use_prioritized_weights:
            weights = tensordict.get(self.tensor_keys.priority_weight, default=None)
            if weights is not None:
                loss = loss * weights.reshape(loss.shape).to(loss.dtype)
        if self.reduction == "mean":
            return loss.mean()
        if self.reduction == "sum":
            return loss.sum()
        return loss.reshape(tensordict.batch_size)

    def _write_priority(self, tensordict: TensorDictBase, td_error: torch.Tensor) -> None:
        tensordict.set(self.tensor_keys.priority, td_error.detach().reshape(tensordict.batch_size))


class PixelDQNLoss(_PixelLoss):
    """Pixelwise DQN loss: Huber loss between ``Q(s, a)`` at the executed pixel and ``r + gamma * max Q'(s')``.

    The bootstrap is the maximum over *all* next maps (every primitive, rotation and pixel; with ``action_mask``
    over the allowed actions only), zero where the transition is terminal. With ``double_dqn`` the online network
    picks the next action and the target network values it.

    Args:
        value_network: Heightmaps ``(N, 4, H, W)`` -> maps ``(N, *action_shape)``.
        gamma: Discount factor in [0, 1].
        delay_value: Use a target network (``target_value_network_params``, synced by ``HardUpdate``/``SoftUpdate``).
        double_dqn: Double DQN bootstrap; needs ``delay_value=True``.
        huber_delta: Threshold of the Huber loss (quadratic below, linear above).
        reduction: ``"mean"``, ``"sum"`` or ``"none"`` over the batch.
        use_prioritized_weights: Multiply by ``"priority_weight"`` when the tensordict holds it.
        action_mask: Optional ``observation (N, 4, H, W) -> bool (N, *flat action)`` restricting the bootstrap's
            max (e.g. ``HeightmapActionMask(...).from_observation``), the same mask the actor acts under; where the
            transitions hold ``("next", "fit_heightmap")`` it is called as ``action_mask(observation, fit)``. Where
            they hold the next state's mask itself (``("next", "action_mask")``, e.g. joined by
            :class:`~maniskill_pnp.agents.pixel.replay.NextMaskJoin`), that is used and nothing is computed.
        executed_only: Compute the online ``Q(s, a)`` from the executed primitive and rotation only, when the
            network offers ``executed_values`` (the gradient is the same; BatchNorm's train-mode statistics come
            from the executed images). False: the full maps, as the module docstring describes.

    Example:
        >>> from torchrl.objectives import HardUpdate
        >>> net = PixelQNetwork(num_rotations=4, backbone="small")
        >>> loss = PixelDQNLoss(net, gamma=0.5, delay_value=True)
        >>> updater = HardUpdate(loss, value_network_update_interval=100)
        >>> loss(batch)["loss_qvalue"].backward(); optimizer.step(); updater.step()  # doctest: +SKIP
    """

    def __init__(
        self,
        value_network: nn.Module,
        *,
        gamma: float,
        delay_value: bool = True,
        double_dqn: bool = False,
        huber_delta: float = 1.0,
        reduction: str = "mean",
        use_prioritized_weights: bool = True,
        action_mask: Callable[[torch.Tensor], torch.Tensor] | None = None,
        executed_only: bool = True,
    ):
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {gamma!r}")
        if double_dqn and not delay_value:
            raise ValueError("double_dqn=True requires delay_value=True (a target network to value the online argmax)")
        if not huber_delta > 0:
            raise ValueError(f"huber_delta must be > 0, got {huber_delta!r}")
        super().__init__(
            value_network, delay_value=delay_value, reduction=reduction, use_prioritized_weights=use_prioritized_weights,
            executed_only=executed_only,
        )
        self.gamma = float(gamma)
        self.double_dqn = double_dqn
        self.huber_delta = float(huber_delta)
        self.action_mask = action_mask

    @torch.no_grad()
    def bootstrap(self, next_observation: torch.Tensor, next_fit: torch.Tensor | None = None,
                  next_allowed: torch.Tensor | None = None) -> torch.Tensor:
        """``max_a' Q(s', a')`` per sample ``(N,)`` (double DQN: target value of the online argmax); ``next_fit``: the
        next states' fit heightmaps ``(N, k·H, k·W)`` for the action mask; ``next_allowed``: their action masks
        ``(N, A)`` already computed (then ``action_mask`` is not called)."""
        n = next_observation.shape[0]
        target_params = self.target_value_network_params if self.delay_value else self.value_network_params.data
        next_q = self._maps(next_observation, target_params).reshape(n, -1)
        allowed = None if next_allowed is None else next_allowed.reshape(n, -1)
        if allowed is None and self.action_mask is not None:
            fit = () if next_fit is None else (next_fit.to(torch.float32),)
            allowed = self.action_mask(next_observation, *fit).reshape(n, -1)
        if not self.double_dqn:
            return (next_q if allowed is None else next_q.masked_fill(~allowed, float("-inf"))).max(dim=1).values
        online = self._maps(next_observation, self.value_network_params.data).reshape(n, -1)
        if allowed is not None:
            online = online.masked_fill(~allowed, float("-inf"))
        return next_q.gather(1, online.argmax(dim=1, keepdim=True)).squeeze(1)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """Loss of a batch of transitions; writes ``"td_error"`` into ``tensordict``."""
        n = self._batch(tensordict)
        keys = self.tensor_keys
        obs = tensordict.get(keys.observation)
        obs = obs.reshape(n, *obs.shape[tensordict.batch_dims :])
        q = self._executed(obs, tensordict.get(keys.action), n)

        reward = tensordict.get(("next", keys.reward)).reshape(n).to(q.dtype)
        terminated = tensordict.get(("next", keys.terminated), default=None)
        if terminated is None:
            terminated = tensordict.get(("next", keys.done))
        terminated = terminated.reshape(n).bool()
        next_obs = tensordict.get(("next", keys.observation))
        next_obs = next_obs.reshape(n, *next_obs.shape[tensordict.batch_dims :])
        next_fit = tensordict.get(("next", FIT_KEY), default=None)
        if next_fit is not None:
            next_fit = next_fit.reshape(n, *next_fit.shape[tensordict.batch_dims:])
        next_allowed = tensordict.get(("next", keys.action_mask), default=None) if self.action_mask is not None else None
        next_value = self.bootstrap(next_obs, next_fit, next_allowed).to(q.dtype)
        target = reward + self.gamma * next_value.masked_fill(terminated, 0.0)

        self._write_priority(tensordict, (target - q).abs())
        loss = F.huber_loss(q, target, reduction="none", delta=self.huber_delta)
        return TensorDict(
            loss_qvalue=self._reduce(loss, tensordict),
            q_executed=q.detach().mean(),
            target_value=target.mean(),
        )


class PixelBCELoss(_PixelLoss):
    """Binary-classification baseline (thesis Ch. 6): BCE-with-logits at the executed pixel, no bootstrapping.

    The label is ``("next", "reward") > success_threshold``: the maps are read as success logits.

    Args:
        value_network: Heightmaps ``(N, 4, H, W)`` -> logit maps ``(N, *action_shape)``.
        success_threshold: Rewards strictly above it count as a success.
        reduction: ``"mean"``, ``"sum"`` or ``"none"`` over the batch.
        use_prioritized_weights: Multiply by ``"priority_weight"`` when the tensordict holds it.
        executed_only: As for :class:`PixelDQNLoss`.
    """

    def __init__(
        self,
        value_network: nn.Module,
        *,
        success_threshold: float = 0.0,
        reduction: str = "mean",
        use_prioritized_weights: bool = True,
        executed_only: bool = True,
    ):
        super().__init__(
            value_network, delay_value=False, reduction=reduction, use_prioritized_weights=use_prioritized_weights,
            executed_only=executed_only,
        )
        self.success_threshold = float(success_threshold)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """Loss of a batch of labelled attempts; writes ``"td_error"`` (``|label - sigmoid(logit)|``)."""
        n = self._batch(tensordict)
        keys = self.tensor_keys
        obs = tensordict.get(keys.observation)
        obs = obs.reshape(n, *obs.shape[tensordict.batch_dims :])
        logit = self._executed(obs, tensordict.get(keys.action), n)
        label = (tensordict.get(("next", keys.reward)).reshape(n) > self.success_threshold).to(logit.dtype)
        self._write_priority(tensordict, (label - logit.detach().sigmoid()).abs())
        loss = F.binary_cross_entropy_with_logits(logit, label, reduction="none")
        return TensorDict(loss_bce=self._reduce(loss, tensordict), success_label=label.mean())
