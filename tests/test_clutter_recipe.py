"""The pixel actor (argmax layout, ε-greedy draws) and the clutter DQN recipe as a subprocess smoke run with resume."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Categorical
from torchrl.envs.utils import ExplorationType, set_exploration_type

from maniskill_pnp.agents.clutter_curves import load_actions, plot_training_curves, run_curves, trailing_mean
from maniskill_pnp.agents.clutter_recipe import ClutterConfig, OutcomeTracker, load_checkpoint
from maniskill_pnp.agents.pixel_policy import make_pixel_policy
from maniskill_pnp.tasks.pixel_action import PixelActionLayout

LAYOUT = PixelActionLayout(1, 2, 8, 8)


class FixedMaps(nn.Module):
    """Returns preset maps ``(N, P, R, H, W)`` whatever the input (checks only the input's shape)."""

    def __init__(self, maps: torch.Tensor):
        super().__init__()
        self.maps = maps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        assert x.shape == (self.maps.shape[0], 4, LAYOUT.height, LAYOUT.width)
        return self.maps


def heightmap_td(b: int) -> TensorDict:
    return TensorDict(
        color_heightmap=torch.randint(0, 256, (b, LAYOUT.height, LAYOUT.width, 3), dtype=torch.uint8),
        depth_heightmap=torch.rand(b, LAYOUT.height, LAYOUT.width),
        batch_size=[b],
    )


def test_greedy_action_decodes_to_the_maximum_of_the_maps():
    torch.manual_seed(0)
    maps = torch.randn(3, *LAYOUT.shape)
    spec = Categorical(LAYOUT.size, shape=(3,))
    greedy, _, _ = make_pixel_policy(FixedMaps(maps), spec, eps_init=0.3, eps_end=0.1, annealing_num_steps=10)
    out = greedy(heightmap_td(3))
    assert out["action_value"].shape == (3, LAYOUT.size)
    for b, index in enumerate(out["action"].tolist()):
        assert maps[b][LAYOUT.decode(index)] == maps[b].max()


def test_epsilon_one_draws_valid_varied_indices():
    maps = torch.zeros(64, *LAYOUT.shape)
    maps[..., 0, 0] = 1.0  # the greedy action is index 0 of every rotation 0
    spec = Categorical(LAYOUT.size, shape=(64,))
    _, explore, egreedy = make_pixel_policy(FixedMaps(maps), spec, eps_init=1.0, eps_end=1.0, annealing_num_steps=10)
    with set_exploration_type(ExplorationType.RANDOM):
        actions = explore(heightmap_td(64))["action"]
    assert actions.dtype == torch.int64 and actions.shape == (64,)
    assert int(actions.min()) >= 0 and int(actions.max()) < LAYOUT.size
    assert len(set(actions.tolist())) > 32
    egreedy.step(5)
    assert egreedy.eps.item() == 1.0


def test_presets_resolve():
    thesis = ClutterConfig.from_preset("thesis")
    assert (thesis.backbone, thesis.num_rotations, thesis.heightmap_size, thesis.num_objects, thesis.episodes) == (
        "densenet121", 16, 224, 10, 3000
    )
    assert ClutterConfig.from_preset("cpu-small", seed=3).run_name.endswith("seed3")


@pytest.mark.parametrize("option", [dict(max_minutes=-1.0), dict(max_minutes=float("nan")), dict(episodes=-1)])
def test_negative_budgets_are_rejected(option):
    with pytest.raises(ValueError, match=next(iter(option))):
        ClutterConfig(**option)


def test_explore_weights_need_one_weight_per_primitive():
    assert ClutterConfig.from_preset("gs-cpu-small", explore_weights=[2, 1, 1]).explore_weights == (2.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="one weight per primitive"):
        ClutterConfig.from_preset("gs-cpu-small", explore_weights=(1.0, 1.0))
    with pytest.raises(ValueError, match="explore weights"):
        ClutterConfig.from_preset("cpu-small", explore_weights=(0.0,))


def _train(out, steps: int, *extra: str, preset: str = "cpu-small") -> dict:
    cmd = [
        sys.executable, "-m", "maniskill_pnp.cli", "train-clutter", "--preset", preset, "--heightmap-size", "32",
        "--num-rotations", "2", "--num-objects", "2", "--steps", str(steps), "--checkpoint-interval", "2",
        "--log-interval", "1", "--out", str(out), *extra,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout[proc.stdout.index("{"):])


def test_smoke_run_then_resume(tmp_path):
    first = _train(tmp_path, 3)
    run_dir = tmp_path / "cpu-small_small_r2_px32_seed0"
    assert first["steps"] == 3 and first["updates"] == 3
    ckpt = load_checkpoint(run_dir / "checkpoint.pt")
    assert ckpt["counters"]["steps"] == 3
    assert ckpt["replay"]["dir"] == "replay_step3" and ckpt["replay"]["size"] == 3
    assert [p.name for p in run_dir.glob("replay_step*")] == ["replay_step3"]
    assert json.loads((run_dir / "config.json").read_text())["heightmap_size"] == 32
    assert (run_dir / "scalars" / "train" / "grasp_success.csv").is_file()

    second = _train(tmp_path, 5, "--resume")
    assert second["start_step"] == 3 and second["steps"] == 5 and second["updates"] == 5
    resumed = load_checkpoint(run_dir / "checkpoint.pt")
    assert resumed["counters"]["steps"] == 5
    assert resumed["replay"]["size"] == 5  # the 3 saved transitions were loaded back, 2 new ones added
    assert [p.name for p in run_dir.glob("replay_step*")] == ["replay_step5"]
    assert load_actions(run_dir)["step"].tolist() == [1, 2, 3, 4, 5]  # one row per action, across the resume
    assert len((run_dir / "scalars" / "train" / "loss.csv").read_text().splitlines()) >= 5

    third = _train(tmp_path, 50, "--resume", "--max-minutes", "0.0001")  # the clock runs out after the first action
    assert third["stopped_by_time"] and third["steps"] == 6
    assert load_checkpoint(run_dir / "checkpoint.pt")["counters"]["steps"] == 6  # stopped with a checkpoint


def test_grasp_slide_bce_smoke_run(tmp_path):
    """The G&S agent's binary-classification baseline trains three FCNs on ClutterGraspSlide-v1; with ε = 1 and
    ``--explore-weights 0 1 1`` every action is a random slide."""
    summary = _train(tmp_path, 2, "--loss", "bce", "--eps-start", "1", "--eps-end", "1", "--explore-weights", "0", "1",
                     "1", preset="gs-cpu-small")
    assert summary["steps"] == 2 and summary["updates"] == 2
    run_dir = tmp_path / "gs-cpu-small_small_r2_px32_seed0"
    with open(run_dir / "actions.csv") as f:
        assert {row["primitive"] for row in csv.DictReader(f)} <= {"1", "2"}  # left or right slide
    ckpt = load_checkpoint(run_dir / "checkpoint.pt")
    assert ClutterConfig.from_json(ckpt["config"]).task == "grasp_slide"
    assert {key.split(".")[1] for key in ckpt["model"]} == {"grasp", "left_slide", "right_slide"}
    assert "target_value_network_params" not in str(list(ckpt["loss"]))  # BCE: no bootstrap, no target network


def test_outcome_tracker_reads_grasps_places_and_episodes():
    tracker = OutcomeTracker({"place": 1.0, "grasp": 0.8, "slide": 0.5}, actions_per_primitive=100, window=10)
    actions = torch.tensor([5, 150, 7, 250, 9])  # grasp, left slide, grasp, right slide, grasp
    rewards = torch.tensor([1.0, 0.5, 0.0, 0.0, 0.8])
    done = torch.tensor([False, False, False, False, True])
    finished = tracker.add(actions, rewards, done, terminated=done)
    assert tracker.grasp_success == pytest.approx(2 / 3)
    assert tracker.success_rate == pytest.approx(1 / 5)
    assert finished == [dict(actions=5, placed=1, success_rate=0.2, completed=True)]


def test_action_log_survives_a_resume_and_feeds_the_curves(tmp_path):
    rewards = {"place": 1.0, "grasp": 0.5}
    tracker = OutcomeTracker(rewards, actions_per_primitive=10, window=4, log_path=tmp_path / "actions.csv")
    tracker.add(torch.arange(6), torch.tensor([0.0, 0.0, 1.0, 0.5, 1.0, 0.0]), torch.zeros(6, dtype=torch.bool),
                torch.zeros(6, dtype=torch.bool))
    tracker.close()
    # resume from a checkpoint taken at step 4: rows 5 and 6 are dropped, then 4 new actions follow
    tracker = OutcomeTracker(rewards, 10, 4, log_path=tmp_path / "actions.csv", start_step=4)
    tracker.add(torch.arange(4), torch.tensor([1.0, 1.0, 1.0, 0.0]), torch.zeros(4, dtype=torch.bool),
                torch.zeros(4, dtype=torch.bool))
    tracker.close()
    a = load_actions(tmp_path)
    assert a["step"].tolist() == list(range(1, 9))
    assert a["placed"].tolist() == [0, 0, 1, 0, 1, 1, 1, 0]
    c = run_curves(tmp_path, window=4)
    assert c["first"] == dict(grasp_success=0.5, success_rate=0.25, actions=4)
    assert c["last"] == dict(grasp_success=0.75, success_rate=0.75, actions=4)
    summary = plot_training_curves({"run": tmp_path}, tmp_path / "curves.png", window=4)
    assert summary["run"]["last"]["success_rate"] == 0.75
    import matplotlib.image
    assert matplotlib.image.imread(tmp_path / "curves.png").shape[2] in (3, 4)


def test_trailing_mean_by_hand():
    hits, counts = np.array([1.0, 0.0, 1.0, 1.0]), np.array([1.0, 0.0, 1.0, 1.0])
    np.testing.assert_allclose(trailing_mean(hits, counts, 2), [1.0, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(trailing_mean(np.array([0.0, 1.0, 1.0]), np.ones(3), 2), [0.0, 0.5, 1.0])
    assert np.isnan(trailing_mean(np.zeros(2), np.zeros(2), 2)).all()
    with pytest.raises(FileNotFoundError):
        load_actions("/nonexistent/run")
