"""The conveyor recipe end to end: TorchRL env checks, then train + eval as subprocesses with tiny settings."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from torchrl.envs.utils import check_env_specs

from maniskill_pnp.agents.conveyor_recipe import ConveyorConfig, make_env


def _cli(*args, cwd):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "maniskill_pnp.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_masked_torchrl_env_passes_check_env_specs():
    """Random actions from the env's spec respect the phase (the bare wrapper's random actions are invalid)."""
    env = make_env(ConveyorConfig())
    try:
        check_env_specs(env, seed=0)
        rollout = env.rollout(6, break_when_any_done=False)
        assert (rollout["action_mask"].gather(-1, rollout["action"].unsqueeze(-1))).all()
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
