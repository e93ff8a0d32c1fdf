"""The pixel actor (argmax layout, ε-greedy draws), presets, the training metrics (and their agreement with the
evaluation), and the clutter DQN recipe through its command line: a smoke run with resume, and the BCE baseline."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Categorical
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from maniskill_pnp.agents.pixel.curves import load_actions, plot_training_curves, run_curves, trailing_mean
from maniskill_pnp.agents.pixel.checkpoint import load_checkpoint
from maniskill_pnp.agents.pixel.config import PRESETS_FILE, RETIRED_PRESETS, ClutterConfig, preset_descriptions, presets
from maniskill_pnp.agents.pixel.evaluate import EpisodeTally
from maniskill_pnp.agents.pixel.factories import make_action_mask, make_env, make_model, make_policy
from maniskill_pnp.agents.pixel.metrics import ACTION_COLUMNS, OutcomeTracker
from maniskill_pnp.agents.pixel.policy import make_pixel_policy
from maniskill_pnp.agents.pixel.replay import NEXT_MASK_KEY, unpack_transition
from maniskill_pnp.cell.pixel_action import PixelActionLayout

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


#: A few fields of every preset (task, backbone, loss, rotations, heightmap size, steps, batch size, and the ablation
#: each gs-* preset exists for). The recipes that were presets until 2026-12 are checked in tests/test_config_files.py.
PRESET_VALUES = {
    "cpu-small": dict(task="grasp", backbone="small", loss="dqn", num_rotations=16, heightmap_size=64, steps=300, batch_size=4),
    "cpu-equi": dict(task="grasp", backbone="equivariant", num_rotations=16, heightmap_size=64, steps=300, batch_size=4),
    "thesis": dict(task="grasp", backbone="densenet121", num_rotations=16, heightmap_size=224, num_objects=10,
                   episodes=3000, steps=90_000, batch_size=1, replay_capacity=50_000, success_window=200),
    "gs-cpu-small": dict(task="grasp_slide", backbone="small", num_rotations=16, heightmap_size=64, steps=300),
    "gs-cpu-equi": dict(task="grasp_slide", backbone="equivariant", num_rotations=16, head_channels=32, heightmap_size=64,
                        steps=300),
    "gs-cpu-equi-fit": dict(task="grasp_slide", backbone="equivariant", head_channels=32, hard_fraction=0.5,
                            guard_force=20.0, reward_scheme="unlock", explore_weights=(2.0, 1.0, 1.0), updates_per_step=2,
                            mask_grasp_fit=True, mask_fit_scale=1, loss_cost=0.0, hard_sets=("hard_train",)),
    "gs-thesis": dict(task="grasp_slide", backbone="densenet121", num_rotations=16, heightmap_size=224, steps=90_000,
                      eps_decay_steps=10_000, target_update_interval=500, checkpoint_interval=500, log_interval=50),
    "gs-cpu-equi-no-depth": dict(task="grasp_slide", backbone="equivariant", head_channels=32, use_depth=False,
                                 loss="dqn", reward_scheme="default"),
    "gs-cpu-equi-bce": dict(task="grasp_slide", backbone="equivariant", head_channels=32, use_depth=True, loss="bce",
                            delay_value=False, reward_scheme="default"),
    "gs-cpu-equi-no-slide-reward": dict(task="grasp_slide", backbone="equivariant", head_channels=32, use_depth=True,
                                        loss="dqn", reward_scheme="no_slide_reward"),
    "gs-no-depth": dict(task="grasp_slide", use_depth=False, backbone="densenet121", num_rotations=16, heightmap_size=224),
    "gs-bce": dict(task="grasp_slide", backbone="densenet121", loss="bce", delay_value=False, heightmap_size=224),
}


@pytest.mark.parametrize("name", list(PRESET_VALUES))
def test_every_preset_loads_with_its_values(name):
    cfg = ClutterConfig.from_preset(name)
    assert cfg.preset == name and cfg.name is None and cfg.run_name.startswith(f"{name}_")
    assert {field: getattr(cfg, field) for field in PRESET_VALUES[name]} == PRESET_VALUES[name]


@pytest.mark.parametrize("name", list(PRESET_VALUES))
def test_every_preset_has_eight_jaw_orientations(name):
    """A parallel-jaw grasp at rotation r and r + R/2 is one jaw line: R = 16 gives 8 orientations 22.5 degrees apart."""
    cfg = ClutterConfig.from_preset(name)
    assert cfg.num_rotations % 2 == 0 and cfg.num_rotations // 2 >= 8


def test_presets_file_is_the_list_of_presets_and_overrides_apply():
    assert list(presets()) == list(PRESET_VALUES)
    assert PRESETS_FILE.name == "presets.yaml" and PRESETS_FILE.is_file()
    cfg = ClutterConfig.from_preset("thesis", num_rotations=8, seed=3)
    assert (cfg.num_rotations, cfg.heightmap_size) == (8, 224) and cfg.run_name.endswith("seed3")
    assert ClutterConfig.from_preset("gs-cpu-small").primitives == ("grasp", "left_slide", "right_slide")


def test_presets_are_few_with_one_line_each_in_the_help():
    """A user picks from at most 12 presets, each described by one line that `train-clutter --help` shows; the
    recipes that left the list are not presets any more."""
    descriptions = preset_descriptions()
    assert list(descriptions) == list(presets()) and len(descriptions) <= 12
    assert all(text and "\n" not in text and len(text) <= 100 for text in descriptions.values())
    assert not set(presets()) & set(RETIRED_PRESETS) and set(RETIRED_PRESETS.values()) <= set(presets())
    from maniskill_pnp.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["train-clutter"]
    text = sub.format_help()
    for name, line in descriptions.items():
        assert f"  {name} " in text and line in text
    assert "docs/configs/" in text
    with pytest.raises(ValueError, match="'gs-cpu-equi-each' is now a config file: .*docs/configs/gs-cpu-equi-each.yaml"):
        ClutterConfig.from_preset("gs-cpu-equi-each")


def test_a_run_name_starts_with_the_name_where_one_is_set():
    cfg = ClutterConfig.from_preset("gs-cpu-equi", name="my-variant", seed=2)
    assert cfg.run_name == "my-variant_equivariant_r16_px64_seed2" and cfg.preset == "gs-cpu-equi"
    for bad in ("", "a/b", "../x", "two words"):
        with pytest.raises(ValueError, match="name must be"):
            ClutterConfig.from_preset("gs-cpu-equi", name=bad)


def test_unknown_preset_lists_the_valid_ones():
    with pytest.raises(ValueError, match=r"unknown preset 'gs-huge'; valid: \['cpu-small', 'cpu-equi', 'thesis'"):
        ClutterConfig.from_preset("gs-huge")


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
    """``maniskill-pnp train-clutter`` with tiny settings, parsed and run by the command's own ``main`` in this
    process (its JSON summary read back from stdout), collecting in the learner's process (``--collector direct``:
    these tests are about checkpoints, resume and losses; the console script as a process is tested in test_cli, a
    resume in a fresh process in test_crash_safe_training, the worker-process collector in test_collection)."""
    import contextlib
    import io

    from maniskill_pnp.cli import main as cli

    argv = ["train-clutter", "--preset", preset, "--heightmap-size", "32", "--num-rotations", "2", "--num-objects", "2",
            "--steps", str(steps), "--checkpoint-interval", "2", "--log-interval", "1", "--collector", "direct",
            "--out", str(out), *extra]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        cli(argv)
    text = printed.getvalue()
    return json.loads(text[text.index("{"):])


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
    assert summary["faults_per_100_actions"] == 100.0 * summary["faults"] / 2
    run_dir = tmp_path / "gs-cpu-small_small_r2_px32_seed0"
    with open(run_dir / "actions.csv") as f:
        assert {row["primitive"] for row in csv.DictReader(f)} <= {"1", "2"}  # left or right slide
    ckpt = load_checkpoint(run_dir / "checkpoint.pt")
    assert ClutterConfig.from_json(ckpt["config"]).task == "grasp_slide"
    assert {key.split(".")[1] for key in ckpt["model"]} == {"grasp", "left_slide", "right_slide"}
    assert "target_value_network_params" not in str(list(ckpt["loss"]))  # BCE: no bootstrap, no target network


def test_device_cpu_trains_what_auto_trains_without_a_gpu_and_resumes_under_another_device(tmp_path, monkeypatch):
    """``--device cpu`` trains exactly what the default ``auto`` trains on a machine without a GPU (the same actions
    and weights), train_summary.json names the device used, and a run resumes under another device setting (device
    is no architecture field)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # "auto" finds no GPU, on any machine
    summaries = [_train(tmp_path / "auto", 2), _train(tmp_path / "cpu", 2, "--device", "cpu")]
    assert [s["device"] for s in summaries] == ["cpu", "cpu"] and all(s["updates"] == 2 for s in summaries)
    runs = [tmp_path / name / "cpu-small_small_r2_px32_seed0" for name in ("auto", "cpu")]
    assert [json.loads((r / "config.json").read_text())["device"] for r in runs] == ["auto", "cpu"]
    assert (runs[0] / "actions.csv").read_text() == (runs[1] / "actions.csv").read_text()
    auto, cpu = (load_checkpoint(r) for r in runs)
    for part in ("model", "loss"):
        assert auto[part].keys() == cpu[part].keys()
        assert all(torch.equal(auto[part][k], cpu[part][k]) for k in auto[part]), part
    resumed = _train(tmp_path / "cpu", 3, "--resume", "--device", "auto")
    assert resumed["start_step"] == 2 and resumed["steps"] == 3 and resumed["device"] == "cpu"


def test_a_missing_gpu_is_a_clear_error_before_anything_is_built(tmp_path, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(SystemExit, match="train-clutter: device 'cuda': CUDA is not available on this machine"):
        _train(tmp_path, 2, "--device", "cuda")
    with pytest.raises(SystemExit, match="train-clutter: device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got 'gpu'"):
        _train(tmp_path, 2, "--device", "gpu")
    assert not any(tmp_path.iterdir())


@pytest.mark.gpu
def test_cuda_learner_trains_and_its_checkpoint_loads_on_the_cpu(tmp_path):
    """``device="cuda"``: the network, the target network and the optimizer state live on the GPU, while a worker
    process acts with a CPU copy; resumed with the direct collector, the learner's own policy acts on the GPU; the
    checkpoint loads on the CPU, as an actor and as a run resumed there."""
    import dataclasses

    from maniskill_pnp.agents.pixel.factories import load_policy
    from maniskill_pnp.agents.pixel.recipe import main as train

    cfg = ClutterConfig.from_preset("cpu-small", heightmap_size=32, num_rotations=2, num_objects=2, steps=2,
                                    checkpoint_interval=1, log_interval=1, device="cuda", collector="process",
                                    out=tmp_path)
    first = train(cfg)
    assert first["device"] == f"cuda:{torch.cuda.current_device()}" and first["updates"] == 2
    raw = torch.load(cfg.run_dir / "checkpoint.pt", weights_only=True)  # each tensor on the device it was saved from
    assert all(t.is_cuda for part in ("model", "loss") for t in raw[part].values())  # the target network among them
    assert any("target_value_network_params" in k for k in raw["loss"])
    assert raw["optimizer"]["state"] and all(s["momentum_buffer"].is_cuda for s in raw["optimizer"]["state"].values())

    on_gpu = train(dataclasses.replace(cfg, steps=3, resume=True, collector="direct"))
    assert on_gpu["start_step"] == 2 and on_gpu["steps"] == 3 and on_gpu["device"] == first["device"]
    payload = load_checkpoint(cfg.run_dir)
    assert all(t.device.type == "cpu" for part in ("model", "loss") for t in payload[part].values())
    actor, _, counters = load_policy(cfg.run_dir / "checkpoint.pt", torch.device("cpu"))
    assert counters["steps"] == 3 and {p.device.type for p in actor.parameters()} == {"cpu"}
    on_cpu = train(dataclasses.replace(cfg, steps=4, resume=True, collector="direct", device="cpu"))
    assert on_cpu["start_step"] == 3 and on_cpu["steps"] == 4 and on_cpu["device"] == "cpu"


GS = ("grasp", "left_slide", "right_slide")


def outcome_frames(primitive, reward, grasped, placed, done, slide_changed=None, fault=None) -> TensorDict:
    """Flat collector-like frames of one env: the ``"next"`` outcome entries the metrics read."""
    n = len(primitive)
    flags = lambda values: torch.tensor(values, dtype=torch.bool).reshape(n, 1)  # noqa: E731
    nxt = dict(primitive_index=torch.tensor(primitive).reshape(n, 1), reward=torch.tensor(reward).reshape(n, 1),
               grasp_success=flags(grasped), placed_objects=torch.tensor(placed, dtype=torch.int64).reshape(n, 1),
               done=flags(done), terminated=flags(done),
               slide_changed=flags(slide_changed or [False] * n), fault=flags(fault or [False] * n))
    return TensorDict(action=torch.arange(n), next=nxt, batch_size=[n])


def test_outcome_tracker_reads_grasps_places_and_episodes_from_the_outcome_keys():
    tracker = OutcomeTracker(GS, window=10)
    # grasp placing two objects, slide that changed the scene, failed grasp, invalid action (no primitive ran),
    # grasp and hold
    frames = outcome_frames(primitive=[0, 1, 0, -1, 0], reward=[1.0, 0.5, 0.0, 0.0, 0.8],
                            grasped=[True, False, False, False, True], placed=[2, 0, 0, 0, 0],
                            done=[False, False, False, False, True], slide_changed=[False, True, False, False, False],
                            fault=[False, False, False, False, True])
    finished = tracker.add(frames)
    assert tracker.grasp_success == pytest.approx(2 / 3) and tracker.last_grasps == 2
    assert tracker.success_rate == pytest.approx(2 / 5)  # objects placed / actions
    assert tracker.faults_per_100_actions == pytest.approx(20.0) and tracker.last_faults == 1
    assert finished == [dict(actions=5, placed=2, success_rate=0.4, cleared=True)]


def test_action_log_survives_a_resume_and_feeds_the_curves(tmp_path):
    tracker = OutcomeTracker(("grasp",), window=4, log_path=tmp_path / "actions.csv")
    tracker.add(outcome_frames([0] * 6, [0.0, 0.0, 1.0, 0.5, 1.0, 0.0], grasped=[0, 0, 1, 1, 1, 0],
                               placed=[0, 0, 1, 0, 1, 0], done=[0] * 6))
    tracker.close()
    # resume from a checkpoint taken at step 4: rows 5 and 6 are dropped, then 4 new actions follow
    tracker = OutcomeTracker(("grasp",), 4, log_path=tmp_path / "actions.csv", start_step=4)
    tracker.add(outcome_frames([0] * 4, [1.0, 1.0, 1.0, 0.0], grasped=[1, 1, 1, 0], placed=[1, 1, 1, 0], done=[0] * 4))
    tracker.close()
    a = load_actions(tmp_path)
    assert list(a) == list(ACTION_COLUMNS)
    assert a["step"].tolist() == list(range(1, 9))
    assert a["placed"].tolist() == [0, 0, 1, 0, 1, 1, 1, 0]
    c = run_curves(tmp_path, window=4)
    assert c["first"] == dict(grasp_success=0.5, success_rate=0.25, actions=4)
    assert c["last"] == dict(grasp_success=0.75, success_rate=0.75, actions=4)
    assert c["minutes"] is None  # no time log
    # the CSV logger's time/wall_s: the first session logged steps 2 and 4, the resumed one (clock from 0) 6 and 8
    (tmp_path / "scalars" / "time").mkdir(parents=True)
    (tmp_path / "scalars" / "time" / "wall_s.csv").write_text("2,60\n4,120\n6,30\n8,90\n")
    minutes = run_curves(tmp_path, window=4)["minutes"]
    np.testing.assert_allclose(minutes, [0.5, 1, 1.5, 2, 2.25, 2.5, 3, 3.5])
    summary = plot_training_curves({"run": tmp_path}, tmp_path / "curves.png", window=4)
    assert summary["run"]["last"]["success_rate"] == 0.75 and summary["run"]["minutes"] == 3.5
    import matplotlib.image
    assert matplotlib.image.imread(tmp_path / "curves.png").shape[2] in (3, 4)


def test_an_older_action_log_is_resumed_and_plotted(tmp_path):
    """A run folder of an older version has fewer columns: its rows keep theirs on resume, and the curves read it."""
    old = ["step,primitive,action,reward,grasp_attempt,grasped,placed,episode_end", "1,0,5,0,1,0,0,0", "2,0,7,1,1,1,1,0",
           "3,1,9,0.5,0,0,0,0"]
    (tmp_path / "actions.csv").write_text("\n".join(old) + "\n")
    assert load_actions(tmp_path)["placed"].tolist() == [0, 1, 0]
    tracker = OutcomeTracker(GS, 4, log_path=tmp_path / "actions.csv", start_step=2)
    tracker.add(outcome_frames([2], [0.5], grasped=[0], placed=[0], done=[0], slide_changed=[1]))
    tracker.close()
    a = load_actions(tmp_path)
    assert a["step"].tolist() == [1, 2, 3] and a["grasped"].tolist() == [0, 1, 0] and a["grasp_attempt"].tolist() == [1, 1, 0]
    assert np.isnan(a["slide_changed"][:2]).all() and a["slide_changed"][2] == 1


def test_training_metrics_and_evaluation_agree_on_the_same_actions(tmp_path):
    """One env, random grasps and slides: the rows the training writes to actions.csv and the evaluation's per-step
    accounting (from the env's info of the same steps) count the same grasp attempts, grasps and placed objects."""
    cfg = ClutterConfig.from_preset("gs-cpu-small", heightmap_size=32, num_rotations=2, num_objects=2,
                                    explore_weights=(2, 1, 1))
    env = make_env(cfg)
    env.set_seed(5)
    torch.manual_seed(5)
    primitives = env.base_env.primitive_names
    _, explore, _ = make_policy(cfg, make_model(cfg).eval(), env.action_spec, eps=1.0)
    tracker = OutcomeTracker(primitives, window=100, log_path=tmp_path / "actions.csv")
    tallies, infos = [EpisodeTally(primitives)], []
    td = env.reset()
    try:
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            for _ in range(6):
                td = env.step(explore(td))
                info = env.base_env.get_info()  # the info of this step, as the gymnasium env returned it
                infos.append(info)
                tallies[-1].add(info)
                tracker.add(td)
                if td.get(("next", "done")).any():
                    td, tallies = env.reset(), tallies + [EpisodeTally(primitives)]
                else:
                    td = step_mdp(td)
    finally:
        tracker.close()
        env.close()
    with open(tmp_path / "actions.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 6 == sum(t.actions for t in tallies)
    for key, tally_key in (("grasp_attempt", "grasp_attempts"), ("grasped", "grasps"), ("placed", "placed")):
        assert sum(int(r[key]) for r in rows) == sum(getattr(t, tally_key) for t in tallies), key
    for row, info in zip(rows, infos):  # and step by step
        assert int(row["primitive"]) == int(info["primitive_index"])
        assert int(row["grasped"]) == int(info["grasp_success"]) and int(row["placed"]) == int(info["placed_objects"])
        assert int(row["slide_changed"]) == int(info["slide_changed"]) and int(row["fault"]) == int(info["fault"])
    kinds = {primitives[int(r["primitive"])] for r in rows if int(r["primitive"]) >= 0}
    assert "grasp" in kinds and kinds & {"left_slide", "right_slide"}, kinds  # both kinds of action were compared


def test_trailing_mean_by_hand():
    hits, counts = np.array([1.0, 0.0, 1.0, 1.0]), np.array([1.0, 0.0, 1.0, 1.0])
    np.testing.assert_allclose(trailing_mean(hits, counts, 2), [1.0, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(trailing_mean(np.array([0.0, 1.0, 1.0]), np.ones(3), 2), [0.0, 0.5, 1.0])
    assert np.isnan(trailing_mean(np.zeros(2), np.zeros(2), 2)).all()
    with pytest.raises(FileNotFoundError):
        load_actions("/nonexistent/run")


def test_fit_heightmap_training_keeps_the_next_states_fit_mask_for_the_bootstrap(tmp_path):
    """``--mask-fit-scale 2``: the env observes 64 px fit heightmaps beside the 32 px ones, the actor masks with them,
    and the replay keeps the mask of each next state that the actor computed with them (as bits) for the loss's
    masked bootstrap: fewer grasps than the material alone allows."""
    summary = _train(tmp_path, 2, "--mask-grasp-fit", "--mask-fit-scale", "2", preset="gs-cpu-small")
    assert summary["steps"] == 2 and summary["updates"] == 2
    run_dir = tmp_path / "gs-cpu-small_small_r2_px32_seed0"
    ckpt = load_checkpoint(run_dir / "checkpoint.pt")
    cfg = ClutterConfig.from_json(ckpt["config"])
    assert cfg.mask_fit_scale == 2
    stored = unpack_transition(TensorDict.load_memmap(run_dir / ckpt["replay"]["dir"] / "storage")[:2])
    assert ("next", "fit_heightmap") not in stored.keys(True)
    grasps = stored[NEXT_MASK_KEY].reshape(2, 3, -1)[:, 0]  # the grasp primitive's allowed actions
    material = make_action_mask(replace(cfg, mask_grasp_fit=False, mask_fit_scale=1)).from_observation(stored["next", "observation"])
    material = material.reshape(2, 3, -1)[:, 0]
    assert (grasps <= material).all() and grasps.sum() < material.sum() and stored[NEXT_MASK_KEY].any(dim=1).all()
