"""The recipes' explicit logger choice: TensorBoard events through TorchRL's TensorboardLogger, CSV by default, clear
errors for a bad value or a missing extra, and old config.json files (without the field) still load."""

from __future__ import annotations

import math

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from maniskill_pnp.agents import run_io
from maniskill_pnp.agents.pixel import recipe as clutter_recipe
from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.metrics import ACTION_COLUMNS
from maniskill_pnp.agents.tabular import recipe as conveyor_recipe
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig
from maniskill_pnp.cli import main as cli


def _scalars(run_dir) -> dict[str, list[tuple[int, float]]]:
    """``tag -> [(step, value)]`` of the run folder's single TensorBoard event file."""
    (events,) = run_dir.glob("events.out.tfevents.*")
    assert events.stat().st_size > 0
    acc = EventAccumulator(str(events))
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def _check_tags(scalars: dict, tags: set[str], last_step: int) -> None:
    assert tags <= set(scalars), sorted(scalars)
    for tag in tags:
        assert scalars[tag], tag
        assert all(math.isfinite(v) for _, v in scalars[tag]), (tag, scalars[tag])
    assert scalars["train/success_rate"][-1][0] == last_step
    assert all(0.0 <= v <= 1.0 for _, v in scalars["train/success_rate"])


def test_conveyor_run_logs_to_tensorboard(tmp_path):
    cfg = ConveyorConfig(steps=6, log_interval=3, seed=1, logger="tensorboard", out=tmp_path)
    summary = conveyor_recipe.main(cfg)
    assert summary["steps"] == 6
    scalars = _scalars(cfg.run_dir)
    _check_tags(scalars, {"train/success_rate", "train/episodes", "train/epsilon", "time/wall_s"}, last_step=6)
    assert [s for s, _ in scalars["train/epsilon"]] == [3, 6]
    assert not (cfg.run_dir / "scalars").exists()  # no CSV logs beside the events
    assert conveyor_recipe.load_qtable(cfg.run_dir / "qtable.pt")[1] == cfg  # the saved config keeps the logger


def test_clutter_run_logs_to_tensorboard(tmp_path):
    cfg = ClutterConfig.from_preset("cpu-small", heightmap_size=32, num_rotations=2, num_objects=2, steps=2,
                                    checkpoint_interval=2, log_interval=1, logger="tensorboard", collector="direct",
                                    out=tmp_path)
    summary = clutter_recipe.main(cfg)
    assert summary["steps"] == 2
    scalars = _scalars(cfg.run_dir)
    _check_tags(scalars, {"train/success_rate", "train/grasp_success", "train/loss", "train/epsilon", "train/reward",
                          "train/episodes", "time/wall_s"}, last_step=2)
    assert [s for s, _ in scalars["train/grasp_success"]] == [1, 2]
    assert not (cfg.run_dir / "scalars").exists()
    assert (cfg.run_dir / "actions.csv").read_text().splitlines()[0] == ",".join(ACTION_COLUMNS)


@pytest.mark.parametrize("config", [ConveyorConfig, ClutterConfig])
def test_bad_logger_names_the_valid_values(config):
    with pytest.raises(ValueError, match=r"unknown logger 'wandb'; valid: \['csv', 'tensorboard'\]"):
        config(logger="wandb")
    assert config().logger == "csv"


@pytest.mark.parametrize("config", [ConveyorConfig, ClutterConfig])
def test_old_config_without_the_logger_field_loads_as_csv(config, tmp_path):
    old = config().to_json()
    del old["logger"]
    assert config.from_json(old).logger == "csv"
    path = tmp_path / "config.json"
    path.write_text(__import__("json").dumps(old))
    assert config.from_file(path) == config()


def test_missing_tensorboard_names_the_extra_before_anything_is_built(tmp_path, monkeypatch):
    monkeypatch.setattr(run_io, "_tensorboard_installed", lambda: False)
    with pytest.raises(ImportError, match=r"pip install 'maniskill_pnp\[tensorboard\]'"):
        conveyor_recipe.main(ConveyorConfig(logger="tensorboard", out=tmp_path))
    with pytest.raises(run_io.MissingExtraError, match="tensorboard"):
        run_io.make_logger(tmp_path / "run", "tensorboard")
    # the command line reports it as one line (train-clutter turns ValueErrors into a message)
    with pytest.raises(SystemExit, match=r"train-clutter: logger 'tensorboard' needs .*maniskill_pnp\[tensorboard\]"):
        cli(["train-clutter", "--logger", "tensorboard", "--out", str(tmp_path)])
    assert list(tmp_path.iterdir()) == []
