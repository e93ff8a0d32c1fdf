"""Every ``maniskill-pnp`` subcommand as a subprocess with tiny settings: exit code 0 and well-formed output files.

The commands are independent processes (each pays the ~5-10 s import of torch, TorchRL and ManiSkill), so a
module-scoped fixture starts them all at once on ``LANES`` worker threads, longest first; a training run and the
commands that read it (train-clutter -> eval-clutter, plot-clutter; train-conveyor -> eval-conveyor) share one lane.
Each test then waits for its own command and checks what the command promised. The in-process details of each
job (metrics, resume, determinism) are tested elsewhere; here only the command line's contract is.

``--help`` of every subcommand and most bad inputs run in one extra process (argparse builds every subparser anyway;
one bad input goes through the console script), and bad inputs must end in a non-zero exit code with a one-line
message naming the problem, never a traceback.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from maniskill_pnp.agents.pixel.checkpoint import CHECKPOINT_FORMAT
from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.evaluate import EPISODE_COLUMNS, METRICS, SCENARIO_COLUMNS, TABLE_HEADER, ClutterEvalConfig
from maniskill_pnp.agents.pixel.metrics import ACTION_COLUMNS
from maniskill_pnp.agents.pixel.video import ClutterVideoConfig
from maniskill_pnp.agents.tabular.video import ConveyorVideoConfig
from maniskill_pnp.agents.tabular.recipe import QTABLE_FORMAT, ConveyorConfig
from maniskill_pnp.quickstart import QuickstartConfig

#: Commands run side by side: one per core of the 2-core CI machine (each command is single-threaded here).
LANES = max(1, min(2, os.cpu_count() or 1))
MODULE = [sys.executable, "-m", "maniskill_pnp.cli"]
_SCRIPT = Path(sys.executable).parent / "maniskill-pnp"
#: The installed console script (its messages carry the program name), else the module.
SCRIPT = [str(_SCRIPT)] if _SCRIPT.is_file() else MODULE
ENV = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", COLUMNS="200", PYTHONWARNINGS="ignore")
TIMEOUT_S = 400

TINY_CLUTTER = ["--preset", "cpu-small", "--heightmap-size", "32", "--num-rotations", "2", "--num-objects", "2",
                "--steps", "2", "--checkpoint-interval", "2", "--log-interval", "1"]
CLUTTER_RUN = "cpu-small_small_r2_px32_seed0"
CONVEYOR_RUN = "qlearning_normal_seed0"
#: Subcommands whose --help is checked (``bench X --help`` is the help of ``bench``).
HELP_COMMANDS = ["demo", "bench", "bench primitives", "bench clutter-oracle", "bench conveyor", "bench pixel-memory",
                 "bench decision-cost", "train-conveyor", "eval-conveyor", "train-clutter", "eval-clutter", "plot-clutter",
                 "record-clutter", "record-conveyor", "export-clutter", "quickstart", "bench soak"]
#: Runs ``maniskill_pnp.cli.main`` on several command lines in one process and prints, per name, how each would end as
#: a process: ``exited`` (it raised SystemExit), its exit status ``code`` (a message given to SystemExit is printed by
#: the interpreter with status 1; any other exception would be a traceback) and what it wrote to stdout and stderr.
MAIN_DRIVER = """
import contextlib, io, json, sys, traceback
from maniskill_pnp.cli import main
out = {}
for name, argv in json.loads(sys.argv[1]).items():
    stdout, stderr, exited = io.StringIO(), io.StringIO(), False
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        try:
            main(argv)
            code = 0
        except SystemExit as e:
            exited, code = True, e.code if isinstance(e.code, int) else 0 if e.code is None else 1
            if isinstance(e.code, str):
                print(e.code, file=sys.stderr)
        except BaseException:
            traceback.print_exc()
            code = 1
    out[name] = dict(exited=exited, code=code, stdout=stdout.getvalue(), stderr=stderr.getvalue())
print(json.dumps(out))
"""
#: Bad command lines run by MAIN_DRIVER ("bad preset" runs through the console script itself).
BAD_INPUTS = {
    "bad eval-clutter checkpoint": ["eval-clutter", "/nonexistent/run", "--out", "never"],
    "bad plot-clutter run": ["plot-clutter", "empty_run", "--out", "never.png"],
    "bad train-conveyor alpha": ["train-conveyor", "--alpha", "2", "--out", "never"],
    "bad collector": ["train-conveyor", "--workers", "2", "--collector", "direct", "--out", "never"],
}


@dataclasses.dataclass
class Ran:
    """One finished command."""

    name: str
    argv: list[str]
    returncode: int
    stdout: str
    stderr: str
    wall_s: float
    cpu_s: float
    """User + system CPU seconds of the command and the processes it waited for (about its wall time on idle cores)."""

    def ok(self) -> Ran:
        assert self.returncode == 0, f"{self.name} exited {self.returncode}:\n{self.stderr[-4000:]}"
        return self

    def json_stdout(self):
        """The JSON object a command prints after its progress output."""
        return json.loads(self.stdout[self.stdout.index("{"): self.stdout.rindex("}") + 1])


def _run(name: str, argv: list[str], cwd: Path) -> Ran:
    """Run ``argv`` to its end (killed after ``TIMEOUT_S``), with its wall and CPU time (``os.wait4``)."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(argv, cwd=cwd, env=ENV, stdout=out, stderr=err, text=True)
        timer = threading.Timer(TIMEOUT_S, proc.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            timer.cancel()
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if proc.returncode == -9:
        stderr += f"\n(killed after {TIMEOUT_S} s)"
    return Ran(name, argv, proc.returncode, stdout, stderr, time.perf_counter() - t0, usage.ru_utime + usage.ru_stime)


class Jobs:
    """Commands started on a thread pool; ``chain`` runs its commands in order in one lane and skips the rest after a
    failure; ``[name]`` waits for a command."""

    def __init__(self, cwd: Path, lanes: int):
        self.cwd, self.pool, self.futures = cwd, ThreadPoolExecutor(lanes), {}

    def chain(self, *steps: tuple[str, list[str]]) -> None:
        futures = [Future() for _ in steps]
        self.futures.update({name: f for (name, _), f in zip(steps, futures)})

        def lane():
            for i, ((name, argv), fut) in enumerate(zip(steps, futures)):
                try:
                    ran = _run(name, argv, self.cwd)
                except BaseException as e:  # noqa: BLE001 (a timeout): report it on this command and the rest
                    ran = e
                if isinstance(ran, Ran) and ran.returncode == 0:
                    fut.set_result(ran)
                    continue
                if isinstance(ran, Ran):
                    fut.set_result(ran)
                else:
                    fut.set_exception(ran)
                for later in futures[i + 1:]:
                    later.set_exception(RuntimeError(f"not run: {name} before it failed"))
                return

        self.pool.submit(lane)

    def __getitem__(self, name: str) -> Ran:
        return self.futures[name].result(timeout=4 * TIMEOUT_S)

    def timings(self) -> list[tuple[str, float]]:
        done = [f.result() for f in self.futures.values() if f.done() and f.exception() is None]
        return [(r.name, r.wall_s, r.cpu_s) for r in done]


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli")
    (out / "empty_run").mkdir()
    j = Jobs(out, LANES)
    # longest lanes first; CPU seconds measured on a 2-core machine (2026-12-06): clutter lane 114 (train 45, record 25,
    # eval 24, export 10, plot 10), clutter-oracle + scene-counts 59, conveyor lane 44, collection 33, against 26,
    # demo 24, env-overhead 23, decision-breakdown 19, bench conveyor 16, the rest 8-9 each (~450 in all)
    j.chain(("train-clutter", [*MODULE, "train-clutter", *TINY_CLUTTER, "--collector", "direct", "--out", "clutter"]),
            ("eval-clutter", [*MODULE, "eval-clutter", f"clutter/{CLUTTER_RUN}", "--episodes", "1", "--max-steps", "2",
                              "--out", "clutter_eval"]),
            ("plot-clutter", [*MODULE, "plot-clutter", f"clutter/{CLUTTER_RUN}", "--labels", "tiny", "--window", "2",
                              "--out", "clutter_curves.png"]),
            ("export-clutter", [*MODULE, "export-clutter", f"clutter/{CLUTTER_RUN}", "--out", "agent.pt"]),
            ("record-clutter", [*MODULE, "record-clutter", "agent.pt", "--max-steps", "1", "--frame-every", "6",
                                "--out", "clutter_video"]))
    j.chain(("bench clutter-oracle", [*MODULE, "bench", "clutter-oracle", "--episodes", "1", "--scenario", "hard",
                                      "--guard-force", "20", "--out", "bench"]),
            ("bench scene-counts", [*MODULE, "bench", "scene-counts", "--scenes", "1", "--out", "bench"]))
    j.chain(("train-conveyor", [*MODULE, "train-conveyor", "--steps", "30", "--log-interval", "6", "--out", "conveyor"]),
            ("eval-conveyor", [*MODULE, "eval-conveyor", f"conveyor/{CONVEYOR_RUN}", "--iterations", "1",
                               "--out", "conveyor_eval"]),
            ("record-conveyor", [*MODULE, "record-conveyor", f"conveyor/{CONVEYOR_RUN}", "--kind", "sphere", "--speed", "fast",
                                 "--frame-every", "4", "--out", "conveyor_video"]))
    j.chain(("bench collection", [*MODULE, "bench", "collection", "--task", "conveyor", "--workers", "1", "2",
                                  "--frames", "4", "--out", "bench"]))
    # the cheapest benchmark with headline figures (one cube pick-and-place a side): --against is what is tested here
    j.chain(("bench against", [*MODULE, "bench", "primitives", "--episodes", "1", "--against", "HEAD", "--rounds", "1",
                               "--out", "bench_against"]))
    j.chain(("demo", [*MODULE, "demo", "--seed", "0", "--frame-every", "8", "--out", "demo"]))
    j.chain(("bench env-overhead", [*MODULE, "bench", "env-overhead", "--actions", "2", "--out", "bench"]))
    j.chain(("bench decision-breakdown", [*MODULE, "bench", "decision-breakdown", "--actions", "2", "--out", "bench"]))
    j.chain(("bench conveyor", [*MODULE, "bench", "conveyor", "--steps", "30", "--iterations", "1", "--out", "bench_conveyor"]))
    j.chain(("bench primitives", [*MODULE, "bench", "primitives", "--episodes", "1", "--out", "bench"]))
    j.chain(("bad preset", [*SCRIPT, "train-clutter", "--preset", "nope"]))
    in_process = {**{c: [*c.split(), "--help"] for c in HELP_COMMANDS}, **BAD_INPUTS}
    j.chain(("in one process", [sys.executable, "-c", MAIN_DRIVER, json.dumps(in_process)]))
    j.chain(("bench decision-cost", [*MODULE, "bench", "decision-cost", "--backbone", "small", "--rotations", "2",
                                     "--heightmap-size", "32", "--num-primitives", "1", "--warmup", "1", "--repeats", "1",
                                     "--threads", "1", "--out", "bench"]))
    j.out = out
    yield j
    j.pool.shutdown(wait=True, cancel_futures=False)
    timings = sorted(j.timings(), key=lambda t: -t[1])
    print(f"\nmaniskill-pnp commands on {LANES} lanes, wall s / CPU s: "
          + ", ".join(f"{name} {wall:.1f}/{cpu:.1f}" for name, wall, cpu in timings)
          + f"; CPU total {sum(t[2] for t in timings):.0f} s")


# ----------------------------------------------------------------------------- file checks
def _nonempty(path: Path) -> Path:
    assert path.is_file(), f"{path} missing"
    assert path.stat().st_size > 0, f"{path} is empty"
    return path


def _json(path: Path, keys) -> dict:
    data = json.loads(_nonempty(path).read_text())
    missing = set(keys) - set(data)
    assert not missing, f"{path}: keys {sorted(missing)} missing from {sorted(data)}"
    return data


def _report(path: Path, name: str, results_keys) -> dict:
    """A bench report: ``benchmark``, ``machine``, ``settings``, ``results`` with ``results_keys``."""
    report = _json(path, ("benchmark", "machine", "settings", "results"))
    assert report["benchmark"] == name and report["machine"]["cpus"] >= 1
    missing = set(results_keys) - set(report["results"])
    assert not missing, f"{path}: results lack {sorted(missing)}"
    return report["results"]


def _png(path: Path, min_height: int = 50, min_width: int = 50) -> np.ndarray:
    image = iio.imread(_nonempty(path))
    assert image.ndim == 3 and image.shape[2] in (3, 4), image.shape
    assert image.shape[0] >= min_height and image.shape[1] >= min_width, image.shape
    assert image[..., :3].std() > 0, f"{path} is a blank image"
    return image


def _csv(path: Path, header, rows: int) -> list[dict]:
    with open(_nonempty(path), newline="") as f:
        table = list(csv.reader(f))
    assert table[0] == list(header), table[0]
    assert len(table) - 1 == rows, f"{path}: {len(table) - 1} rows, expected {rows}"
    assert all(len(r) == len(header) for r in table[1:])
    return [dict(zip(header, r)) for r in table[1:]]


def _markdown_table(path: Path, header, rows: int) -> list[str]:
    lines = [line for line in _nonempty(path).read_text().splitlines() if line.startswith("|")]
    assert lines[0] == "| " + " | ".join(header) + " |", lines[0]
    assert set(lines[1]) <= set("|-: "), lines[1]
    assert len(lines) - 2 == rows, f"{path}: {len(lines) - 2} rows, expected {rows}"
    return lines[2:]


def _torch_payload(path: Path, fmt: str) -> dict:
    payload = torch.load(_nonempty(path), map_location="cpu", weights_only=True)
    assert isinstance(payload, dict) and payload["format"] == fmt
    return payload


# ----------------------------------------------------------------------------- demo and benchmarks
def test_demo(jobs):
    ran = jobs["demo"].ok()
    out = jobs.out / "demo"
    summary = _json(out / "summary.json", ("success", "sim_steps", "planning_time_s", "wall_time_s_incl_rendering",
                                           "stages", "video", "strip", "config"))
    assert summary["success"] is True and summary["sim_steps"] > 0 and "pick" in summary["stages"]
    strip = _png(out / "pick_and_place_strip.png", 100, 200)
    frames = [frame for frame, _ in zip(iio.imiter(_nonempty(out / "pick_and_place.mp4")), range(3))]
    assert frames and frames[0].ndim == 3 and frames[0].shape[2] == 3
    height, width = frames[0].shape[:2]
    assert strip.shape[0] == height and strip.shape[1] % width == 0 and strip.shape[1] // width >= 3  # key frames
    assert '"success": true' in ran.stdout and "video:" in ran.stdout


def test_bench_primitives(jobs):
    jobs["bench primitives"].ok()
    results = _report(jobs.out / "bench" / "primitives.json", "primitives",
                      ("successes", "episodes", "pick_planning_time_s_median", "pick_and_place_wall_s_median",
                       "episodes_per_s_incl_reset", "failures", "maniskill_mplib_pickcube",
                       "episodes_per_s_ratio_ours_over_maniskill"))
    assert results["episodes"] == 1 and 0 <= results["successes"] <= 1
    assert results["episodes_per_s_incl_reset"] > 0 and results["episodes_per_s_ratio_ours_over_maniskill"] > 0


def test_bench_clutter_oracle(jobs):
    jobs["bench clutter-oracle"].ok()
    results = _report(jobs.out / "bench" / "clutter_oracle.json", "clutter_oracle",
                      ("success_rate", "grasp_success", "completion", "action_efficiency", "scenes",
                       "step_time_s_median"))
    assert len(results["scenes"]) == 1 and results["scenes"][0]["actions"] >= 1
    assert results["scenes"][0]["layout"] == "hard_00"  # the hard set's first file (random clutter: bench against)
    for key in ("success_rate", "grasp_success", "completion", "action_efficiency"):
        assert 0.0 <= results[key] <= 1.0, key


def test_bench_against_a_revision(jobs):
    """The same benchmark on the checkout's HEAD (a worktree) and on the checkout, in turns: both figures and the
    ratio; the same seeded pick-and-place ends the same way after the same number of simulation steps on both sides."""
    ran = jobs["bench against"].ok()
    results = _report(jobs.out / "bench_against" / "against_primitives" / "against.json", "primitives against HEAD",
                      ("ref", "ref_commit", "turns", "median", "ratio"))
    assert len(results["turns"]["ref"]) == len(results["turns"]["this"]) == 1
    for key in ("episodes/s", "successes", "sim steps (median)", "ManiSkill mplib episodes/s", "ratio to ManiSkill"):
        assert results["median"]["ref"][key] >= 0 and results["median"]["this"][key] >= 0, key
    assert results["median"]["this"]["episodes/s"] > 0
    if not results["this_uncommitted_changes"]:  # the same code on both sides
        assert results["median"]["ref"]["successes"] == results["median"]["this"]["successes"]
        assert results["ratio"]["sim steps (median)"] == 1.0
    assert "this / ref" in ran.stdout and "successes" in ran.stdout


def test_bench_scene_counts(jobs):
    jobs["bench scene-counts"].ok()
    results = _report(jobs.out / "bench" / "scene_counts.json", "scene_counts",
                      ("ClutterGrasp-v1:default", "ClutterGraspSlide-v1:min", "ClutterGraspSlide-v1:medium",
                       "ClutterGraspSlide-v1:max"))
    for name, r in results.items():
        lo, hi = r["redrop"]["range"]
        assert r["redrop"]["short"] == 0 and lo <= r["redrop"]["mean_start"] <= hi, name  # every drawn object inside
        assert r["no_redrop"]["mean_start"] <= r["redrop"]["mean_start"], name


def test_bench_conveyor(jobs):
    """Two 30-step trainings, the random test cases and the learning curves."""
    jobs["bench conveyor"].ok()
    out = jobs.out / "bench_conveyor"
    results = _report(out / "conveyor.json", "conveyor", ("qlearning", "sarsa"))
    for algorithm, r in results.items():
        assert set(r["test_case_success_rate"]) == {"1", "2", "3", "4", "5"}
        assert 0.0 <= r["average_success_rate"] <= 1.0 and r["train_wall_s"] > 0
        run = out / "conveyor_runs" / f"{algorithm}_normal_seed0"
        assert _json(run / "config.json", ("steps", "logger"))["steps"] == 30
        _torch_payload(run / "qtable.pt", QTABLE_FORMAT)
    _csv(out / "conveyor_eval" / "test_cases.csv", ("agent", "test_case", "episodes", "success_rate", "grasp_success"), 10)
    _markdown_table(out / "conveyor_eval" / "test_cases.md",
                    ("Test case", "Q-learning success_rate", "SARSA success_rate"), 6)
    evaluation = _json(out / "conveyor_eval" / "eval.json", ("settings", "agents", "plots"))
    assert [Path(p).name for p in evaluation["plots"]] == ["curve_scheme_normal.png"]  # from the runs' CSV logs
    _png(out / "conveyor_eval" / "curve_scheme_normal.png", 200, 300)


def test_bench_decision_cost(jobs):
    ran = jobs["bench decision-cost"].ok()
    results = _report(jobs.out / "bench" / "decision_cost.json", "decision_cost", ("primitives_1",))
    r = results["primitives_1"]
    assert r["decision_s_median"] > 0 and r["trunks_s_median"] > 0 and r["ratio"] > 0
    assert "ratio" in ran.stdout


def test_bench_env_overhead(jobs):
    ran = jobs["bench env-overhead"].ok()
    results = _report(jobs.out / "bench" / "env_overhead.json", "env-overhead",
                      ("clutter_grasp", "pickcube", "ratio_execution_vs_env_step", "ratio_execution_vs_control_step",
                       "ratio_whole_step_vs_env_step"))
    ours, bare = results["clutter_grasp"], results["pickcube"]
    assert ours["actions"] == 2 and ours["sim_steps"] > 0 and ours["motion"] >= ours["planning"] > 0
    assert bare["env_step_sim_steps_per_s"] > 0 and bare["control_step_sim_steps_per_s"] > 0
    assert results["ratio_execution_vs_env_step"] == pytest.approx(
        ours["execution_sim_steps_per_s"] / bare["env_step_sim_steps_per_s"])
    assert "ratio ours executing / bare env.step" in ran.stdout


def test_bench_collection(jobs):
    ran = jobs["bench collection"].ok()
    results = _report(jobs.out / "bench" / "collection_conveyor.json", "collection", ("task", "rows"))
    rows = results["rows"]
    assert results["task"] == "conveyor" and [r["workers"] for r in rows] == [1, 2]
    assert all(r["frames"] >= 4 and r["transitions_per_s"] > 0 for r in rows) and rows[0]["ratio_vs_first"] == 1.0
    assert "2 worker(s)" in ran.stdout


def test_bench_decision_breakdown(jobs):
    ran = jobs["bench decision-breakdown"].ok()
    results = _report(jobs.out / "bench" / "decision_breakdown.json", "decision-breakdown",
                      ("decisions", "mean_s", "median_s", "decisions_per_s", "table"))
    assert len(results["decisions"]) == 2 and results["decisions_per_s"] > 0
    for row in results["decisions"]:
        assert set(row) == {"render", "heightmap", "network", "planning", "execution", "other"}
        assert min(row.values()) >= 0 and row["render"] > 0 and row["network"] > 0 and row["execution"] > 0
    lines = _markdown_table(jobs.out / "bench" / "decision_breakdown.md", ("part", "median ms", "mean ms", "share"), 7)
    assert lines[-1].startswith("| total |") and lines[-1].endswith("| 100.0% |")
    assert "| network |" in ran.stdout


# ----------------------------------------------------------------------------- conveyor agents
def test_train_conveyor(jobs):
    ran = jobs["train-conveyor"].ok()
    run = jobs.out / "conveyor" / CONVEYOR_RUN
    config = _json(run / "config.json", [f.name for f in dataclasses.fields(ConveyorConfig)])
    assert config["steps"] == 30 and config["logger"] == "csv"
    assert ConveyorConfig.from_json(config).run_name == CONVEYOR_RUN
    payload = _torch_payload(run / "qtable.pt", QTABLE_FORMAT)
    assert tuple(payload["values"].shape) == (payload["num_states"], payload["action_n"])
    assert torch.isfinite(payload["values"]).all()
    summary = _json(run / "train_summary.json", ("run_dir", "steps", "episodes", "placed", "final_running_success_rate"))
    assert summary["steps"] == 30 and ran.json_stdout() == summary
    log = np.loadtxt(_nonempty(run / "scalars" / "train" / "success_rate.csv"), delimiter=",", ndmin=2)
    assert log[:, 0].tolist() == [6, 12, 18, 24, 30] and ((0 <= log[:, 1]) & (log[:, 1] <= 1)).all()


def test_eval_conveyor(jobs):
    ran = jobs["eval-conveyor"].ok()
    out = jobs.out / "conveyor_eval"
    rows = _csv(out / "test_cases.csv", ("agent", "test_case", "episodes", "success_rate", "grasp_success"), 5)
    assert [r["test_case"] for r in rows] == ["1", "2", "3", "4", "5"] and {r["episodes"] for r in rows} == {"1"}
    _markdown_table(out / "test_cases.md", ("Test case", "Q-learning success_rate"), 6)
    evaluation = _json(out / "eval.json", ("settings", "agents", "plots"))
    assert evaluation["settings"] == dict(iterations=1, category_iterations=0, seed=12345)
    # one run: its own curve from its CSV log (older conveyor_eval drew none: nothing to compare it with)
    assert {Path(p).name for p in evaluation["plots"]} <= {"curve_scheme_normal.png"}
    for plot in evaluation["plots"]:
        _png(out / Path(plot).name, 200, 300)
    assert not (out / "categories.csv").exists()  # --category-iterations 0 skips the per-category tables
    assert "Test case 5" in ran.stdout


# ----------------------------------------------------------------------------- clutter agents
def test_train_clutter(jobs):
    ran = jobs["train-clutter"].ok()
    run = jobs.out / "clutter" / CLUTTER_RUN
    config = _json(run / "config.json", [f.name for f in dataclasses.fields(ClutterConfig)])
    assert (config["heightmap_size"], config["num_rotations"], config["steps"], config["logger"]) == (32, 2, 2, "csv")
    payload = _torch_payload(run / "checkpoint.pt", CHECKPOINT_FORMAT)
    assert payload["counters"]["steps"] == 2 and payload["replay"]["dir"] == "replay_step2"
    assert (run / "replay_step2").is_dir()
    summary = _json(run / "train_summary.json", ("run_dir", "steps", "episodes", "updates", "running_grasp_success"))
    assert summary["steps"] == 2 and ran.json_stdout() == summary
    actions = _csv(run / "actions.csv", ACTION_COLUMNS, 2)
    assert [r["step"] for r in actions] == ["1", "2"]
    loss = np.loadtxt(_nonempty(run / "scalars" / "train" / "loss.csv"), delimiter=",", ndmin=2)
    assert loss[:, 0].tolist() == [1, 2] and np.isfinite(loss[:, 1]).all()


def test_eval_clutter(jobs):
    ran = jobs["eval-clutter"].ok()
    out = jobs.out / "clutter_eval"
    summary = _json(out / "eval_summary.json", ("metrics", "episodes", "files", "train_config", "eval_config"))
    assert list(summary["metrics"]) == ["train"] and len(summary["episodes"]) == 1
    assert all(0.0 <= summary["metrics"]["train"][k] <= 1.0 for k in METRICS)
    assert {Path(p).name for p in summary["files"].values()} == {
        "eval_summary.json", "eval_table.md", "eval_table.csv", "eval_episodes.csv", "q_heatmaps.png", "eval_metrics.png"}
    _csv(out / "eval_table.csv", SCENARIO_COLUMNS, 1)
    (row,) = _markdown_table(out / "eval_table.md", TABLE_HEADER, 1)
    assert row.startswith("| train | 1 |")
    (episode,) = _csv(out / "eval_episodes.csv", EPISODE_COLUMNS, 1)
    assert 1 <= int(episode["actions"]) <= 2
    _png(out / "q_heatmaps.png", 100, 300)
    _png(out / "eval_metrics.png", 200, 300)
    assert ran.json_stdout() == summary["metrics"] and "q_heatmaps.png" in ran.stdout


def test_plot_clutter(jobs):
    ran = jobs["plot-clutter"].ok()
    _png(jobs.out / "clutter_curves.png", 200, 300)
    summary = ran.json_stdout()
    assert set(summary) == {"tiny"} and summary["tiny"]["actions"] == 2 and summary["tiny"]["minutes"] > 0
    for window in ("first", "last"):
        assert set(summary["tiny"][window]) == {"grasp_success", "success_rate", "actions"}
        assert all(math.isfinite(v) for v in summary["tiny"][window].values())


def test_export_and_record_clutter(jobs):
    """The exported agent (weights and config only) is what record-clutter films: MP4 and decision strip."""
    jobs["export-clutter"].ok()
    payload = _torch_payload(jobs.out / "agent.pt", CHECKPOINT_FORMAT)
    assert set(payload) == {"format", "config", "model", "counters"}
    ran = jobs["record-clutter"].ok()
    out = jobs.out / "clutter_video"
    summary = _json(out / "video_summary.json", ("decisions", "frames", "files"))
    assert len(summary["decisions"]) == 1 and "episode.mp4" in ran.stdout
    video = iio.imread(_nonempty(out / "episode.mp4"))
    assert video.shape[0] == summary["frames"] > 1 and video.shape[1] == 512
    _png(out / "decisions.png", 200, 1000)


def test_record_conveyor(jobs):
    """One greedy episode of the tiny Q-table: the phases it decided, the MP4 of the belt and the arm."""
    ran = jobs["record-conveyor"].ok()
    out = jobs.out / "conveyor_video"
    summary = _json(out / "video_summary.json", ("decisions", "placed", "frames", "files"))
    phases = [d["phase"] for d in summary["decisions"]]
    assert phases and phases[0] == "initial" and set(phases) <= {"initial", "pre_pick", "grasp"}
    video = iio.imread(_nonempty(out / "episode.mp4"))
    assert video.shape[0] == summary["frames"] > len(phases) and video.shape[1:3] == (512, 512)
    assert video.std(axis=0).mean() > 1.0  # the belt and the arm move
    assert "episode.mp4" in ran.stdout


# ----------------------------------------------------------------------------- help and bad inputs
def _flags(*names: str) -> list[str]:
    return ["--" + n.replace("_", "-") for n in names]


BENCH_OPTIONS = ["--episodes", "--out", "--iterations", "--backbone", "--rotations", "--heightmap-size",
                 "--num-primitives", "--repeats", "--warmup", "--device", "--threads", "--max-rss-gb",
                 "--steps", "--actions", "--task", "--workers", "--frames", "--preset", "--against", "--rounds", "primitives", "clutter-oracle",
                 "conveyor", "pixel-memory", "decision-cost", "soak", "env-overhead", "collection", "decision-breakdown"]
HELP_OPTIONS = {
    "demo": ["--out", "--seed"],
    **{command: BENCH_OPTIONS for command in HELP_COMMANDS if command.startswith("bench")},
    "train-conveyor": _flags(*(f.name for f in dataclasses.fields(ConveyorConfig))),
    "eval-conveyor": ["checkpoints", "--iterations", "--category-iterations", "--out", "--seed", "--curves"],
    "train-clutter": ["--preset", "--config", *_flags(*(f.name for f in dataclasses.fields(ClutterConfig)))],
    "eval-clutter": ["checkpoint", *_flags(*(f.name for f in dataclasses.fields(ClutterEvalConfig)
                                            if f.name != "checkpoint"))],
    "plot-clutter": ["runs", "--labels", "--window", "--out"],
    "record-clutter": ["checkpoint", *_flags(*(f.name for f in dataclasses.fields(ClutterVideoConfig) if f.name != "checkpoint"))],
    "export-clutter": ["checkpoint", "--out", "--half", "--slide-margin", "--mask-grasp-fit",
                       "--mask-fit-scale"],
    "record-conveyor": ["checkpoint", *_flags(*(f.name for f in dataclasses.fields(ConveyorVideoConfig) if f.name != "checkpoint"))],
    "quickstart": _flags(*(f.name for f in dataclasses.fields(QuickstartConfig))),
}


def _in_one_process(jobs) -> dict:
    """The ends of the command lines :data:`MAIN_DRIVER` ran (the ``--help`` of each command, the bad inputs)."""
    return json.loads(jobs["in one process"].ok().stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("command", HELP_COMMANDS)
def test_help_exits_0_and_names_every_option(jobs, command):
    ran = _in_one_process(jobs)[command]
    assert ran["exited"] and ran["code"] == 0, ran
    text = ran["stdout"]
    assert text.startswith("usage: maniskill-pnp " + command.split()[0])
    missing = [option for option in HELP_OPTIONS[command] if option not in text]
    assert not missing, f"{command} --help does not mention {missing}"
    assert "--logger" not in HELP_OPTIONS[command] or "{csv,tensorboard}" in text


@pytest.mark.parametrize("name, message", [
    ("bad preset", "argument --preset: invalid choice: 'nope'"),
    ("bad eval-clutter checkpoint", "eval-clutter: checkpoint /nonexistent/run does not exist"),
    ("bad plot-clutter run", "plot-clutter: empty_run/actions.csv does not exist"),
    ("bad train-conveyor alpha", "train-conveyor: alpha must be in (0, 1], got 2.0"),
    ("bad collector", "train-conveyor: the direct collector runs one env in this process"),
])
def test_bad_input_is_one_clear_line(jobs, name, message):
    if name in BAD_INPUTS:
        ran = _in_one_process(jobs)[name]
        returncode, stderr = ran["code"], ran["stderr"]
    else:
        ran = jobs[name]
        returncode, stderr = ran.returncode, ran.stderr
    assert returncode != 0
    assert "Traceback" not in stderr, stderr[-2000:]
    last = stderr.strip().splitlines()[-1]
    assert message in last, stderr[-2000:]
    assert not (jobs.out / "never").exists() and not (jobs.out / "never.png").exists()
