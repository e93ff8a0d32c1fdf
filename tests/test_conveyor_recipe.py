"""The conveyor recipe end to end: TorchRL env checks, then train + eval as subprocesses with tiny settings."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch
from torchrl.envs.utils import ExplorationType, check_env_specs, set_exploration_type, step_mdp

from maniskill_pnp.agents.tabular.qtable import QTable, make_qtable_policy
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig, make_env
from maniskill_pnp.tasks.conveyor_config import ConveyorSpec


def _cli(*args, cwd):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "maniskill_pnp.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_masked_torchrl_env_passes_check_env_specs():
    """Random actions from the env's spec respect the phase (the bare wrapper's random actions may be invalid).

    TorchRL's check draws one more random action after its 3-step rollout; once an episode is over no action is
    valid (an all-False mask cannot be sampled), so the check starts one phase into an episode and its rollout runs
    on across the reset, as a collector's does."""
    env = make_env(ConveyorConfig())
    try:
        env.set_seed(0)
        after_wait = step_mdp(env.step(env.rand_action(env.reset())))
        check_env_specs(env, tensordict=after_wait, break_when_any_done=False)
        rollout = env.rollout(6, break_when_any_done=False)
        assert (rollout["action_mask"].gather(-1, rollout["action"].unsqueeze(-1))).all()
        assert not rollout["next", "invalid_action"].any()
    finally:
        env.close()


@pytest.mark.parametrize("exploration", ["greedy", "eps=1"])
def test_action_mask_is_the_tasks_and_the_policy_keeps_to_it(exploration):
    """The mask the policies read is the task's own ``info["action_mask"]`` in every phase, the action spec follows
    it, and a table that prefers masked actions still picks valid ones: the episode runs its phases without an
    invalid action."""
    torch.manual_seed(0)
    spec = ConveyorSpec()
    table = QTable(spec.num_states, spec.action_n)
    table.values[:, -1] = 10.0  # the last action is valid only in the pre-pick phase; greedy would take it anywhere
    eps = 0.0 if exploration == "greedy" else 1.0
    env = make_env(ConveyorConfig(seed=2))
    greedy, explore, _ = make_qtable_policy(table, env.action_spec_unbatched, eps_init=eps, eps_end=eps, annealing_num_steps=1)
    policy, mode = (greedy, ExplorationType.DETERMINISTIC) if exploration == "greedy" else (explore, ExplorationType.RANDOM)
    task = env.base_env.base_env
    try:
        td, phases = env.reset(), []
        for _ in range(3):
            info = task.get_info()
            phases.append(info["phase"])
            assert torch.equal(td["action_mask"], info["action_mask"])
            assert torch.equal(env.action_spec.mask, info["action_mask"])
            with set_exploration_type(mode):
                td = policy(td)
            assert td["action_mask"].gather(-1, td["action"].unsqueeze(-1)).all(), (info["phase"], td["action"])
            td = env.step(td)
            assert not td["next", "invalid_action"].any()
            if td["next", "done"].any():
                break
            td = step_mdp(td)
        assert phases[:2] == ["initial", "pre_pick"]
        assert task.get_info()["phase"] == "done"
        assert torch.equal(td["next", "action_mask"], task.get_info()["action_mask"])
        assert not td["next", "action_mask"].any()  # no action is valid once the episode is over
        if exploration == "greedy":  # the reach to a pre-pick coordinate succeeds: all three phases were seen
            assert phases == ["initial", "pre_pick", "grasp"]
            assert td["action"].item() < spec.num_actions["grasp"] < spec.action_n
    finally:
        env.close()


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    res = _cli("train-conveyor", "--algorithm", "sarsa", "--steps", "30", "--seed", "3", "--log-interval", "6",
               "--out", str(out), cwd=out)
    assert res.returncode == 0, res.stderr[-3000:]
    return out / "sarsa_normal_seed3"


def test_train_writes_config_qtable_and_logs(trained):
    config = json.loads((trained / "config.json").read_text())
    assert config["algorithm"] == "sarsa" and config["steps"] == 30 and config["seed"] == 3
    assert (trained / "qtable.pt").is_file()
    log = (trained / "scalars" / "train" / "success_rate.csv").read_text().splitlines()
    assert len(log) >= 2 and log[-1].split(",")[0] == "30"


def test_eval_writes_tables(trained, tmp_path):
    res = _cli("eval-conveyor", str(trained), "--iterations", "3", "--out", str(tmp_path / "eval"), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    md = (tmp_path / "eval" / "test_cases.md").read_text()
    assert "Test case 5" in md and "SARSA success_rate" in md
    rows = (tmp_path / "eval" / "test_cases.csv").read_text().splitlines()
    assert rows[0] == "agent,test_case,episodes,success_rate,grasp_success" and len(rows) == 6


def test_eval_of_a_truncated_qtable_fails_clearly(trained, tmp_path):
    bad = tmp_path / "qtable.pt"
    data = (trained / "qtable.pt").read_bytes()
    bad.write_bytes(data[:100])
    res = _cli("eval-conveyor", str(bad), "--iterations", "1", "--out", str(tmp_path / "eval"), cwd=tmp_path)
    assert res.returncode != 0
    assert str(bad) in res.stderr and "truncated" in res.stderr
