"""Configs from YAML/JSON files: validated field by field, with errors that name the file and the field; the recipes
of docs/configs/ (the presets until 2026-12 against what those presets trained); every shipped agent's config."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from maniskill_pnp.agents.pixel.checkpoint import ACTING_FIELDS, load_checkpoint
from maniskill_pnp.agents.pixel.config import RETIRED_PRESETS, ClutterConfig, presets
from maniskill_pnp.agents.pixel.factories import load_policy
from maniskill_pnp.agents.tabular.recipe import ConveyorConfig
from maniskill_pnp.cli import main as cli
from maniskill_pnp.quickstart import BUNDLED_AGENTS


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
    ("device: gpu", "device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got 'gpu'"),
])
def test_bad_files_name_the_file_and_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        ClutterConfig.from_file(path)
    assert "bad.yaml" in str(info.value)


def test_device_is_checked_and_a_config_written_before_it_loads():
    """``device`` (where the learner runs) is checked by name, and is no architecture field: a config.json written
    before the field existed loads with "auto"; a bench variant sets it like any field, checked before any training."""
    import re

    from maniskill_pnp.agents.pixel.config import ARCHITECTURE_FIELDS
    from maniskill_pnp.bench.training_throughput import parse_variant

    older = ClutterConfig.from_preset("gs-cpu-equi", seed=1).to_json()
    del older["device"]
    assert ClutterConfig.from_json(older) == ClutterConfig.from_preset("gs-cpu-equi", seed=1, device="auto")
    assert "device" not in ARCHITECTURE_FIELDS
    for good in ("auto", "cpu", "cuda", "cuda:1"):
        assert ClutterConfig(device=good).device == good
    expected = "device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got "
    for bad in ("gpu", "CPU", "cuda:", "cuda:x", "mps", "", 0, None):
        with pytest.raises(ValueError, match=re.escape(f"{expected}{bad!r}")):
            ClutterConfig(device=bad)
    assert parse_variant("gs-thesis,device=cuda") == ("gs-thesis", {"device": "cuda"})
    with pytest.raises(ValueError, match="variant 'gs-thesis,device=gpu': device must be"):
        parse_variant("gs-thesis,device=gpu")


def test_missing_file_and_cli_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.yaml"):
        ClutterConfig.from_file(tmp_path / "nowhere.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("num_rotations: four\n")
    with pytest.raises(SystemExit, match="train-clutter: config file .*bad.yaml: config field 'num_rotations' must be int"):
        cli(["train-clutter", "--config", str(bad)])


# ------------------------------------------------------------------------ the recipes that were presets until 2026-12
#: What each retired preset trained, as ClutterConfig.from_preset(name) resolved it before it became a config file
#: (every field that differs from the defaults; recorded from presets.yaml at commit 17987c1). The file
#: docs/configs/<name>.yaml must give exactly these values, whatever becomes of the presets it starts from.
THESIS_SIZE = dict(backbone="densenet121", heightmap_size=224, steps=90000, episodes=3000, target_update_interval=500,
                   batch_size=1, replay_capacity=50000, eps_decay_steps=10000, checkpoint_interval=500, log_interval=50,
                   success_window=200)
HARD = dict(task="grasp_slide", reward_scheme="unlock", backbone="equivariant", head_channels=32, hard_fraction=0.5,
            guard_force=20.0, updates_per_step=2, explore_weights=(2.0, 1.0, 1.0))
RETIRED_VALUES = {
    "gs-cpu-equi-hard": HARD,
    "gs-cpu-equi-keep": {**HARD, "mask_grasp_fit": True, "loss_cost": 1.0, "hard_sets": ("hard_train", "packed_train")},
    "gs-cpu-equi-fine": {**HARD, "mask_grasp_fit": True, "loss_cost": 1.0, "hard_sets": ("hard_train", "packed_train"),
                         "mask_fit_scale": 2},
    "gs-cpu-equi-each": {**HARD, "reward_scheme": "unlock_each", "mask_grasp_fit": True, "loss_cost": 1.0,
                         "hard_sets": ("hard_train", "packed_train"), "mask_fit_scale": 2},
    "cpu-equi-no-depth": dict(backbone="equivariant", use_depth=False),
    "cpu-densenet121-s8": dict(backbone="densenet121-s8", num_rotations=4),
    "cpu-resnet101-s8": dict(backbone="resnet101-s8", num_rotations=4),
    "gs-resnet101": {**THESIS_SIZE, "task": "grasp_slide", "backbone": "resnet101"},
    "gs-no-slide-reward": {**THESIS_SIZE, "task": "grasp_slide", "reward_scheme": "no_slide_reward"},
    "gs-double-dqn": {**THESIS_SIZE, "task": "grasp_slide", "double_dqn": True},
}
CONFIGS = Path(__file__).resolve().parents[1] / "docs" / "configs"


def test_every_retired_preset_is_a_config_file_and_every_config_file_names_its_recipe():
    """docs/configs/ holds the retired presets and the recipes of single experiments: each file says what it is and
    which entry of the experiment log used it, names a preset as its base and itself as the recipe."""
    assert set(RETIRED_VALUES) == set(RETIRED_PRESETS)
    assert {p.stem for p in CONFIGS.glob("*.yaml")} >= set(RETIRED_PRESETS)
    for path in CONFIGS.glob("*.yaml"):
        first = path.read_text().splitlines()[0]
        assert first.startswith(f"# {path.stem}: ") and "docs/experiments.md" in first, first  # what it is, who used it
        cfg = ClutterConfig.from_file(path)
        assert cfg.preset in presets() and cfg.name == path.stem


@pytest.mark.parametrize("name", sorted(RETIRED_VALUES))
def test_a_config_file_trains_what_its_preset_did(name, monkeypatch, capsys):
    """``train-clutter --config docs/configs/NAME.yaml --seed S`` builds the values ``--preset NAME --seed S`` built,
    in the run folder it used; the config records the base preset and the name."""
    path = CONFIGS / f"{name}.yaml"
    expected = {**ClutterConfig().to_json(), **RETIRED_VALUES[name], "seed": 1}
    cfg = ClutterConfig.from_file(path, seed=1)
    assert (cfg.preset, cfg.name) == (RETIRED_PRESETS[name], name)
    values = cfg.to_json()
    assert {k: v for k, v in values.items() if k not in ("preset", "name")} == \
           {k: v for k, v in expected.items() if k not in ("preset", "name")}
    assert cfg.run_name == f"{name}_{cfg.backbone}_r{cfg.num_rotations}_px{cfg.heightmap_size}_seed1"
    # the command line builds the same config (the training itself replaced by a stub)
    trained = []
    monkeypatch.setattr("maniskill_pnp.agents.pixel.recipe.main", lambda c: trained.append(c) or {"run": str(c.run_dir)})
    cli(["train-clutter", "--config", str(path), "--seed", "1"])
    assert trained == [cfg] and cfg.run_name in capsys.readouterr().out


def test_configs_recorded_under_a_retired_preset_load_as_its_config_file(tmp_path):
    """A run's config.json (or a checkpoint's config) from before: the same values, the same run folder."""
    cfg = ClutterConfig.from_file(CONFIGS / "gs-cpu-equi-each.yaml", seed=0)
    old = {**cfg.to_json(), "preset": "gs-cpu-equi-each"}
    old.pop("name")  # configs of that time had no name field
    assert ClutterConfig.from_json(old) == cfg
    (tmp_path / "config.json").write_text(__import__("json").dumps(old))
    assert ClutterConfig.from_file(tmp_path / "config.json") == cfg  # `train-clutter --config <old run>/config.json`
    assert cfg.run_name == "gs-cpu-equi-each_equivariant_r16_px64_seed0"  # the folder the experiment log names
    with pytest.raises(ValueError, match="now a config file"):
        ClutterConfig.from_preset("gs-cpu-equi-hard")


#: Every agent file the repository ships or keeps: the bundled ones and the experiments' exported agents.
AGENT_FILES = sorted([*(CONFIGS.parent / "agents").glob("*.pt"), *BUNDLED_AGENTS.values()])


@pytest.mark.parametrize("path", AGENT_FILES, ids=lambda p: p.name)
def test_every_shipped_agent_loads(path):
    """Each exported agent's config loads, under the name it was trained as (a bundled agent as its preset, an
    experiment's agent ``<recipe>-seed<S>.pt`` as the recipe it names, or ``<recipe>-<variant>-seed<S>.pt`` where its
    command line changed the recipe's fields), and its weights fit the network of that config (no env is made)."""
    payload = load_checkpoint(path)
    cfg = ClutterConfig.from_json(payload["config"])
    actor, acting, _ = load_policy(path, torch.device("cpu"))
    assert acting.run_name == cfg.run_name and actor.q_network.primitives == cfg.primitives
    stem, recipe = path.stem.rsplit("-seed", 1)[0], cfg.name or cfg.preset
    assert stem == recipe or stem.startswith(f"{recipe}-"), (stem, recipe)
    assert cfg.run_name.startswith(f"{recipe}_") and cfg.preset in presets()
    if stem != recipe:  # a variant: its command line changed some of the recipe's fields, not only seed and folder
        base = ClutterConfig.from_preset(cfg.preset, seed=cfg.seed).to_json()
        trained = cfg.to_json()
        assert {k for k in trained if trained[k] != base[k]} - {"seed", "out", "name", *ACTING_FIELDS}, stem
    if (CONFIGS / f"{recipe}.yaml").exists():  # trained with what the config file repeats: only the command line differs
        repeated = ClutterConfig.from_file(CONFIGS / f"{recipe}.yaml")
        assert (cfg.preset, cfg.name) == (repeated.preset, recipe)
        trained, repeated = cfg.to_json(), repeated.to_json()
        differ = {k for k in trained if trained[k] != repeated[k]}
        assert differ <= {"steps", "max_minutes", "seed", "out", *ACTING_FIELDS}, differ
    else:
        assert (cfg.preset, cfg.name) == (recipe, None)
    assert set(payload["model"]) and payload["counters"]["steps"] > 0
