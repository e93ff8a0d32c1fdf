"""The soak benchmark, sized down for CI: random primitive actions on ClutterGraspSlide-v1 across several resets,
with no crash and no scene object leaked between resets (the full 2000-action run is `bench soak`)."""

from __future__ import annotations

import json

import pytest

from maniskill_pnp.bench.soak import SoakBenchConfig, run


def test_soak_runs_across_resets_without_leaks(tmp_path):
    out = tmp_path / "soak.json"
    # 2 objects at 32 px: random masked actions clear or exhaust a scene within a few actions, so several resets
    results = run(SoakBenchConfig(actions=24, warmup=4, num_objects=2, heightmap_size=32, num_rotations=2, out=out))
    assert results["episodes"] >= 2, "the soak must cross resets to look for leaks"
    assert results["leaks"] == []
    counts = results["scene_counts"]
    assert counts["lights"] >= 1 and counts["cameras"] >= 2 and counts["actors"] > 2
    assert sum(results["primitives"].values()) == 24 == len(results["rss_mb_series"])
    assert set(results["primitives"]) <= {"grasp", "left_slide", "right_slide"}
    report = json.loads(out.read_text())
    assert report["benchmark"] == "soak" and report["results"]["growth_after_warmup_mb"] == results["growth_after_warmup_mb"]
    assert out.with_suffix(".png").stat().st_size > 0


def test_soak_config_names_bad_values():
    with pytest.raises(ValueError, match="warmup < actions"):
        SoakBenchConfig(actions=10, warmup=10)
