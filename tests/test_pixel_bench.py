"""The pixel-network benchmarks at tiny sizes: they run, and their JSON reports hold positive numbers and the ratios."""

from __future__ import annotations

import json

import pytest
import torch

from maniskill_pnp.agents.pixel.fcn import MultiPrimitiveQNetwork
from maniskill_pnp.bench.pixel_dqn import (
    DecisionCostBenchConfig,
    run_decision_cost,
    set_memory_efficient,
)
from maniskill_pnp.bench.training_throughput import TrainingThroughputBenchConfig, run as run_throughput
from maniskill_pnp.cli import main as cli


def test_memory_efficient_switch_reaches_every_dense_layer():
    net = MultiPrimitiveQNetwork(("grasp",), num_rotations=1, backbone="densenet121", use_depth=False)
    assert set_memory_efficient(net, False) == 58  # DenseNet-121: 6 + 12 + 24 + 16 dense layers
    assert not any(getattr(m, "memory_efficient", False) for m in net.modules())


def test_pixel_memory_tiny(tmp_path, capsys):
    """The command line ``bench pixel-memory`` (parsed and run by the command's ``main`` here; its variants measure in
    processes of their own): both DenseNet-121 variants, their memory and step times, and the ratio."""
    cli(["bench", "pixel-memory", "--rotations", "2", "--heightmap-size", "32", "--num-primitives", "1", "--repeats", "1",
         "--threads", "1", "--out", str(tmp_path)])
    report = json.loads((tmp_path / "pixel_memory.json").read_text())
    assert report["machine"]["cpus"] >= 1 and "ratio" in capsys.readouterr().out
    results = report["results"]
    for name, flag in (("efficient", True), ("non_efficient", False)):
        v = results[name]
        assert v["memory_efficient"] is flag and v["dense_layers"] == 2 * 58  # colour and depth trunks
        assert v["rss_growth_bytes"] > 0 and all(s > 0 for s in v["step_s"])
        assert (v["cuda_peak_bytes"] is not None) == torch.cuda.is_available()
    assert results["ratio_rss_efficient_over_non_efficient"] > 0


def test_decision_cost_tiny(tmp_path, capsys):
    out = tmp_path / "decision_cost.json"
    run_decision_cost(DecisionCostBenchConfig(backbone="small", num_rotations=2, heightmap_size=32, num_primitives=(1, 2),
                                              warmup=1, repeats=2, threads=1, out=out))
    report = json.loads(out.read_text())
    for n in (1, 2):
        r = report["results"][f"primitives_{n}"]
        assert r["decision_s_median"] > 0 and r["trunks_s_median"] > 0 and r["ratio"] > 0
        assert len(r["trunk_batch"]) == 2 * n and r["trunk_batch"][0][0] == 2  # B*R images per trunk call
        assert r["breakdown_s"]["trunks"] > 0 and r["breakdown_s"]["heads"] > 0
    assert report["machine"]["cpus"] >= 1
    assert "ratio" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["bench", "pixel-memory", "--num-primitives", "1", "3"], "one --num-primitives"),
    (["bench", "pixel-memory", "--backbone", "small"], "densenet121"),
    (["bench", "decision-cost", "--num-primitives", "4"], "num_primitives"),
    (["bench", "decision-cost", "--repeats", "0"], "repeats"),
    (["bench", "training-throughput", "--variants", "gs-cpu-tiny"], "unknown preset 'gs-cpu-tiny'"),
    (["bench", "training-throughput", "--variants", "cpu-equi,num_rotations"], "is not FIELD=VALUE"),
    (["bench", "training-throughput", "--variants", "cpu-equi,num_rotations=eight"], "num_rotations"),
    (["bench", "training-throughput", "--variants", "cpu-equi,learning_rate=0.1"], "unknown config fields"),
    (["bench", "training-throughput", "--minutes", "0"], "minutes"),
])
def test_bad_bench_options_are_clear_errors(argv, message, tmp_path):
    with pytest.raises(SystemExit, match=message):
        cli([*argv, "--out", str(tmp_path)])


def test_training_throughput_trains_each_variant_in_turn(tmp_path, capsys):
    """Two tiny variants (one collecting in the learner's process, one with a process collector whose worker steps
    the simulator beside the learner), each trained for real for a few seconds: actions, updates per action as
    configured, a rate and the ratio table."""
    tiny = "num_objects=2,heightmap_size=32,num_rotations=4,checkpoint_interval=1000"
    variants = (f"cpu-small,{tiny},collector=direct", f"cpu-equi,{tiny},collector=process,sync=false")
    out = tmp_path / "throughput.json"
    run_throughput(TrainingThroughputBenchConfig(variants=variants, minutes=0.1, updates_per_step=1, out=out))
    results = json.loads(out.read_text())["results"]
    for spec in variants:
        (turn,) = results[spec]["turns"]
        assert turn["actions"] >= 1 and turn["updates"] == turn["actions"]
        assert results[spec]["actions_per_hour"] > 0 and turn["startup_s"] > 0
    assert results[variants[0]]["ratio"] == 1.0
    assert "actions/h" in capsys.readouterr().out
