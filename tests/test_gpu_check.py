"""scripts/gpu_check.sh: it refuses to run without a GPU, its dry run names commands the package accepts (so that a
renamed bench option or test file breaks this test, not the GPU lease), and its step loop writes the summary (run
here with stub commands in a copy of the scripts)."""

from __future__ import annotations

import importlib.util
import os
import shlex
import shutil
import stat
import subprocess
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "gpu_check.sh"
BUDGET_S = 480


def run_script(*args: str, script: Path = SCRIPT, env: dict | None = None) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("MANISKILL_PNP_")}
    return subprocess.run(["bash", str(script), *args], check=False, capture_output=True, text=True, timeout=60,
                          env={**environ, **(env or {})})


def gpu_present() -> bool:
    if torch.cuda.is_available():
        return True
    smi = shutil.which("nvidia-smi")
    if smi is None:
        return False
    listed = subprocess.run([smi, "-L"], check=False, capture_output=True, text=True, timeout=30)
    return listed.returncode == 0 and "GPU " in listed.stdout


def executable(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


@pytest.mark.skipif(gpu_present(), reason="this machine has an NVIDIA GPU")
def test_without_a_gpu_it_stops_at_once(tmp_path):
    done = run_script("--out", str(tmp_path / "check"))
    assert done.returncode == 2, done.stderr
    assert "gpu_check.sh needs an NVIDIA GPU" in done.stderr and "nothing was run" in done.stderr
    assert not (tmp_path / "check").exists()


def test_a_failing_nvidia_smi_counts_as_no_gpu(tmp_path):
    fake = executable(tmp_path / "bin" / "nvidia-smi", "#!/bin/sh\necho 'NVIDIA-SMI has failed' >&2\nexit 9\n")
    done = run_script("--out", str(tmp_path / "check"), env={"PATH": f"{fake.parent}{os.pathsep}{os.environ['PATH']}"})
    assert done.returncode == 2 and "(nvidia-smi found none); nothing was run" in done.stderr
    assert not (tmp_path / "check").exists()


def test_dry_run_names_commands_the_package_accepts(tmp_path, monkeypatch):
    from maniskill_pnp import cli
    from maniskill_pnp.bench import pixel_dqn, scale, training_throughput

    out = tmp_path / "check"
    done = run_script("--dry-run", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert not out.exists()  # a dry run writes nothing
    commands = [shlex.split(line) for line in done.stdout.splitlines()]
    assert len(commands) == 6 and all(c[:3] == ["timeout", "-k", "5"] for c in commands)
    assert sum(int(c[3]) for c in commands) <= BUDGET_S  # the steps' own timeouts fit the 8 minutes
    steps = [c[4:] for c in commands]
    assert steps[0] == ["bash", "scripts/setup.sh"] and (ROOT / "scripts" / "setup.sh").is_file()
    assert steps[1] == ["nvidia-smi"]

    pytest_cmd = steps[2]
    assert pytest_cmd[1:4] == ["-m", "pytest", "-m"] and pytest_cmd[4] == "gpu"
    paths = [a for a in pytest_cmd[5:] if not a.startswith("-")]
    assert paths and all((ROOT / p).exists() for p in paths), paths
    assert f"--junitxml={out}/pytest_gpu.xml" in pytest_cmd
    if any(a.startswith("--timeout") for a in pytest_cmd):
        assert importlib.util.find_spec("pytest_timeout"), "--timeout needs pytest-timeout (the test extra)"

    configs = {}
    for name, module, attr in [("batched-decisions", scale, "run_batched_decisions"),
                               ("pixel-memory", pixel_dqn, "run_pixel_memory"),
                               ("training-throughput", training_throughput, "run")]:
        monkeypatch.setattr(module, attr, lambda cfg, name=name: configs.setdefault(name, cfg))
    for command in steps[3:]:
        assert command[0].endswith("maniskill-pnp"), command
        tokens = command[1:]
        try:
            cli.build_parser().parse_args(tokens)
            cli.main(tokens)  # builds the benchmark's config as the command would; the run itself is stubbed out
        except SystemExit as e:
            pytest.fail(f"maniskill-pnp rejects {shlex.join(tokens)}: {e}")
    assert configs.keys() == {"batched-decisions", "pixel-memory", "training-throughput"}
    assert configs["batched-decisions"].num_envs == (1, 4, 16, 64)
    assert configs["pixel-memory"].device == "cuda"
    assert configs["training-throughput"].variants == ("gs-thesis,device=cuda,collector=direct",) and configs["training-throughput"].minutes == 2
    assert all(cfg.out.parent == out / "bench" for cfg in configs.values())


def test_steps_write_logs_and_a_summary_within_the_budget(tmp_path):
    """With stubs: a failing step, one that runs into its timeout (cut to the budget's rest) and one left out."""
    repo = tmp_path / "repo"
    script = repo / "scripts" / "gpu_check.sh"
    script.parent.mkdir(parents=True)
    shutil.copy(SCRIPT, script)
    executable(repo / "scripts" / "setup.sh", "#!/bin/sh\necho '[setup] stub'\n")
    junit = ('<testsuites><testsuite name="pytest" errors="0" failures="0" skipped="0" tests="4" time="1">'
             "</testsuite></testsuites>")
    executable(repo / ".venv" / "bin" / "python", "#!/bin/sh\nfor a; do case \"$a\" in --junitxml=*) "
               f"echo '{junit}' > \"${{a#--junitxml=}}\";; esac; done\necho 'python stub'\n")
    executable(repo / ".venv" / "bin" / "maniskill-pnp", "#!/bin/sh\ncase \"$2\" in\n"
               "  batched-decisions) echo 'no GPU rows' >&2; exit 3;;\n  pixel-memory) exec sleep 60;;\nesac\n")
    fake = executable(tmp_path / "bin" / "nvidia-smi",
                      '#!/bin/sh\n[ "$1" = -L ] && echo "GPU 0: Stub GPU (UUID: GPU-0)" || echo "stub nvidia-smi table"\n')
    out = tmp_path / "check"
    done = run_script("--out", str(out), script=script,
                      env={"PATH": f"{fake.parent}{os.pathsep}{os.environ['PATH']}", "MANISKILL_PNP_GPU_CHECK_BUDGET_S": "12"})
    assert done.returncode == 1, done.stderr
    summary = (out / "summary.md").read_text()
    rows = {line.split("|")[1].strip(): [cell.strip() for cell in line.split("|")[2:-1]]
            for line in summary.splitlines() if line.startswith("| ") and not line.startswith("| step")}
    assert [rows[s][0] for s in ("setup", "nvidia-smi", "pytest-gpu", "batched-decisions", "pixel-memory",
                                 "training-throughput")] == ["0", "0", "0", "3", "124", "not run"]
    assert int(rows["pixel-memory"][2]) < 60  # its timeout was cut to what the budget had left
    assert "GPU 0: Stub GPU" in summary and 'tests="4"' in summary
    assert (out / "02-nvidia-smi.log").read_text() == "stub nvidia-smi table\n"
    assert "no GPU rows" in (out / "04-batched-decisions.log").read_text()
    assert (out / "pytest_gpu.xml").is_file() and (out / "bench").is_dir()
