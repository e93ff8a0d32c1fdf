"""Greedy evaluation of a clutter DQN checkpoint (thesis parts II and III), with the metrics of ``docs/metrics.md``
per scenario.

The network of a ``checkpoint.pt`` written by :func:`~maniskill_pnp.agents.pixel.checkpoint.save_checkpoint` is
rebuilt from the checkpoint's own config (:func:`~maniskill_pnp.agents.pixel.factories.load_policy`) and run
greedily (argmax of the Q maps, no ε) over seeded scenes: episode ``i`` is reset with seed ``seed + i``. The default seed 1000 keeps the test scenes apart from the small seeds training uses.
An episode ends when the workspace is clear, when the task truncates it (too many consecutive failures or
actions), after ``actions_per_object`` × its objects actions (3 by default) or after ``max_steps`` actions. The policy acts under the action mask its training used (grasps only where
there is material, see :mod:`~maniskill_pnp.agents.pixel.mask`); ``grasp_only`` also masks out a G&S agent's
slides, the thesis' grasp-only comparison on the same network. With ``avoid_repeats`` the policy never repeats a
failed action or its neighbours until the heightmap changes (pure argmax without it: a failure that leaves the scene
unchanged leaves the argmax unchanged, so one failing action can repeat until the failure limit ends the episode).

Scenarios (``scenarios``, one table row each, like the thesis' Table IX): ``"train"`` (the checkpoint's object
count), an object count such as ``"10"``, a density preset of the task (``"min"``, ``"medium"``, ``"max"``) or
``"complicated"`` (ClutterGraspSlide-v1's hand-designed locking layouts; for ClutterGrasp-v1 its 3-7 object preset),
``"hard"`` (the 24 generated tightly packed scenes and the 8 locking layouts, episode ``i`` on file ``i mod 32``: run
at least 32 episodes to play them all), ``"hard_unseen"`` (the 48 tightly packed scenes of families no training draws);
see :data:`~maniskill_pnp.agents.pixel.factories.SCENARIOS`. Scene files of the user's own arrangements
(``layout_file``, :mod:`~maniskill_pnp.scenes.scene_file`) are one more scenario, after those: its row is named
after the files' stems (joined by ``+``), and episode ``i`` is played on file ``i mod (number of files)`` (seed
``seed + i``); the file of each episode is in its ``layout`` column. Without ``scenarios``, ``"train"`` is
evaluated, or only the layout files when there are some.

Metrics (``docs/metrics.md``, computed from the env's ``info`` of every step):

* ``success_rate`` (thesis): objects placed in the bin / actions, per episode, averaged over episodes (objects, not
  actions: a grasp that carries two objects into the bin places two, ``info["placed_objects"]``).
* ``grasp_success``: successful grasps / grasp attempts, over all episodes.
* ``completion`` (VPG): episodes in which every starting object ended in the bin, with no run of more than
  :data:`MAX_FAILURE_RUN` consecutive failures (failed grasps, slides that changed nothing) / episodes. An object
  pushed or dropped out of the workspace, by any primitive, is not cleared: that episode is not completed.
* ``action_efficiency`` (VPG): objects placed / actions, summed over the completed episodes (0 when none completed,
  as in :mod:`maniskill_pnp.bench.clutter_oracle`).

Two more columns, named for what they measure: ``workspace_cleared`` (episodes whose workspace was emptied, into the
bin or not: the completion rule before objects were counted) and ``lost_per_scene`` (objects pushed or dropped out of
the workspace per scene; each episode's count is its ``lost`` column), split by cause as the task reports it
(``lost_by_slide_per_scene``, ``lost_by_grasp_per_scene``, ``lost_in_transit_per_scene``,
``lost_at_release_per_scene``; :data:`~maniskill_pnp.tasks.LOSS_CAUSES`).

Each comes with its standard error over scenes (``<metric>_se``: the spread of the per-scene values of
:func:`scene_values`), and each scenario with its faults per 100 actions (steps that ended on a fault of the
simulation, ``info["fault"]``). :func:`paired_differences` pairs two evaluations scene by scene (``maniskill-pnp
compare-clutter A B``), e.g. a G&S agent against its ``grasp_only`` restriction.

Files written into ``out``: ``eval_summary.json`` (metrics per scenario, per-episode records, both configs),
``eval_table.md`` and ``eval_table.csv`` (one row per scenario: the metrics), ``eval_episodes.csv`` (one row per
episode), and ``q_heatmaps.png``: the colour and depth heightmaps of the first state of the first episode beside the
Q map of every primitive and rotation (one colour scale; the chosen action marked), as in the thesis' Fig. 22.

Run it with ``maniskill-pnp eval-clutter runs/clutter/<run folder> --episodes 10`` (G&S, Table IX:
``--scenarios min medium max complicated``; your own arrangements: ``--layout-file my_scene.yaml``).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import statistics
import time
from dataclasses import dataclass, field
from collections.abc import Collection
from pathlib import Path

import numpy as np
import torch

from maniskill_pnp.agents.pixel.checkpoint import checkpoint_file
from maniskill_pnp.agents.pixel.decision_strip import decisions_strip, describe, outcome_lines, strip_rows
from maniskill_pnp.agents.pixel.failure_memory import FailureMemory
from maniskill_pnp.agents.pixel.eval_figures import plot_paired, plot_scenario_metrics
from maniskill_pnp.agents.pixel.factories import SCENARIOS, is_scenario, load_policy, make_env, scenario_layout_files
from maniskill_pnp.agents.pixel.fcn import rotation_angles
from maniskill_pnp.agents.pixel.metrics import is_grasp_attempt
from maniskill_pnp.agents.pixel.policy import FIT_KEY, GreedyPixelActor
from maniskill_pnp.agents.run_io import atomic_write_bytes, write_json
from maniskill_pnp.progress import progress_bar
from maniskill_pnp.runtime import resolve_device
from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.scenes.scene_file import read_scene
from maniskill_pnp.tasks import LOSS_CAUSES

#: Longest run of consecutive failed grasps a completed episode may contain (VPG's completion criterion).
MAX_FAILURE_RUN = 10
#: Names of the metrics, in table order (``docs/metrics.md``).
METRICS = ("success_rate", "grasp_success", "completion", "action_efficiency")
#: Columns of the per-episode table.
#: Why an object was lost, as the task reports it per step (``info`` keys of
#: :data:`~maniskill_pnp.tasks.LOSS_CAUSES`): slide, grasp of another object, dropped in transit,
#: lost at release.
LOSS_CAUSE_KEYS = tuple(LOSS_CAUSES)
EPISODE_COLUMNS = ("scenario", "seed", "objects", "dropped_out", "actions", "grasp_attempts", "grasps", "placed", "slides",
                   "futile_slides", "lost",
                   *LOSS_CAUSE_KEYS, "cleared", "completed", "max_failure_run", "success_rate", "grasp_success", "faults",
                   "layout")
#: Extra per-scenario columns: the share of episodes whose workspace was emptied (into the bin or not), the objects
#: lost (pushed or dropped out of the workspace) per scene, and per scene by cause, the slides per scene and those
#: of them that changed nothing.
EXTRA_COLUMNS = ("workspace_cleared", "lost_per_scene", *(f"{k}_per_scene" for k in LOSS_CAUSE_KEYS), "slides_per_scene",
                 "futile_slides_per_scene")
#: Columns of the per-scenario table (Table IX).
SCENARIO_COLUMNS = ("scenario", "episodes", *METRICS, *(f"{m}_se" for m in METRICS), *EXTRA_COLUMNS, "faults_per_100_actions")
#: Columns of ``eval_table.md``: each metric is shown as "value ± standard error"; the lost objects per scene by
#: cause as "slide / grasp / transit / release".
TABLE_HEADER = ("scenario", "episodes", *METRICS, "workspace cleared", "lost / scene",
                "lost by slide / grasp / transit / release", "slides / scene (changed nothing)", "faults / 100 actions")


@dataclass(frozen=True)
class ClutterEvalConfig:
    """Settings of one greedy evaluation of a clutter DQN checkpoint."""

    checkpoint: Path
    """checkpoint.pt of a clutter DQN run (train-clutter), or the run folder that holds it."""
    episodes: int = 10
    """Seeded scenes to evaluate (episode i uses seed + i)."""
    num_objects: int | None = None
    """Objects per scene; None: the checkpoint's training value."""
    seed: int = 1000
    """Seed of the first scene; the default keeps the test scenes apart from the small seeds used in training."""
    max_steps: int | None = None
    """Cap on actions per episode (an episode cut by it is not completed); None: only the task's own limits."""
    actions_per_object: float | None = 3.0
    """Cap on an episode's actions per object of its scene (3: at most 3 × objects actions, the evaluation protocol
    of the results table); an episode cut by it is not completed. None (or a large value): no such cap."""
    scenarios: tuple[str, ...] = ()
    """Scenes to evaluate, one table row each: "train", an object count, "min", "medium", "max", "complicated",
    "hard" (the hard test set: 32 scene files), "hard_unseen" (48 scene files of families no training draws) or
    "anywhere" (24 scene files of packed arrangements anywhere in the workspace, half near its edge); none:
    "train", or only the layout files when some are given."""
    layout_file: tuple[Path, ...] = ()
    """Scene files (YAML or JSON) of your own arrangements: one more table row, named after the file stems; episode
    i is played on file i mod the number of files."""
    grasp_only: bool = False
    """Mask out every primitive but grasps (a G&S agent evaluated as a grasp-only agent)."""
    slide_margin: float | None = None
    """A G&S agent slides only where a slide's Q value beats the best grasp's by more than this (None: the run's own
    ``slide_margin``, 0 unless it was trained with one)."""
    mask_grasp_fit: bool | None = None
    """Mask out grasps whose open fingers would strike the heightmap (see ``HeightmapActionMask.grasp_fit``); None:
    as the run was trained (its ``mask_grasp_fit``)."""
    mask_fit_scale: int | None = None
    """Test the grasp fit on a heightmap this many times finer than the network's (see ``ClutterConfig.mask_fit_scale``;
    needs the fit test); None: as the run was trained."""
    mask_keep_in: bool | None = None
    """Mask out slides that would carry material off the heightmap (see ``ClutterConfig.mask_keep_in``); None: the
    agent's own setting (on unless it was exported without it)."""
    mask_reach: bool | None = None
    """Mask out grasps and slides the arm cannot reach (see ``ClutterConfig.mask_reach``); None: the agent's own
    setting (on unless it was exported without it)."""
    avoid_repeats: bool = True
    """Never repeat a failed action (a failed grasp, a slide that changed nothing), nor its neighbours (±2 px, ±1
    rotation), until the heightmap changes (:class:`~maniskill_pnp.agents.pixel.failure_memory.FailureMemory`): a
    failure that leaves the scene as it was leaves the greedy argmax where it was, so without this memory the policy
    can repeat one failing action until the failure limit ends the episode. False: the plain argmax."""
    guard_force: float | None = None
    """Guarded grasps and slides (N): a grasp's descent or a slide's lowering stops, and the action fails, when contacts
    push the gripper up by more than this, as a real arm's collision reflex would (e.g. 20); None: unguarded, as in
    training."""
    out: Path = Path("runs/clutter_eval")
    """Folder for eval_summary.json, eval_table.md/.csv and q_heatmaps.png."""
    device: str = "auto"
    """Torch device of the Q network ("auto": CUDA when available, else CPU); the simulation stays on the CPU."""
    strips: int = 0
    """Draw the decisions of this many worst episodes per scenario (not completed first, then most objects lost,
    longest failure run, lowest success rate; perfect episodes never) as strips/<scenario>_seed<seed>.png."""

    def __post_init__(self):
        object.__setattr__(self, "checkpoint", Path(self.checkpoint))
        object.__setattr__(self, "out", Path(self.out))
        object.__setattr__(self, "scenarios", tuple(str(x) for x in self.scenarios))
        object.__setattr__(self, "layout_file", tuple(Path(p) for p in self.layout_file))
        if not self.scenarios and not self.layout_file:
            object.__setattr__(self, "scenarios", ("train",))
        for path in self.layout_file:  # schema errors before any env is made (the workspace is checked then)
            read_scene(path)
        if self.layout_file and self.layout_scenario in self.scenarios:
            raise ValueError(f"the layout files' row {self.layout_scenario!r} has the name of a scenario: rename the file")
        bad = [x for x in self.scenarios if not is_scenario(x)]
        if bad:
            raise ValueError(f"unknown scenarios {bad}; valid: a positive object count or one of {list(SCENARIOS)}")
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")
        if self.episodes < len(self.layout_file):
            raise ValueError(f"episodes ({self.episodes}) must be at least the number of layout files "
                             f"({len(self.layout_file)}), so that every file is played")
        if self.num_objects is not None and self.num_objects < 1:
            raise ValueError(f"num_objects must be >= 1 (or None for the checkpoint's value), got {self.num_objects}")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1 (or None for no cap), got {self.max_steps}")
        if self.actions_per_object is not None and not self.actions_per_object > 0:
            raise ValueError(f"actions_per_object must be > 0 (or None for no cap), got {self.actions_per_object}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.strips < 0:
            raise ValueError(f"strips must be >= 0, got {self.strips}")
        if self.guard_force is not None and not self.guard_force > 0:
            raise ValueError(f"guard_force must be a positive force in N (or None: unguarded), got {self.guard_force}")
        if self.device != "auto":
            try:
                torch.device(self.device)
            except RuntimeError as e:
                raise ValueError(f"device must be 'auto' or a torch device such as 'cpu' or 'cuda:0', got {self.device!r}") from e

    @property
    def checkpoint_path(self) -> Path:
        """The checkpoint file (``checkpoint.pt`` inside ``checkpoint`` when that is a folder)."""
        return checkpoint_file(self.checkpoint)

    @property
    def layout_scenario(self) -> str:
        """Name of the layout files' table row: their stems joined by "+" ("" without layout files)."""
        return "+".join(p.stem for p in self.layout_file)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(checkpoint=str(self.checkpoint), out=str(self.out), layout_file=[str(p) for p in self.layout_file])
        return d


# ----------------------------------------------------------------------------- metrics
def is_completed(episode: dict) -> bool:
    """Whether an episode record counts as completed: every object it started with ended in the bin, with no run of
    more than :data:`MAX_FAILURE_RUN` consecutive failures."""
    return episode["placed"] >= episode["objects"] and episode["max_failure_run"] <= MAX_FAILURE_RUN


def scene_values(episode: dict) -> dict[str, float | None]:
    """Each metric of :data:`METRICS` on one scene (an episode record); None where it is undefined (grasp success
    of a scene without grasp attempts). Their means over scenes give the per-scene averages whose standard errors
    :func:`summarize` reports."""
    e, completed = episode, is_completed(episode)
    return dict(success_rate=e["placed"] / e["actions"],
                grasp_success=e["grasps"] / e["grasp_attempts"] if e["grasp_attempts"] else None,
                completion=float(completed), action_efficiency=e["placed"] / e["actions"] if completed else 0.0)


def standard_error(values) -> float:
    """Standard error of the mean of ``values`` (sample standard deviation / sqrt(n)); 0 for fewer than 2."""
    values = [v for v in values if v is not None]
    return statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else 0.0


def summarize(episodes: list[dict]) -> dict:
    """The metrics (see the module docstring) of per-episode records from :func:`run_episode`, the standard error
    over scenes of each (``<metric>_se``, from :func:`scene_values`) and the faults per 100 actions."""
    attempts = sum(e["grasp_attempts"] for e in episodes)
    completed = [e for e in episodes if is_completed(e)]
    completed_actions = sum(e["actions"] for e in completed)
    per_scene = [scene_values(e) for e in episodes]
    actions = sum(e["actions"] for e in episodes)
    return dict(
        success_rate=statistics.mean(e["placed"] / e["actions"] for e in episodes),
        grasp_success=sum(e["grasps"] for e in episodes) / attempts if attempts else 0.0,
        completion=len(completed) / len(episodes),
        action_efficiency=sum(e["placed"] for e in completed) / completed_actions if completed_actions else 0.0,
        **{f"{m}_se": standard_error(v[m] for v in per_scene) for m in METRICS},
        workspace_cleared=statistics.mean(float(bool(e["cleared"])) for e in episodes),
        lost_per_scene=statistics.mean(e["lost"] for e in episodes),
        **{f"{k}_per_scene": statistics.mean(int(e.get(k, 0)) for e in episodes) for k in LOSS_CAUSE_KEYS},
        slides_per_scene=statistics.mean(int(e.get("slides", 0)) for e in episodes),
        futile_slides_per_scene=statistics.mean(int(e.get("futile_slides", 0)) for e in episodes),
        faults_per_100_actions=100.0 * sum(e.get("faults", 0) for e in episodes) / actions if actions else 0.0,
    )


def paired_differences(episodes_a: list[dict], episodes_b: list[dict]) -> dict[str, dict]:
    """Per scenario, the paired per-scene difference A - B of every metric (mean and standard error over the scenes
    both evaluations played: same scenario, seed and layout), e.g. a G&S agent against its grasp-only restriction
    on the same scenes. ValueError when they share no scene."""
    key = lambda e: (e["scenario"], int(e["seed"]), e.get("layout", ""))  # noqa: E731
    b_by_key = {key(e): e for e in episodes_b}
    out: dict[str, dict] = {}
    for a in episodes_a:
        b = b_by_key.get(key(a))
        if b is None:
            continue
        va, vb = scene_values(a), scene_values(b)
        row = out.setdefault(a["scenario"], {m: [] for m in METRICS})
        for m in METRICS:
            if va[m] is not None and vb[m] is not None:
                row[m].append(va[m] - vb[m])
    if not out:
        raise ValueError("the two evaluations share no scene (scenario, seed and layout)")
    return {scenario: dict(scenes=len(diffs["completion"]),
                           **{m: dict(mean=statistics.mean(d) if d else 0.0, se=standard_error(d), scenes=len(d))
                              for m, d in diffs.items()})
            for scenario, diffs in out.items()}


def comparison_table(eval_a: Path, eval_b: Path, plot: Path | None = None) -> str:
    """Markdown table of :func:`paired_differences` between two ``eval-clutter`` output folders (or their
    ``eval_summary.json``): per scenario, A - B of each metric in points, ± its standard error over the paired
    scenes; with ``plot``, also the differences as a PNG (:func:`~maniskill_pnp.agents.pixel.eval_figures.plot_paired`).
    FileNotFoundError / ValueError naming the folder for a missing or unreadable summary."""
    import json

    def episodes(path: Path) -> list[dict]:
        path = Path(path)
        summary = path / "eval_summary.json" if path.is_dir() else path
        if not summary.is_file():
            raise FileNotFoundError(f"{path}: no eval_summary.json (an eval-clutter output folder?)")
        try:
            return json.loads(summary.read_text())["episodes"]
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise ValueError(f"{summary} is not an eval-clutter summary: {e}") from e

    diffs = paired_differences(episodes(eval_a), episodes(eval_b))
    if plot is not None:
        plot_paired({"A − B": diffs}, plot)
    lines = [f"A = {eval_a}, B = {eval_b}; paired per-scene differences A - B (points ± standard error)", "",
             "| scenario | scenes | " + " | ".join(METRICS) + " |", "|---" * (len(METRICS) + 2) + "|"]
    for scenario, d in diffs.items():
        cells = [f"{100 * d[m]['mean']:+.1f} ± {100 * d[m]['se']:.1f}" for m in METRICS]
        lines.append(f"| {scenario} | {d['scenes']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- episodes
@torch.inference_mode()
def decide(actor: GreedyPixelActor, obs: dict, device: torch.device, exclude: Collection[int] = ()) -> tuple[int, torch.Tensor]:
    """Greedy flat action index and the Q maps ``(P, R, H, W)`` (on the CPU) of one env observation; the flat
    action indices in ``exclude`` are never chosen (unless they are all the allowed actions)."""
    color, depth = obs["color_heightmap"].to(device), obs["depth_heightmap"].to(device)
    fit = obs.get(FIT_KEY)
    values, action, *mask = actor(color, depth, None if fit is None else fit.to(device))
    if len(exclude):
        allowed = mask[0].reshape(-1).clone() if mask else torch.ones(values.numel(), dtype=torch.bool, device=values.device)
        allowed[torch.as_tensor(np.asarray(exclude, dtype=np.int64), device=values.device)] = False
        if allowed.any():  # the actor's ranking (its primitive margins) over what is left
            action = actor.choice_values(values.reshape(1, -1))[0].masked_fill(~allowed, float("-inf")).argmax()
    net = actor.q_network
    maps = values.reshape(len(net.primitives), net.num_rotations, *depth.shape[-2:])
    return int(action.reshape(-1)[0]), maps.float().cpu()


@dataclass
class EpisodeTally:
    """The per-step accounting of one episode, from the env's ``info`` of every step (the outcome keys of
    :data:`~maniskill_pnp.tasks.OUTCOME_KEYS`; grasp attempts by the rule of
    :func:`~maniskill_pnp.agents.pixel.metrics.is_grasp_attempt`, as the training metrics count them)."""

    primitives: tuple[str, ...]
    """The task's primitive names, in primitive-index order."""
    actions: int = 0
    grasp_attempts: int = 0
    grasps: int = 0
    placed: int = 0
    slides: int = 0
    futile_slides: int = 0
    """Slides that changed nothing (``info["slide_changed"]`` false)."""
    faults: int = 0
    max_failure_run: int = 0
    lost: dict = field(default_factory=lambda: dict.fromkeys(LOSS_CAUSE_KEYS, 0))
    """Objects the steps lost, by cause (:data:`LOSS_CAUSE_KEYS`)."""

    def add(self, info: dict) -> None:
        """Count one step's ``info``."""
        for key in LOSS_CAUSE_KEYS:
            self.lost[key] += int(info[key])
        self.actions += 1
        primitive = self.primitives[int(info["primitive_index"])]
        if primitive != "grasp":
            self.slides += 1
            self.futile_slides += int(not bool(info["slide_changed"]))
        self.grasp_attempts += int(is_grasp_attempt(self.primitives, int(info["primitive_index"])))
        self.grasps += int(info["grasp_success"])
        self.placed += int(info["placed_objects"])
        self.faults += int(info["fault"])
        self.max_failure_run = max(self.max_failure_run, int(info["consecutive_failures"]))


def run_episode(env, actor: GreedyPixelActor, seed: int, device: torch.device, max_steps: int | None,
                on_step=None, scenario: str = "train", avoid_repeats: bool = True, layout_index: int | None = None,
                layout: str = "", actions_per_object: float | None = None,
                drawn: list | None = None) -> tuple[dict, dict]:
    """One greedy episode of the gymnasium env ``env`` from ``reset(seed=seed)``.

    Args:
        on_step: Called with the step's ``info`` after every action (the progress bar's hook).
        avoid_repeats: Mask out the failed actions of the unchanged scene and their neighbours (see
            :class:`ClutterEvalConfig`).
        layout_index: The env's explicit layout to play (``reset(options={"layout_index": k})``); None: the env's own
            choice.
        layout: The record's ``layout`` (the name of that layout).
        actions_per_object: Also cap the actions at this many per object of the scene.
        drawn: A list to append every decision to, drawn for a strip (:func:`~maniskill_pnp.agents.pixel.decision_strip.describe`
            plus its outcome); None: nothing is drawn.

    Returns:
        The episode record (``EPISODE_COLUMNS``) and the first decision: ``{"color", "depth", "maps", "action"}``.
    """
    obs, info = env.reset(seed=seed, options=None if layout_index is None else {"layout_index": layout_index})
    # the objects the episode starts with: those in the workspace once the dropped clutter has settled (the task
    # drops again what rolls off, so dropped_out stays 0 but for a drop that keeps rolling off; it is not in lost)
    objects, dropped_out = int(info["objects_remaining"]), int(info["lost_objects"])
    if actions_per_object is not None:
        cap = max(1, math.floor(actions_per_object * objects))
        max_steps = cap if max_steps is None else min(max_steps, cap)
    tally = EpisodeTally(env.unwrapped.primitive_names)
    first = None
    done = False
    memory = FailureMemory(env.unwrapped.action_layout, env.unwrapped.primitive_names) if avoid_repeats else None
    while not done and (max_steps is None or tally.actions < max_steps):
        action, maps = decide(actor, obs, device, exclude=() if memory is None else memory.excluded())
        if first is None:
            first = dict(color=obs["color_heightmap"][0].cpu().numpy(), depth=obs["depth_heightmap"][0].cpu().numpy(),
                         maps=maps.numpy(), action=action)
        decision = None if drawn is None else describe(env, action, maps.numpy(), obs, tally.actions)
        obs, reward, terminated, truncated, info = env.step(action)
        tally.add(info)
        failed = int(info["consecutive_failures"]) > 0  # a failed grasp, or a slide that changed nothing
        if decision is not None:
            decision.update(outcome_lines=outcome_lines(info, float(reward.item()), decision["primitive"]),
                            failed=failed, lost=sum(int(info[k]) for k in LOSS_CAUSE_KEYS))
            drawn.append(decision)
        if memory is not None:
            memory.observe(action, failed, obs["depth_heightmap"][0].cpu().numpy())
        done = bool(terminated.item() or truncated.item())
        if on_step is not None:
            on_step(info)
    t = tally
    record = dict(
        scenario=scenario, seed=seed, objects=objects, dropped_out=dropped_out, actions=t.actions,
        grasp_attempts=t.grasp_attempts, grasps=t.grasps, placed=t.placed, lost=int(info["lost_objects"]) - dropped_out,
        **t.lost, cleared=bool(info["success"].item()),
        max_failure_run=t.max_failure_run, success_rate=t.placed / t.actions, slides=t.slides,
        futile_slides=t.futile_slides,
        completed=False,
        grasp_success=t.grasps / t.grasp_attempts if t.grasp_attempts else 0.0, faults=t.faults, layout=layout,
    )
    record["completed"] = is_completed(record)
    return record, first


# ----------------------------------------------------------------------------- outputs
def plot_q_heatmaps(first: dict, primitives: tuple[str, ...], path: Path) -> Path:
    """Colour and depth heightmaps, then the Q map of every (primitive, rotation) on one colour scale; the chosen
    ``(rotation, row, col)`` is marked on its map and on the heightmaps. Written as PNG (matplotlib's Agg backend)."""
    import matplotlib.pyplot as plt  # the backend is left to the caller (Agg when there is no display)

    maps = first["maps"]
    P, R, H, W = maps.shape
    p, r, row, col = PixelActionLayout(P, R, H, W).decode(first["action"])
    degrees = np.degrees(rotation_angles(R).numpy())
    panels = 2 + P * R
    ncols = min(panels, 6)
    nrows = math.ceil(panels / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(2.6 * ncols, 2.6 * nrows + 0.6), squeeze=False)
    axes = axes.ravel()
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0].imshow(first["color"])
    axes[0].set_title("colour heightmap")
    depth_img = axes[1].imshow(first["depth"], cmap="viridis")
    axes[1].set_title("depth heightmap (m)")
    fig.colorbar(depth_img, ax=axes[1], fraction=0.046, pad=0.04)
    marker = dict(marker="x", color="red", markersize=10, markeredgewidth=2)
    for ax in axes[:2]:
        ax.plot(col, row, **marker)
    vmin, vmax = float(maps.min()), float(maps.max())
    map_axes = []
    for i in range(P):
        for j in range(R):
            ax = axes[2 + i * R + j]
            img = ax.imshow(maps[i, j], cmap="jet", vmin=vmin, vmax=vmax)
            name = f"{primitives[i]} " if P > 1 else ""
            chosen = (i, j) == (p, r)
            ax.set_title(f"{name}{degrees[j]:g}°" + (" (chosen)" if chosen else ""), fontweight="bold" if chosen else None)
            if chosen:
                ax.plot(col, row, **marker)
            map_axes.append(ax)
    for ax in axes[panels:]:
        ax.set_visible(False)
    fig.colorbar(img, ax=map_axes, fraction=0.02, pad=0.02, label="Q value")
    fig.suptitle(f"Q maps of the first state; chosen {primitives[p]} at rotation {degrees[r]:g}°, row {row}, col {col} (x)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _fmt(v) -> str:
    return f"{v:.3f}" if isinstance(v, float) else str(v)


def _write_csv(path: Path, columns, rows) -> None:
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(columns)
    writer.writerows([[_fmt(r[c]) for c in columns] for r in rows])
    atomic_write_bytes(path, lambda f: f.write(buf.getvalue().encode()))


def write_tables(rows: list[dict], episodes: list[dict], out: Path) -> tuple[Path, Path, Path]:
    """``eval_table.md`` (one row per scenario: each metric in % ± its standard error over scenes, faults per 100
    actions), ``eval_table.csv`` (the same as fractions: :data:`SCENARIO_COLUMNS`) and
    ``eval_episodes.csv`` (one row per episode: :data:`EPISODE_COLUMNS`)."""
    md = ["| " + " | ".join(TABLE_HEADER) + " |", "|---" * len(TABLE_HEADER) + "|"]
    md += ["| " + " | ".join([r["scenario"], str(r["episodes"]), *(f"{r[k]:.1%} ± {r[f'{k}_se']:.1%}" for k in METRICS),
                              f"{r['workspace_cleared']:.1%}", f"{r['lost_per_scene']:.2f}",
                              " / ".join(f"{r[f'{k}_per_scene']:.2f}" for k in LOSS_CAUSE_KEYS),
                              f"{r['slides_per_scene']:.2f} ({r['futile_slides_per_scene']:.2f})",
                              f"{r['faults_per_100_actions']:.2f}"]) + " |" for r in rows]
    md_path, csv_path, ep_path = out / "eval_table.md", out / "eval_table.csv", out / "eval_episodes.csv"
    atomic_write_bytes(md_path, lambda f: f.write(("\n".join(md) + "\n").encode()))
    _write_csv(csv_path, SCENARIO_COLUMNS, rows)
    _write_csv(ep_path, EPISODE_COLUMNS, episodes)
    return md_path, csv_path, ep_path


# ----------------------------------------------------------------------------- main
def worst_first(record: dict) -> tuple:
    """Sort key of episode records, the worst first: not completed, then most objects lost, longest run of
    failures, lowest success rate."""
    return (is_completed(record), -int(record["lost"]), -int(record["max_failure_run"]), float(record["success_rate"]))


def _is_perfect(record: dict) -> bool:
    return is_completed(record) and record["lost"] == 0 and record["placed"] >= record["actions"]


def run(cfg: ClutterEvalConfig, on_episode=None, progress: bool = True) -> dict:
    """Evaluate the checkpoint greedily on every scenario; write the JSON summary, the tables, the Q-map figure, the
    per-scenario metrics figure and the strips of the worst episodes (``cfg.strips``) into ``cfg.out``.

    Args:
        on_episode: Called with each episode's record as it ends (a caller's progress hook).
        progress: Show a progress bar (:func:`~maniskill_pnp.progress.progress_bar`).

    Returns:
        The summary written to ``eval_summary.json``: ``metrics`` (per scenario), ``episodes`` (per-episode
        records), ``files``, ``strips`` (the worst episodes' decision strips), the configs, ``wall_s``.

    Raises:
        FileNotFoundError: the checkpoint does not exist.
        ValueError: the checkpoint is unreadable or not a clutter DQN checkpoint, or a scenario does not fit its task.
    """
    device = resolve_device(cfg.device)
    # 1. load the policy (a bad file fails before any env is made)
    ckpt = cfg.checkpoint_path
    actor, train_cfg, counters = load_policy(ckpt, device, grasp_only=cfg.grasp_only, slide_margin=cfg.slide_margin,
                                               mask_grasp_fit=cfg.mask_grasp_fit, mask_fit_scale=cfg.mask_fit_scale,
                                               mask_keep_in=cfg.mask_keep_in, mask_reach=cfg.mask_reach)
    primitives = actor.q_network.primitives
    env_cfg = train_cfg if cfg.num_objects is None else dataclasses.replace(train_cfg, num_objects=cfg.num_objects)

    # 2. greedy episodes, scenario by scenario (episode i of every scenario from seed + i)
    t0 = time.perf_counter()
    episodes, rows, first = [], [], None
    outcomes = []
    # (row name, make_env arguments, names of the layout files: episode i plays file i mod their number)
    plans = [(scenario, dict(scenario=scenario), None if files is None else [p.stem for p in files])
             for scenario, files in ((s, scenario_layout_files(s)) for s in cfg.scenarios)]
    if cfg.layout_file:
        plans.append((cfg.layout_scenario, dict(scenario="train", layout_file=[str(p) for p in cfg.layout_file]),
                      [p.stem for p in cfg.layout_file]))
    strips: list[Path] = []
    with progress_bar(total=cfg.episodes * len(plans), desc=f"eval {train_cfg.run_name}", unit="episode",
                      disable=not progress) as bar:

        def on_step(info):
            if is_grasp_attempt(primitives, int(info["primitive_index"])):
                outcomes.append(bool(info["grasp_success"]))
            bar.set_postfix(grasp=f"{sum(outcomes) / max(1, len(outcomes)):.2f}", attempts=len(outcomes))

        for scenario, env_args, layouts in plans:
            bar.set_description(f"eval {scenario}")
            torchrl_env = make_env(env_cfg, guard_force=cfg.guard_force, **env_args)
            env = torchrl_env.maniskill_env  # the gymnasium env underneath: its per-step info holds the outcome
            try:
                scenario_episodes, worst = [], []  # worst: (record, drawn decisions) of the worst cfg.strips so far
                for i in range(cfg.episodes):
                    k = None if layouts is None else i % len(layouts)
                    drawn = [] if cfg.strips else None
                    record, decision = run_episode(env, actor, cfg.seed + i, device, cfg.max_steps, on_step, scenario,
                                                   cfg.avoid_repeats, k, "" if k is None else layouts[k],
                                                   cfg.actions_per_object, drawn)
                    scenario_episodes.append(record)
                    first = first or decision
                    if drawn and not _is_perfect(record):
                        worst = sorted([*worst, (record, drawn)], key=lambda w: worst_first(w[0]))[: cfg.strips]
                    bar.update()
                    if on_episode is not None:
                        on_episode(record)
            finally:
                torchrl_env.close()
            for record, drawn in worst:
                name = f"{scenario}_seed{record['seed']}" + (f"_{record['layout']}" if record["layout"] else "")
                strips.append(decisions_strip(strip_rows(drawn), train_cfg.heightmap_size, cfg.out / "strips" / f"{name}.png"))
            episodes += scenario_episodes
            rows.append(dict(scenario=scenario, episodes=len(scenario_episodes), **summarize(scenario_episodes)))
    wall = time.perf_counter() - t0

    # 3. tables, figure and JSON
    out = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    md_path, csv_path, ep_path = write_tables(rows, episodes, out)
    png_path = plot_q_heatmaps(first, primitives, out / "q_heatmaps.png")
    metrics_png = plot_scenario_metrics({train_cfg.run_name: rows}, out / "eval_metrics.png")
    json_path = out / "eval_summary.json"
    metrics = {r["scenario"]: {k: v for k, v in r.items() if k not in ("scenario", "episodes")} for r in rows}
    summary = dict(
        checkpoint=str(ckpt), metrics=metrics, episodes=episodes, wall_s=wall, device=str(device),
        eval_config=cfg.to_json(), train_config=train_cfg.to_json(), train_counters=counters,
        action_mask=None if actor.action_mask is None else actor.action_mask.to_json(),
        files=dict(summary=str(json_path), table_md=str(md_path), table_csv=str(csv_path), episodes_csv=str(ep_path),
                   q_heatmaps=str(png_path), metrics_png=str(metrics_png)),
        strips=[str(p) for p in strips],
    )
    write_json(json_path, summary)
    return summary


__all__ = ["ClutterEvalConfig", "EpisodeTally", "MAX_FAILURE_RUN", "METRICS", "SCENARIO_COLUMNS", "TABLE_HEADER", "comparison_table", "decide", "is_completed", "paired_differences", "worst_first",
           "plot_q_heatmaps", "run", "run_episode", "scene_values", "standard_error", "summarize", "write_tables"]
