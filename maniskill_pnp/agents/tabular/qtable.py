"""Tabular TD(0) control on TorchRL: a Q-table policy masked by the env's action mask, Q-learning and SARSA.

The library part of the conveyor recipe (thesis chapter 4), written against TorchRL's tensordict contract so that
the table plugs into TorchRL's collectors and exploration modules like any Q-value network:

* :class:`QTable` is a ``nn.Module`` ``observation (int64 state id) -> action_value``; :func:`make_qtable_policy`
  wraps it with :class:`~torchrl.modules.QValueModule` (greedy over the *valid* actions) and, for exploration,
  :class:`~torchrl.modules.EGreedyModule` (random valid action with probability ε).
* The valid actions are the env's own ``"action_mask"`` entry (bool, ``[*batch, num_actions]``): the task reports
  the actions valid in its current phase, and the TorchRL env carries them next to the observation. Both policies
  read it from the tensordict they act on; chained with :class:`~torchrl.envs.transforms.ActionMask`, the env's
  action spec follows it too, so random actions (``check_env_specs``, ``rollout``) respect the task's phases.
* :func:`td_update` applies ``Q(s, a) += α (r + γ (1 - terminal) B(s', a') - Q(s, a))`` where the bootstrap
  term ``B`` is the one place where the algorithms differ (see :data:`BOOTSTRAPS`).

Tensordict keys of one transition (as collected by TorchRL, flattened to a batch of transitions):

=============================  ======  ===================================================================
key                            dtype   meaning
=============================  ======  ===================================================================
``"observation"``              int64   state id ``s``
``"action"``                   int64   action taken ``a``
``("next", "reward")``         float   reward ``r`` (trailing dim of size 1)
``("next", "terminated")``     bool    terminal transition: bootstrap 0
``("next", "observation")``    int64   next state id ``s'``
``("next", "action_mask")``    bool    valid actions at ``s'`` (Q-learning's max runs over these)
``"next_action"``              int64   action taken at ``s'`` by the behaviour policy (SARSA's ``a'``);
                                       any value for terminal transitions
=============================  ======  ===================================================================
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Categorical, TensorSpec
from torchrl.modules import EGreedyModule, QValueModule

ALGORITHMS = ("qlearning", "sarsa")


class QTable(nn.Module):
    """A table of action values, one row per discrete state id.

    The values are a buffer, not a parameter: TD updates write them in place (:func:`td_update`), no optimizer.

    Args:
        num_states: Number of state ids (rows).
        num_actions: Number of actions (columns): the size of the Discrete action space.
        init: Initial value of every entry. A value at or above the best achievable return makes the greedy policy
            try every valid action before it settles ("optimistic initial values", Sutton & Barto §2.6).

    Example:
        >>> q = QTable(4, 2, init=1.0)
        >>> q(torch.tensor([3])).shape
        torch.Size([1, 2])
    """

    def __init__(self, num_states: int, num_actions: int, *, init: float = 0.0):
        super().__init__()
        if num_states < 1 or num_actions < 1:
            raise ValueError(f"a Q-table needs >= 1 state and action, got {num_states} x {num_actions}")
        self.register_buffer("values", torch.full((num_states, num_actions), float(init)))

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.values.shape)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        """Action values of the given state ids: ``[*batch] -> [*batch, num_actions]``."""
        return self.values[observation.long()]


def make_qtable_policy(
    table: QTable,
    action_spec: TensorSpec,
    *,
    eps_init: float,
    eps_end: float,
    annealing_num_steps: int,
) -> tuple[TensorDictSequential, TensorDictSequential, EGreedyModule]:
    """The greedy policy over valid actions, and the same policy with ε-greedy exploration.

    Args:
        table: The Q-table (shared, not copied: TD updates are seen by both policies at once).
        action_spec: The env's (unbatched or batched) ``Categorical`` action spec; cloned, because ε-greedy updates
            its mask in place.
        eps_init, eps_end, annealing_num_steps: Linear ε schedule of :class:`~torchrl.modules.EGreedyModule`;
            call ``egreedy.step(frames)`` after each collected batch.

    Returns:
        ``(greedy, explore, egreedy)``; both policies read ``"observation"`` and ``"action_mask"`` (the env's valid
        actions) and write ``"action_value"``, ``"action"`` and ``"chosen_action_value"``. Neither ever picks a
        masked action. A state whose mask is all False (the episode is over) takes no action: the ε-greedy draw
        needs at least one valid action.
    """
    if not isinstance(action_spec, Categorical):
        raise TypeError(f"a Q-table policy needs a Categorical action spec, got {type(action_spec).__name__}")
    if action_spec.space.n != table.shape[1]:
        raise ValueError(f"action spec has {action_spec.space.n} actions, the Q-table {table.shape[1]}")
    values = TensorDictModule(table, in_keys=["observation"], out_keys=["action_value"])
    argmax = QValueModule(action_space="categorical", action_mask_key="action_mask", spec=action_spec.clone())
    greedy = TensorDictSequential(values, argmax)
    egreedy = EGreedyModule(
        spec=action_spec.clone(),
        eps_init=float(eps_init),
        eps_end=float(eps_end),
        annealing_num_steps=int(annealing_num_steps),
        action_mask_key="action_mask",
    )
    explore = TensorDictSequential(greedy, egreedy)
    return greedy, explore, egreedy


# ----------------------------------------------------------------------------- the TD(0) update
Bootstrap = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def max_valid(next_values: torch.Tensor, next_mask: torch.Tensor, next_action: torch.Tensor) -> torch.Tensor:
    """Q-learning's bootstrap: the greedy value ``max_{a' valid} Q(s', a')`` (0 where no action is valid)."""
    masked = next_values.masked_fill(~next_mask, float("-inf")).amax(-1)
    return torch.where(next_mask.any(-1), masked, torch.zeros_like(masked))


def taken(next_values: torch.Tensor, next_mask: torch.Tensor, next_action: torch.Tensor) -> torch.Tensor:
    """SARSA's bootstrap: ``Q(s', a')`` of the action ``a'`` the behaviour policy actually took in ``s'``."""
    return next_values.gather(-1, next_action.long().clamp(min=0).unsqueeze(-1)).squeeze(-1)


#: The one difference between Q-learning (off-policy) and SARSA (on-policy): the bootstrap term.
BOOTSTRAPS: dict[str, Bootstrap] = {"qlearning": max_valid, "sarsa": taken}


def bootstrap_for(algorithm: str) -> Bootstrap:
    """The bootstrap function of ``algorithm`` (one of :data:`ALGORITHMS`); ValueError otherwise."""
    if algorithm not in BOOTSTRAPS:
        raise ValueError(f"unknown algorithm {algorithm!r}; valid: {list(ALGORITHMS)}")
    return BOOTSTRAPS[algorithm]


def td_targets(table: QTable, transitions: TensorDictBase, *, gamma: float, bootstrap: Bootstrap) -> torch.Tensor:
    """``r + γ (1 - terminal) B(s', a')`` for a flat batch of transitions (keys: see the module docstring)."""
    next_obs = transitions.get(("next", "observation")).long()
    next_values = table.values[next_obs]
    boot = bootstrap(next_values, transitions.get(("next", "action_mask")), transitions.get("next_action"))
    reward = transitions.get(("next", "reward")).reshape(boot.shape)
    terminal = transitions.get(("next", "terminated")).reshape(boot.shape)
    return reward + gamma * torch.where(terminal, torch.zeros_like(boot), boot)


@torch.no_grad()
def td_update(table: QTable, transitions: TensorDictBase, *, alpha: float, gamma: float, bootstrap: Bootstrap) -> torch.Tensor:
    """One TD(0) step ``Q(s, a) += α (target - Q(s, a))`` per transition, applied in order; returns the TD errors.

    Transitions are applied one after the other, so a later one bootstraps from values an earlier one changed
    (and two updates of the same pair both count), exactly as in the online algorithm.

    Args:
        table: The Q-table, updated in place.
        transitions: A 1-D tensordict of transitions (keys: see the module docstring).
        alpha: Step size α in (0, 1].
        gamma: Discount γ in [0, 1].
        bootstrap: :func:`max_valid` (Q-learning) or :func:`taken` (SARSA); see :func:`bootstrap_for`.
    """
    if transitions.batch_dims != 1:
        raise ValueError(f"td_update takes a flat batch of transitions, got batch size {tuple(transitions.batch_size)}")
    errors = []
    for i in range(transitions.batch_size[0]):
        step = transitions[i : i + 1]
        s, a = step.get("observation").long(), step.get("action").long()
        target = td_targets(table, step, gamma=gamma, bootstrap=bootstrap)
        error = target - table.values[s, a]
        table.values[s, a] += alpha * error
        errors.append(error)
    return torch.cat(errors) if errors else torch.zeros(0)
