"""The whole evaluation protocol of one or more agents in one command: ``maniskill-pnp benchmark AGENT [AGENT ...]``.

Each agent is a saved agent of the package: a clutter DQN checkpoint or exported agent (``train-clutter`` run folder,
``checkpoint.pt``, or an ``export-clutter`` file such as ``maniskill_pnp/weights/gs-cpu-equi-fit.pt``), or a conveyor
Q-table (``train-conveyor`` run folder or its ``qtable.pt``). The protocol is a list of *parts*, each one
``eval-clutter`` (or ``eval-conveyor``) run with fixed settings (:data:`GRASP_SLIDE_PARTS`, :data:`GRASP_PARTS`,
:data:`CONVEYOR_PARTS`):

* a G&S agent (``ClutterGraspSlide-v1``): 24 ``medium``, 8 ``min``, 8 ``max`` scenes and the 8 locking layouts,
  the hard set (32 scene files), the held-out families (``hard_unseen``, 48) and packed arrangements anywhere in the
  workspace (``anywhere``, 24) with guarded grasps and slides (20 N); ``medium`` and the three packed sets again
  with the agent's grasp-only restriction, the comparison of the protocol;
* a grasping agent (``ClutterGrasp-v1``): 24 scenes of 10 objects;
* a conveyor Q-table: the thesis' random test cases 1-5, 50 episodes each.

Every scenario's scenes come from fixed seeds from 1000 on, at most 3 × objects actions each
(:class:`~maniskill_pnp.agents.pixel.evaluate.ClutterEvalConfig`'s defaults). ``quick`` plays the same parts on a
single scene each (:data:`QUICK_EPISODES`), for a first look and for the tests.

The parts run in worker processes (``workers``, by default one per core), the largest first; the progress bar
counts scenes. Each part writes into ``out/<agent>/<part>/`` and records what it ran in ``part.json``: a part that
finished is never run again (run the same command to resume after a stop, or to rebuild the report), and a folder
that holds another agent's or another protocol's part stops the command before anything runs, so nothing recorded is
overwritten. A part that fails is reported, and the others go on.

The report folder ``out`` gets:

* ``report.md``: per agent the Table IX figures per scenario with their standard errors (success rate, grasp
  success, completion, action efficiency), objects lost per scene by cause and every lost object, slides per scene
  and those that changed nothing, faults, G&S − grasp-only paired per scene, the conveyor's test cases; with two or
  more agents each one's paired differences against the first; the parts' wall times;
* ``scenarios.png`` (completion and efficiency per scenario, ± SE) and ``paired.png`` (the paired differences,
  ± 2 SE): :mod:`~maniskill_pnp.agents.pixel.eval_figures`, the figures of ``eval-clutter`` and ``compare-clutter``;
* ``<agent>/<part>/strips/*.png``: the decisions of each part's worst episodes (``strips`` per part).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from maniskill_pnp.bench.protocol_report import write_report
from maniskill_pnp.progress import progress_bar


@dataclass(frozen=True)
class Part:
    """One evaluation of the protocol."""

    name: str
    """Folder and table name of the part."""
    scenario: str
    """The eval-clutter scenario (or "test_cases" for the conveyor)."""
    episodes: int
    """Scenes (or episodes per conveyor test case) in the full protocol."""
    grasp_only: bool = False
    """The agent's grasp-only restriction (slides masked out)."""
    guard_force: float | None = None
    """Guarded grasps and slides (N), as the hard sets are played."""
    actions_per_episode: float = 10.0
    """About how many actions one of its scenes takes (to run the largest parts first)."""


#: Scenes of every part in the quick protocol (conveyor: episodes per test case, :data:`QUICK_CONVEYOR_EPISODES`).
QUICK_EPISODES = 1
QUICK_CONVEYOR_EPISODES = 5
#: The guard of the hard sets (N): a real arm's collision reflex.
GUARD_N = 20.0
#: The parts of a G&S agent (ClutterGraspSlide-v1).
GRASP_SLIDE_PARTS = (
    Part("medium", "medium", 24, actions_per_episode=19),
    Part("medium grasp-only", "medium", 24, grasp_only=True, actions_per_episode=19),
    Part("min", "min", 8, actions_per_episode=8),
    Part("max", "max", 8, actions_per_episode=28),
    Part("locking layouts", "complicated", 8, actions_per_episode=6),
    Part("hard", "hard", 32, guard_force=GUARD_N, actions_per_episode=6),
    Part("hard grasp-only", "hard", 32, grasp_only=True, guard_force=GUARD_N, actions_per_episode=7),
    Part("hard_unseen", "hard_unseen", 48, guard_force=GUARD_N, actions_per_episode=6),
    Part("hard_unseen grasp-only", "hard_unseen", 48, grasp_only=True, guard_force=GUARD_N, actions_per_episode=7),
    Part("anywhere", "anywhere", 24, guard_force=GUARD_N, actions_per_episode=6),
    Part("anywhere grasp-only", "anywhere", 24, grasp_only=True, guard_force=GUARD_N, actions_per_episode=7),
)
#: The parts of a grasping agent (ClutterGrasp-v1).
GRASP_PARTS = (Part("10 objects", "10", 24, actions_per_episode=11),)
#: The parts of a conveyor Q-table.
CONVEYOR_PARTS = (Part("test cases", "test_cases", 50, actions_per_episode=0.5),)


@dataclass(frozen=True)
class BenchmarkConfig:
    """Settings of ``maniskill-pnp benchmark``."""

    agents: tuple[Path, ...]
    """Agents to evaluate: clutter checkpoints or exported agents (.pt, or a train-clutter run folder), conveyor
    Q-tables (qtable.pt or a train-conveyor run folder). With several, each is compared with the first, scene by scene."""
    quick: bool = False
    """The quick protocol: every part on 1 scene (conveyor: 5 episodes per test case), for a first look."""
    out: Path | None = None
    """Report folder (default: runs/benchmark, or runs/benchmark_quick with --quick); a second run with the same
    agents resumes it."""
    workers: int = 0
    """Worker processes running parts side by side (0: one per core)."""
    strips: int = 2
    """Decision strips of the worst episodes drawn per part."""

    def __post_init__(self):
        object.__setattr__(self, "agents", tuple(Path(p) for p in self.agents))
        if not self.agents:
            raise ValueError("give at least one agent")
        if self.out is None:
            object.__setattr__(self, "out", Path("runs/benchmark_quick" if self.quick else "runs/benchmark"))
        object.__setattr__(self, "out", Path(self.out))
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0 (0: one per core), got {self.workers}")
        if self.strips < 0:
            raise ValueError(f"strips must be >= 0, got {self.strips}")
        missing = [str(p) for p in self.agents if not p.exists()]
        if missing:
            raise FileNotFoundError(f"no such agent: {', '.join(missing)}")
        labels = [agent_label(p) for p in self.agents]
        twice = sorted({x for x in labels if labels.count(x) > 1})
        if twice:
            raise ValueError(f"two agents share the name {twice}: their results would share a folder; copy one to "
                             "another file name")


# ----------------------------------------------------------------------------- agents and parts
def agent_label(path: Path) -> str:
    """The folder name of an agent's results: the file's stem, or the run folder's name."""
    path = Path(path)
    if path.is_dir():
        return path.name
    return path.parent.name if path.stem in ("checkpoint", "qtable") else path.stem


def agent_file(path: Path) -> Path:
    """The file that holds the agent: ``path``, or the checkpoint / Q-table inside a run folder."""
    path = Path(path)
    if not path.is_dir():
        return path
    for name in ("checkpoint.pt", "qtable.pt"):
        if (path / name).is_file():
            return path / name
    raise FileNotFoundError(f"{path} holds neither checkpoint.pt (train-clutter) nor qtable.pt (train-conveyor)")


def agent_kind(path: Path) -> str:
    """``"grasp_slide"``, ``"grasp"`` (clutter agents, by their task) or ``"conveyor"``; ValueError for anything else."""
    import torch

    from maniskill_pnp.agents.pixel.checkpoint import CHECKPOINT_FORMAT
    from maniskill_pnp.agents.tabular.recipe import QTABLE_FORMAT

    file = agent_file(path)
    try:
        payload = torch.load(file, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for foreign files
        raise ValueError(f"agent {file} is unreadable (not a torch.save file): {str(e).splitlines()[0]}") from e
    fmt = payload.get("format") if isinstance(payload, dict) else None
    if fmt == QTABLE_FORMAT:
        return "conveyor"
    if fmt == CHECKPOINT_FORMAT:
        return str(payload["config"].get("task", "grasp"))
    raise ValueError(f"agent {file} is neither a clutter DQN agent nor a conveyor Q-table (format {fmt!r})")


def protocol(kind: str, quick: bool) -> list[Part]:
    """The parts an agent of ``kind`` is evaluated on (with their quick sizes when ``quick``)."""
    parts = {"grasp_slide": GRASP_SLIDE_PARTS, "grasp": GRASP_PARTS, "conveyor": CONVEYOR_PARTS}[kind]
    if not quick:
        return list(parts)
    size = lambda p: QUICK_CONVEYOR_EPISODES if p.scenario == "test_cases" else QUICK_EPISODES  # noqa: E731
    return [Part(**{**asdict(p), "episodes": size(p)}) for p in parts]


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _folder_name(name: str) -> str:
    return name.replace(" ", "_")


@dataclass(frozen=True)
class Job:
    """One part of one agent, as a worker runs it."""

    agent: Path
    label: str
    kind: str
    part: Part
    folder: Path
    strips: int
    record: dict
    """What ``part.json`` holds: the agent's file and hash, the part, the settings that decide its scenes."""

    @property
    def done(self) -> bool:
        return (self.folder / "part.json").is_file() and (self.folder / "done").is_file()


def plan_jobs(cfg: BenchmarkConfig) -> list[Job]:
    """Every (agent, part) of the run; ValueError when a part's folder holds a different agent's or protocol's part."""
    jobs = []
    for agent in cfg.agents:
        kind = agent_kind(agent)
        digest = _sha256(agent_file(agent))
        label = agent_label(agent)
        for part in protocol(kind, cfg.quick):
            folder = cfg.out / label / _folder_name(part.name)
            record = dict(agent=str(agent_file(agent)), sha256=digest, kind=kind, part=asdict(part), quick=cfg.quick)
            recorded = folder / "part.json"
            if recorded.is_file():
                old = json.loads(recorded.read_text())
                if {k: old.get(k) for k in record if k != "agent"} != {k: v for k, v in record.items() if k != "agent"}:
                    raise ValueError(f"{folder} holds results of another agent or protocol ({old.get('agent')}, quick="
                                     f"{old.get('quick')}); give another --out, or remove that folder")
            jobs.append(Job(agent, label, kind, part, folder, cfg.strips, record))
    return jobs


# ----------------------------------------------------------------------------- running a part (in a worker)
@contextmanager
def _output_to(path: Path):
    """Send this process's stdout and stderr (the C libraries' too) to ``path`` while the block runs."""
    path.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(path, "ab") as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def run_job(job: Job, queue=None) -> dict:
    """Run one part (in this process) into its folder; put a message on ``queue`` after every scene. Returns
    ``{"label", "part", "wall_s"}``."""
    import torch

    torch.set_num_threads(1)
    job.folder.mkdir(parents=True, exist_ok=True)
    (job.folder / "part.json").write_text(json.dumps(job.record, indent=2))
    t0 = time.perf_counter()
    tick = (lambda _=None: queue.put((job.label, job.part.name))) if queue is not None else (lambda _=None: None)
    with _output_to(job.folder / "log.txt"):
        if job.kind == "conveyor":
            _run_conveyor(job, tick)
        else:
            from maniskill_pnp.agents.pixel.evaluate import ClutterEvalConfig, run

            cfg = ClutterEvalConfig(job.agent, episodes=job.part.episodes, scenarios=(job.part.scenario,),
                                    grasp_only=job.part.grasp_only, guard_force=job.part.guard_force, out=job.folder,
                                    device="cpu", strips=job.strips)
            run(cfg, on_episode=tick, progress=False)
    wall = time.perf_counter() - t0
    from maniskill_pnp.bench.protocol_report import git_revision

    (job.folder / "done").write_text(json.dumps(dict(wall_s=wall, revision=git_revision())))
    return dict(label=job.label, part=job.part.name, wall_s=wall)


def _run_conveyor(job: Job, tick) -> None:
    from maniskill_pnp.agents.tabular.evaluate import EvalConfig, run

    run(EvalConfig(checkpoints=(job.agent,), iterations=job.part.episodes, out=job.folder))
    for _ in range(scenes_of(job)):
        tick()


def scenes_of(job: Job) -> int:
    """The scenes (episodes) a job plays: the unit of the progress bar (a conveyor part plays each test case)."""
    from maniskill_pnp.agents.tabular.evaluate import TEST_CASES

    return job.part.episodes * (len(TEST_CASES) if job.kind == "conveyor" else 1)


# ----------------------------------------------------------------------------- main
def run(cfg: BenchmarkConfig) -> dict:
    """Run every part that has not finished, then write the report. Returns ``{"report", "failed", "wall_s"}``.

    Raises:
        FileNotFoundError / ValueError: an agent is missing or unreadable, or ``out`` holds other results.
    """
    import multiprocessing as mp

    jobs = plan_jobs(cfg)
    todo = sorted((j for j in jobs if not j.done), key=lambda j: -j.part.episodes * j.part.actions_per_episode)
    workers = min(cfg.workers or os.cpu_count() or 1, max(1, len(todo)))
    cfg.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    failed: dict[str, str] = {}
    if todo:
        print(f"benchmark: {len(todo)} of {len(jobs)} parts to run ({len(jobs) - len(todo)} done before), "
              f"{sum(scenes_of(j) for j in todo)} scenes, {workers} worker(s); results in {cfg.out}", flush=True)
        ctx = mp.get_context("spawn")
        with ctx.Manager() as manager, progress_bar(total=sum(scenes_of(j) for j in todo), desc="benchmark",
                                                    unit="scene") as bar:
            queue = manager.Queue()
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                futures = {pool.submit(run_job, j, queue): j for j in todo}
                pending = set(futures)
                while pending:
                    while not queue.empty():
                        label, part = queue.get()
                        bar.set_postfix_str(f"{label}: {part}")
                        bar.update()
                    finished = [f for f in pending if f.done()]
                    for f in finished:
                        pending.discard(f)
                        job = futures[f]
                        try:
                            f.result()
                        except Exception as e:  # a failed part is reported; the others go on
                            failed[f"{job.label}/{job.part.name}"] = f"{type(e).__name__}: {e}"
                            print(f"benchmark: part {job.label}/{job.part.name} failed: {e} (log: {job.folder / 'log.txt'})",
                                  flush=True)
                    if pending:
                        time.sleep(0.5)
                while not queue.empty():  # the ticks of the last scenes
                    queue.get()
                    bar.update()
    report = write_report(jobs, cfg, failed)
    wall = time.perf_counter() - t0
    print(f"benchmark: {len(jobs) - len(failed)} of {len(jobs)} parts done in {wall / 60:.1f} min; report: {report}")
    return dict(report=str(report), failed=failed, wall_s=wall)


__all__ = ["BenchmarkConfig", "CONVEYOR_PARTS", "GRASP_PARTS", "GRASP_SLIDE_PARTS", "Job", "Part", "QUICK_EPISODES",
           "agent_kind", "agent_label", "plan_jobs", "protocol", "run", "run_job"]
