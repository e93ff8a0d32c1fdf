"""Crash-safe clutter training: SIGKILL at a random moment, resume, and lose at most one checkpoint interval."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import time

import pytest

from maniskill_pnp.agents.pixel.checkpoint import load_checkpoint
from maniskill_pnp.agents.pixel.curves import load_actions

STEPS, INTERVAL = 8, 2
#: Tiny settings, collected in the learner's process: what a kill can tear is the learner's checkpoint, whichever
#: collector fed it (the worker-process collector's resume is tested in test_collection).
ARGS = ["--preset", "cpu-small", "--heightmap-size", "32", "--num-rotations", "2", "--num-objects", "2",
        "--steps", str(STEPS), "--checkpoint-interval", str(INTERVAL), "--log-interval", "1", "--collector", "direct"]


def _cmd(out, *extra):
    return [sys.executable, "-m", "maniskill_pnp.cli", "train-clutter", *ARGS, "--out", str(out), *extra]


def test_sigkill_then_resume_loses_at_most_one_interval(tmp_path):
    run_dir = tmp_path / "cpu-small_small_r2_px32_seed0"
    proc = subprocess.Popen(_cmd(tmp_path), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 240
    while not (run_dir / "checkpoint.pt").is_file():  # wait for the first checkpoint, then kill at a random moment
        assert proc.poll() is None and time.monotonic() < deadline, "training ended or stalled before its first checkpoint"
        time.sleep(0.2)
    time.sleep(random.Random(0).uniform(0.0, 3.0))
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)

    saved = load_checkpoint(run_dir / "checkpoint.pt")  # whatever moment the kill hit, the checkpoint is whole
    steps = saved["counters"]["steps"]
    assert steps % INTERVAL == 0 and INTERVAL <= steps <= STEPS
    assert (run_dir / saved["replay"]["dir"]).is_dir()

    resumed = subprocess.run(_cmd(tmp_path, "--resume"), capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    summary = json.loads(resumed.stdout[resumed.stdout.index("{"):])
    assert summary["start_step"] == steps and summary["steps"] == STEPS
    final = load_checkpoint(run_dir / "checkpoint.pt")
    assert final["counters"]["steps"] == STEPS and final["replay"]["size"] == STEPS
    assert load_actions(run_dir)["step"].tolist() == list(range(1, STEPS + 1))


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_a_damaged_checkpoint_is_a_clear_error(tmp_path, damage):
    run_dir = tmp_path / "cpu-small_small_r2_px32_seed0"
    run_dir.mkdir(parents=True)
    ckpt = run_dir / "checkpoint.pt"
    if damage == "truncate":
        import torch

        torch.save({"format": "maniskill_pnp.clutter_dqn/1", "model": torch.zeros(1000)}, ckpt)
        ckpt.write_bytes(ckpt.read_bytes()[:200])
    else:
        ckpt.write_bytes(b"\x00not a checkpoint")
    proc = subprocess.run(_cmd(tmp_path, "--resume"), capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("train-clutter: checkpoint") and "checkpoint.pt" in last and "unreadable" in last


def test_atomic_writes_get_ordinary_file_permissions(tmp_path):
    """Checkpoints and JSON go through a temp file (owner-only); the file in place gets 0o666 less the umask."""
    import os
    import stat

    from maniskill_pnp.agents.run_io import atomic_write_bytes, write_json

    old = os.umask(0o027)
    try:
        write_json(tmp_path / "summary.json", {"steps": 1})
        atomic_write_bytes(tmp_path / "checkpoint.pt", lambda f: f.write(b"weights"))
    finally:
        os.umask(old)
    for name in ("summary.json", "checkpoint.pt"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o640, name
    assert json.loads((tmp_path / "summary.json").read_text()) == {"steps": 1}
    assert not list(tmp_path.glob(".*.tmp"))  # no temp file left behind
