"""Configs from YAML/JSON files: validated field by field, with errors that name the file and the field."""

from __future__ import annotations

import pytest

from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig
from maniskill_pnp.cli import main as cli


def test_yaml_values_override_defaults_and_round_trip(tmp_path):
    path = tmp_path / "run.yaml"
    path.write_text("steps: 20\nlr: 0.001\nout: runs/x\nuse_depth: false\n")
    cfg = ClutterConfig.from_file(path)
    assert (cfg.steps, cfg.lr, str(cfg.out), cfg.use_depth) == (20, 0.001, "runs/x", False)
    assert cfg.batch_size == ClutterConfig().batch_size  # missing fields keep their defaults
    (tmp_path / "saved.json").write_text(__import__("json").dumps(cfg.to_json()))
    assert ClutterConfig.from_file(tmp_path / "saved.json") == cfg  # a run's config.json loads back
    assert ConveyorConfig.from_json(ConveyorConfig().to_json()) == ConveyorConfig()


@pytest.mark.parametrize("text, message", [
    ("steps: abc", "'steps' must be int, got 'abc'"),
    ("stepz: 3", "unknown config fields \\['stepz'\\]"),
    ("use_depth: 1", "'use_depth' must be bool"),
    ("lr: [1", "not valid YAML/JSON"),
    ("- 1\n- 2", "must be a mapping"),
    ("steps: 0", "steps must be >= 1"),
    ("backbone: vgg", "unknown backbone 'vgg'"),
])
def test_bad_files_name_the_file_and_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        ClutterConfig.from_file(path)
    assert "bad.yaml" in str(info.value)


def test_missing_file_and_cli_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.yaml"):
        ClutterConfig.from_file(tmp_path / "nowhere.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("num_rotations: four\n")
    with pytest.raises(SystemExit, match="train-clutter: config file .*bad.yaml: config field 'num_rotations' must be int"):
        cli(["train-clutter", "--config", str(bad)])
