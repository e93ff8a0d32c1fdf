"""Unit tests of the tabular TD library: hand-computed targets, masking, ε schedule, SARSA's next-action pairing."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Categorical
from torchrl.envs.utils import ExplorationType, set_exploration_type

from maniskill_pnp.agents.tabular.qtable import QTable, bootstrap_for, make_qtable_policy, td_targets, td_update
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, NextActionPairing, load_qtable, save_qtable
from maniskill_pnp.tasks.conveyor_config import ConveyorSpec


def _transition(s, a, r, s2, terminal, next_action, next_mask):
    return TensorDict(
        {
            "observation": torch.tensor([s]),
            "action": torch.tensor([a]),
            "next_action": torch.tensor([next_action]),
            "next": {
                "observation": torch.tensor([s2]),
                "reward": torch.tensor([[r]], dtype=torch.float32),
                "terminated": torch.tensor([[terminal]]),
                "action_mask": torch.tensor([next_mask]),
            },
        },
        batch_size=[1],
    )


def _two_state_table():
    """State 0 -> state 1; Q(1, ·) = [2, 5]. With γ = 0.5, α = 0.5, r = 1 and a' = 0 taken in state 1:
    Q-learning target 1 + 0.5·max(2, 5) = 3.5, so Q(0, 0) = 0 + 0.5·3.5 = 1.75;
    SARSA target      1 + 0.5·Q(1, 0) = 2.0, so Q(0, 0) = 0 + 0.5·2.0 = 1.0."""
    table = QTable(2, 2)
    table.values[1] = torch.tensor([2.0, 5.0])
    return table


@pytest.mark.parametrize("algorithm, target, q", [("qlearning", 3.5, 1.75), ("sarsa", 2.0, 1.0)])
def test_two_state_mdp_targets_differ_by_bootstrap(algorithm, target, q):
    table = _two_state_table()
    tr = _transition(0, 0, 1.0, 1, False, next_action=0, next_mask=[True, True])
    assert td_targets(table, tr, gamma=0.5, bootstrap=bootstrap_for(algorithm)).tolist() == [target]
    errors = td_update(table, tr, alpha=0.5, gamma=0.5, bootstrap=bootstrap_for(algorithm))
    assert errors.tolist() == [target]
    assert table.values.tolist() == [[q, 0.0], [2.0, 5.0]]


def test_qlearning_max_runs_over_valid_actions_only():
    table = _two_state_table()  # action 1 (value 5) is invalid in state 1: target 1 + 0.5·2 = 2
    tr = _transition(0, 0, 1.0, 1, False, next_action=0, next_mask=[True, False])
    assert td_targets(table, tr, gamma=0.5, bootstrap=bootstrap_for("qlearning")).tolist() == [2.0]


def test_qlearning_bootstraps_zero_where_no_action_is_valid():
    """The env's mask is all False once the episode is over: no valid next action, nothing to bootstrap."""
    table = _two_state_table()
    tr = _transition(0, 0, 1.0, 1, False, next_action=0, next_mask=[False, False])
    assert td_targets(table, tr, gamma=0.5, bootstrap=bootstrap_for("qlearning")).tolist() == [1.0]


@pytest.mark.parametrize("algorithm", ["qlearning", "sarsa"])
def test_terminal_bootstraps_zero_and_updates_apply_in_order(algorithm):
    table = _two_state_table()
    tr = _transition(0, 1, 1.0, 1, True, next_action=1, next_mask=[True, True])
    both = torch.cat([tr, tr])  # the same pair twice: 0 -> 0.5 -> 0.75
    errors = td_update(table, both, alpha=0.5, gamma=0.5, bootstrap=bootstrap_for(algorithm))
    assert errors.tolist() == [1.0, 0.5]
    assert table.values[0].tolist() == [0.0, 0.75]


def test_unknown_algorithm_is_a_value_error():
    with pytest.raises(ValueError, match="qlearning"):
        bootstrap_for("dqn")
    with pytest.raises(ValueError, match="algorithm"):
        ConveyorConfig(algorithm="dqn")
    with pytest.raises(ValueError, match="alpha"):
        ConveyorConfig(alpha=0.0)


def _policies(eps):
    table = QTable(3, 4)
    table.values[:] = torch.tensor([10.0, 0.0, 0.0, 0.0])  # the best action is invalid in state 1
    greedy, explore, egreedy = make_qtable_policy(table, Categorical(4), eps_init=eps, eps_end=eps, annealing_num_steps=1)
    return greedy, explore, egreedy


def test_masked_actions_are_never_chosen_even_with_eps_one():
    greedy, explore, _ = _policies(eps=1.0)
    mask = torch.tensor([[False, True, True, False]]).expand(500, 4)
    td = TensorDict({"observation": torch.ones(500, dtype=torch.long), "action_mask": mask}, batch_size=[500])
    with set_exploration_type(ExplorationType.RANDOM):
        actions = explore(td.clone())["action"]
    assert set(actions.tolist()) == {1, 2}  # both valid actions drawn, nothing else
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert set(greedy(td.clone())["action"].tolist()) == {1}  # argmax over valid actions (ties: first)


def test_eps_schedule_steps_linearly_then_stays():
    table = QTable(1, 2)
    _, _, egreedy = make_qtable_policy(table, Categorical(2), eps_init=0.3, eps_end=0.1, annealing_num_steps=4)
    assert egreedy.eps.item() == pytest.approx(0.3)
    egreedy.step(2)
    assert egreedy.eps.item() == pytest.approx(0.2)
    egreedy.step(10)
    assert egreedy.eps.item() == pytest.approx(0.1)


def _frame(s, a, s2, terminated, traj=0):
    return TensorDict(
        {
            "observation": torch.tensor([s]),
            "action": torch.tensor([a]),
            "collector": {"traj_ids": torch.tensor([traj])},
            "next": {
                "observation": torch.tensor([s2]),
                "reward": torch.zeros(1, 1),
                "terminated": torch.tensor([[terminated]]),
                "truncated": torch.tensor([[False]]),
            },
        },
        batch_size=[1],
    )


def test_sarsa_pairing_uses_the_action_taken_next_across_batch_boundaries():
    pairing = NextActionPairing(policy=None)
    # episode A: 0 -a0-> 5 -a3-> 7 -a2-> terminal; episode B: 0 -a0-> 5 ...; split into batches of 2
    ready = pairing(torch.cat([_frame(0, 0, 5, False), _frame(5, 3, 7, False)]))
    assert ready["observation"].tolist() == [0] and ready["next_action"].tolist() == [3]
    ready = pairing(torch.cat([_frame(7, 2, 9, True), _frame(0, 0, 5, False, traj=1)]))
    assert ready["observation"].tolist() == [5, 7] and ready["next_action"].tolist()[0] == 2
    assert list(pairing.pending) == [(0, 1)] and pairing.pending[(0, 1)]["observation"].tolist() == [0]
    # another worker's trajectory interleaves without disturbing the held-back transition of trajectory 1
    ready = pairing(torch.cat([_frame(3, 1, 4, False, traj=2), _frame(5, 1, 6, False, traj=1)]))
    assert ready["observation"].tolist() == [0] and ready["next_action"].tolist() == [1]
    assert sorted(pairing.pending) == [(0, 1), (0, 2)] and pairing.pending[(0, 2)]["observation"].tolist() == [3]
    with pytest.raises(RuntimeError, match="next state"):  # trajectory 2 went 3 -> 4, so it cannot go on from 9
        pairing(_frame(9, 1, 7, False, traj=2))


def test_qtable_file_errors_name_the_file_and_the_problem(tmp_path):
    spec = ConveyorSpec()
    path = tmp_path / "qtable.pt"
    with pytest.raises(FileNotFoundError, match="qtable.pt"):
        load_qtable(path)
    save_qtable(QTable(spec.num_states, spec.action_n, init=0.25), ConveyorConfig(), path, spec=spec)
    table, cfg, _ = load_qtable(path)
    assert table.values.eq(0.25).all() and cfg == ConveyorConfig()
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"qtable\.pt.*truncated"):
        load_qtable(path)
    save_qtable(QTable(3, 2), ConveyorConfig(), path, spec=spec)
    with pytest.raises(ValueError, match=r"shape \(3, 2\)"):
        load_qtable(path)


def test_state_encoding_takes_the_task_infos_unknown_as_not_sensed():
    """The task's info says "unknown" (and last_coord -1) where the spec's state encoding means None."""
    from maniskill_pnp.tasks.conveyor_config import UNKNOWN

    spec = ConveyorSpec()
    assert spec.encode_state("pre_pick", UNKNOWN, UNKNOWN, -1) == spec.encode_state("pre_pick", None, None, None)
    s = spec.encode_state("grasp", "fast", UNKNOWN, 4)
    assert spec.decode_state(s) == dict(phase="grasp", speed="fast", alignment=None, last=4)
