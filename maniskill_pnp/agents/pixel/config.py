"""The config of a pixelwise DQN run (:class:`ClutterConfig`) and its presets.

A run is described by one frozen dataclass, saved as ``config.json`` in its run folder. Presets are data: the file
``presets.yaml`` beside this module lists, per preset, a one-line description and the fields that differ from the
dataclass defaults (which are the ``cpu-small`` preset). :meth:`ClutterConfig.from_preset` applies one, then any
overrides. A config file (:meth:`ClutterConfig.from_file`, ``train-clutter --config FILE``) names a preset as its base
and the fields it changes; the recipes of single experiments, among them the presets until 2026-12
(:data:`RETIRED_PRESETS`), are such files in the repository's ``docs/configs/``.

Example:
    >>> cfg = ClutterConfig.from_preset("gs-cpu-small", seed=2)
    >>> cfg.primitives, cfg.env_id
    (('grasp', 'left_slide', 'right_slide'), 'ClutterGraspSlide-v1')
"""

from __future__ import annotations

import functools
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

from maniskill_pnp.agents.collection import check_collection
from maniskill_pnp.agents.pixel.fcn import BACKBONE_CHOICES, EQUIVARIANT
from maniskill_pnp.agents.pixel.policy import PrimitiveExploreMask
from maniskill_pnp.agents.run_io import LOGGERS, RunConfig, require_positive
from maniskill_pnp.scenes.packed_families import check_training_sets
from maniskill_pnp.tasks.clutter_grasp import ClutterGraspEnv, check_loss_cost
from maniskill_pnp.tasks.clutter_grasp_slide import REWARD_SCHEMES, ClutterGraspSlideEnv

#: The tasks a run trains on: its env id and task class (whose ``PRIMITIVES`` are the action's primitives, one FCN
#: each).
TASKS = {
    "grasp": ("ClutterGrasp-v1", ClutterGraspEnv),
    "grasp_slide": ("ClutterGraspSlide-v1", ClutterGraspSlideEnv),
}
LOSSES = ("dqn", "bce")
OPTIMIZERS = ("sgd", "adam")
#: The valid values of the config's choice fields (checked by the config, offered as choices by the command line).
CHOICES = dict(task=tuple(TASKS), loss=LOSSES, optimizer=OPTIMIZERS, backbone=BACKBONE_CHOICES,
               reward_scheme=tuple(REWARD_SCHEMES), logger=LOGGERS)
#: Fields that fix the network's shape or the task: a resumed run must keep them.
ARCHITECTURE_FIELDS = (
    "task", "loss", "backbone", "use_depth", "head_channels", "num_rotations", "heightmap_size", "workspace_side",
)
#: The presets file: preset name -> its ``description`` and the fields it sets.
PRESETS_FILE = Path(__file__).with_name("presets.yaml")
#: Presets that became config files (``docs/configs/<name>.yaml`` in the repository, each naming its base preset and
#: ``name: <name>``): name -> that base preset. Runs and exported agents made before record the old name as their
#: ``preset``; a config read with one (a checkpoint, a run's ``config.json``, a file) gets ``preset`` = the base and
#: ``name`` = the old name, so it loads, and its run name stays what it was.
RETIRED_PRESETS = {
    "gs-cpu-equi-hard": "gs-cpu-equi",
    "gs-cpu-equi-keep": "gs-cpu-equi-fit",
    "gs-cpu-equi-fine": "gs-cpu-equi-fit",
    "gs-cpu-equi-each": "gs-cpu-equi-fit",
    "cpu-equi-no-depth": "cpu-equi",
    "cpu-densenet121-s8": "cpu-small",
    "cpu-resnet101-s8": "cpu-small",
    "gs-resnet101": "gs-thesis",
    "gs-no-slide-reward": "gs-thesis",
    "gs-double-dqn": "gs-thesis",
}


def unretired(preset: str, name: str | None) -> tuple[str, str | None]:
    """``(preset, name)`` of a recorded config: a retired preset (:data:`RETIRED_PRESETS`) becomes its base preset,
    and the name of the recipe, unless one is given; any other preset stays as it is."""
    if preset in RETIRED_PRESETS:
        return RETIRED_PRESETS[preset], name or preset
    return preset, name


#: Characters of a run's ``name`` (it names a folder).
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")
#: The values of ``device``.
_DEVICE = re.compile(r"auto|cpu|cuda(:[0-9]+)?")


@dataclass(frozen=True)
class ClutterConfig(RunConfig):
    """Everything a clutter-grasping DQN run depends on; saved as ``config.json`` in the run folder.

    The defaults are the ``cpu-small`` preset; :func:`presets` holds the overrides of each preset. Where the values
    come from is recorded in two fields: ``preset``, the preset they started from (always one of :func:`presets`), and
    ``name``, the recipe's own name where it is not the preset's (e.g. a config file of ``docs/configs/``). The run
    folder is ``<name or preset>_<backbone>_r<rotations>_px<size>_seed<seed>``. A config recorded before its preset
    became a config file (``preset: gs-cpu-equi-each``) is read as ``preset`` = the file's base and ``name`` = the old
    preset (:data:`RETIRED_PRESETS`): the same values and the same run folder.
    """

    preset: str = "cpu-small"
    """The preset the values start from (each listed with one line at the end of `train-clutter --help`); the run
    name starts with it unless ``name`` is set."""
    name: str | None = None
    """Name of the recipe, the first part of the run name (None: the preset's); a config file of docs/configs/ sets
    it to the file's name, so that its runs keep the folder names they had as a preset."""
    task: str = "grasp"
    """"grasp": one grasp FCN on ClutterGrasp-v1; "grasp_slide": the G&S agent (3 FCNs) on ClutterGraspSlide-v1."""
    loss: str = "dqn"
    """"dqn": Huber loss to r + gamma max Q(s'); "bce": the binary-classification baseline (no bootstrapping, so it
    turns delay_value and double_dqn off)."""
    reward_scheme: str = "default"
    """Reward scheme of ClutterGraspSlide-v1: "default" (a slide pays for any change of the scene),
    "no_slide_reward", "unlock" (a slide pays only when it makes a locked object graspable, judged in the simulator),
    "unlock_each" (it pays per object it makes graspable, up to a placement's reward) or "fit_gain" (it pays only when
    it adds a region where grasps fit the heightmap: no simulator state, as on a real cell); must be "default" for
    task grasp."""
    loss_cost: float = 0.0
    """Reward taken off per object an action loses off the workspace, by any cause (a slide's push, a neighbour set
    rolling by a grasp, a drop in transit or at release; the task's ``loss_cost``); 0: a loss costs only the reward
    it forgoes."""
    backbone: str = "small"
    """Feature trunk of the Q network: "densenet121" (thesis), "resnet101", their stride-8 cuts "densenet121-s8" and
    "resnet101-s8" (the trunk pair at 64 px), or "small" (ResNet-18 to layer2), each run on
    R rotated copies of the heightmap; or "equivariant": a small rotation-equivariant (e2cnn, C_R) network giving all R
    maps in one pass on the unrotated heightmap, its grasp maps r and r + R/2 tied (needs num_rotations >= 2, no
    pretrained weights)."""
    pretrained_path: str | None = None
    """Local state_dict of the full torchvision classifier of the backbone (never downloaded); None: random init (the
    only choice for the equivariant backbone)."""
    use_depth: bool = True
    """Keep the depth trunk beside the colour trunk (False: the thesis' colour-only ablation)."""
    head_channels: int = 64
    """Width of the hidden 1x1 convolution of the Q head (equivariant backbone: channels of its full-resolution layers,
    in whole regular fields of num_rotations channels)."""
    num_rotations: int = 16
    """Grasp yaws evenly spaced over 360 degrees (the thesis' 16: a parallel-jaw grasp at r and r + R/2 is the same
    jaw line, so 16 rotations are 8 jaw orientations 22.5 degrees apart)."""
    heightmap_size: int = 64
    """Heightmap pixels per side; the pixel size is ``workspace_side / heightmap_size``."""
    workspace_side: float = 0.448
    """Side (m) of the square workspace the heightmap covers (the thesis: 224 px of 2 mm)."""
    num_objects: int = 10
    """Objects dropped into the workspace each episode."""
    packed_fraction: float = 0.0
    """Share of training episodes whose objects are packed into tight clusters instead of dropped (so that slides have
    something to pull apart; see maniskill_pnp.scenes.clutter.sample_packed); evaluation scenes other than "train" are
    never packed."""
    hard_fraction: float = 0.0
    """Share of training episodes that play one of the hard training arrangements (tightly packed rows and blocks,
    at least half of their objects locked; a set disjoint from the ``hard`` test scenes, see
    maniskill_pnp.scenes.hard_scenes) at a random yaw, instead of a random clutter."""
    hard_sets: tuple[str, ...] = ("hard_train",)
    """The training arrangement sets ``hard_fraction`` draws from: ``"hard_train"`` (rows and blocks, the hard set's
    generator at training seeds) and/or ``"packed_train"`` (arches and U shapes around blocks, L and T interlocks, a
    tall block among low ones; see maniskill_pnp.scenes.packed_families). Never a test set."""
    guard_force: float | None = None
    """Guarded grasps and slides (N): a descent stops, and the action fails, when contacts push the gripper up by
    more than this, as a real Panda's collision reflex would (20 N: libfranka's example threshold); None: unguarded.
    Training only: evaluations say it with ``eval-clutter --guard-force``."""
    steps: int = 300
    """Grasp attempts (env steps) to train for, counted over resumes."""
    episodes: int = 0
    """Stop after this many finished episodes as well (0: no episode limit)."""
    max_minutes: float = 0.0
    """Stop, with a checkpoint, after this many minutes of this invocation's training loop as well (0: no time
    limit; a resumed run starts its clock again)."""
    gamma: float = 0.5
    """Discount of the DQN target ``r + gamma * max Q'(s')``."""
    delay_value: bool = True
    """Bootstrap from a target network synced by HardUpdate every ``target_update_interval`` updates."""
    target_update_interval: int = 100
    """SGD updates between two hard target-network syncs (used with ``delay_value``)."""
    double_dqn: bool = False
    """Double DQN bootstrap (needs ``delay_value``)."""
    optimizer: str = "sgd"
    """"sgd" (thesis: momentum, weight decay) or "adam" (momentum is unused)."""
    lr: float = 1e-2
    """SGD learning rate."""
    momentum: float = 0.9
    """SGD momentum."""
    weight_decay: float = 1e-3
    """SGD weight decay (L2)."""
    batch_size: int = 4
    """Transitions per sampled replay batch."""
    updates_per_step: int = 1
    """SGD steps (each on a fresh prioritized batch) after every env step."""
    mask_empty: bool = True
    """Act, explore and bootstrap only over grasps where the heightmap shows material (see maniskill_pnp.agents.pixel.mask)."""
    mask_min_height: float = 0.01
    """Height (m) above the table from which a pixel counts as material for ``mask_empty``."""
    mask_grasp_fit: bool = False
    """Also mask out grasps whose open fingers, lowered to the grasp's depth, would strike the heightmap (a neighbour
    pressed against the object, or the object itself when wider than the jaws); needs ``mask_empty``."""
    mask_keep_in: bool = True
    """Also mask out slides that would carry material off the heightmap, where it is lost (the push judged from the
    heightmap: see maniskill_pnp.agents.pixel.mask); needs ``mask_empty``, and only a G&S task has slides."""
    mask_reach: bool = True
    """Also mask out grasps and slides the arm cannot reach (its IK, per rotation and pixel: see
    maniskill_pnp.cell.reach_map; about 1% of the default workspace, at its far corner); needs ``mask_empty``."""
    mask_fit_scale: int = 1
    """With ``mask_grasp_fit``, test the fit on a heightmap this many times finer than the network's (the env also
    observes it as ``fit_heightmap``, and the replay keeps the next state's for the bootstrap's mask): 2 halves the
    pixels the open fingers and pads are placed on. 1: the network's heightmap."""
    learning_starts: int = 1
    """Transitions in the replay before the first SGD step."""
    replay_capacity: int = 2000
    """Transitions the prioritized replay keeps (oldest overwritten first)."""
    replay_alpha: float = 0.6
    """Priority exponent of the replay (0: uniform)."""
    replay_beta: float = 0.4
    """Importance-sampling exponent of the replay's priority weights."""
    save_replay: bool = True
    """Save the replay contents with every checkpoint, so a resumed run continues from them."""
    eps_start: float = 0.3
    """ε of the ε-greedy behaviour at step 0."""
    eps_end: float = 0.1
    """ε after ``eps_decay_steps`` steps (linear decay, then constant)."""
    eps_decay_steps: int = 200
    """Steps over which ε decays linearly from ``eps_start`` to ``eps_end``."""
    explore_weights: tuple[float, ...] = ()
    """Share of each primitive (grasp, left-slide, right-slide) among the ε-random actions, e.g. 2 1 1; empty: a
    uniform draw over the allowed actions, which in clutter makes about 4 in 5 of them slides."""
    slide_margin: float = 0.0
    """Greedy choice of a G&S agent: a slide is chosen only where its Q value beats the best allowed grasp's by more
    than this (0: the plain argmax over all primitives). The Q values and their targets are unchanged; only which
    action the greedy policy (and the ε-greedy one outside its random draws) takes."""
    seed: int = 0
    """Seed of the network initialisation, the episodes, the planner and the exploration."""
    workers: int = 1
    """Env workers collecting in parallel (processes, or Ray actors); each has its own seed, recorded in
    train_summary.json."""
    collector: str = "auto"
    """Collector backend: "auto" (worker processes, one or more), "direct" (the env in the learner's process),
    "process" or "ray" (needs the ray extra, ``pip install maniskill_pnp[ray]``; joins the cluster named by
    RAY_ADDRESS). With synchronous process workers the learner updates on one batch while the workers collect the
    next, with the weights of one batch earlier; a run still repeats from its seed."""
    sync: bool = True
    """A batch waits for every worker (False: each worker's frames as soon as they are ready; the workers then act
    with weights that change under them, so a run no longer repeats from its seed)."""
    device: str = "auto"
    """Torch device of the learner: the Q networks, the target network, the optimizer and each sampled replay batch
    ("auto": CUDA when available, else the CPU; or "cpu", "cuda", "cuda:N"). The simulation and the replay stay on the
    CPU; worker processes act with a CPU copy of the networks, the direct collector on this device. Not an
    architecture field: a run resumes on any device; train_summary.json records the device used."""
    checkpoint_interval: int = 50
    """Write the checkpoint atomically every this many steps (and at the end)."""
    log_interval: int = 10
    """Log the training metrics every this many steps."""
    success_window: int = 50
    """Grasp attempts in the running grasp success shown on the progress bar and logged."""
    logger: str = "csv"
    """Where the training metrics go: "csv" (CSV files in the run folder, read back by the evaluation/plot commands)
    or "tensorboard" (TorchRL's TensorboardLogger; needs the tensorboard extra,
    ``pip install maniskill_pnp[tensorboard]``). The per-action ``actions.csv`` is written either way."""
    resume: bool = False
    """Continue from the run folder's checkpoint.pt (its architecture fields must match this config)."""
    out: Path = Path("runs/clutter")
    """Parent folder of the run folder ``<name or preset>_<backbone>_r<rotations>_px<size>_seed<seed>``."""

    def __post_init__(self):
        object.__setattr__(self, "out", Path(self.out))
        preset, name = unretired(self.preset, self.name)  # recorded before it became a config file
        object.__setattr__(self, "preset", preset)
        object.__setattr__(self, "name", name)
        if self.preset not in presets():
            raise ValueError(f"unknown preset {self.preset!r}; valid: {list(presets())}")
        if self.name is not None and not _NAME.fullmatch(self.name):
            raise ValueError(f"name must be letters, digits and ._+- (it names the run folder), got {self.name!r}")
        for name, valid in CHOICES.items():
            if getattr(self, name) not in valid:
                raise ValueError(f"unknown {name.replace('_', ' ')} {getattr(self, name)!r}; valid: {list(valid)}")
        check_collection(self.workers, self.collector, self.sync)
        if not isinstance(self.device, str) or not _DEVICE.fullmatch(self.device):
            raise ValueError(f"device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {self.device!r}")
        if self.task == "grasp" and self.reward_scheme != "default":
            raise ValueError(f"reward_scheme {self.reward_scheme!r} needs task 'grasp_slide' (ClutterGrasp-v1 has one scheme)")
        if self.loss == "bce" and (self.double_dqn or self.delay_value):
            object.__setattr__(self, "delay_value", False)  # no bootstrap, so no target network
            object.__setattr__(self, "double_dqn", False)
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {self.gamma}")
        if self.double_dqn and not self.delay_value:
            raise ValueError("double_dqn needs delay_value (a target network)")
        if not 0.0 <= self.eps_end <= self.eps_start <= 1.0:
            raise ValueError(f"need 0 <= eps_end <= eps_start <= 1, got {self.eps_start} -> {self.eps_end}")
        if not self.workspace_side > 0 or not self.lr > 0:
            raise ValueError(f"workspace_side and lr must be > 0, got {self.workspace_side}, {self.lr}")
        positive = ("head_channels", "num_rotations", "heightmap_size", "num_objects", "steps", "target_update_interval",
                    "batch_size", "updates_per_step", "learning_starts", "replay_capacity", "eps_decay_steps", "checkpoint_interval",
                    "log_interval", "success_window")
        require_positive(self, positive)
        if self.backbone == EQUIVARIANT and (self.pretrained_path is not None or self.num_rotations < 2):
            raise ValueError(f"the equivariant backbone needs num_rotations >= 2 and no pretrained_path, got "
                             f"{self.num_rotations} and {self.pretrained_path!r}")
        object.__setattr__(self, "explore_weights", tuple(float(w) for w in self.explore_weights))
        if self.explore_weights and len(self.explore_weights) != len(self.primitives):
            raise ValueError(f"explore_weights needs one weight per primitive {self.primitives}, got {self.explore_weights}")
        if self.explore_weights:
            PrimitiveExploreMask(self.explore_weights)  # raises on negative, non-finite or all-zero weights
        if not 0.0 <= self.packed_fraction <= 1.0:
            raise ValueError(f"packed_fraction must be in [0, 1], got {self.packed_fraction}")
        if not 0.0 <= self.hard_fraction <= 1.0 or self.packed_fraction + self.hard_fraction > 1.0:
            raise ValueError(f"hard_fraction must be in [0, 1 - packed_fraction], got {self.hard_fraction} "
                             f"(packed_fraction {self.packed_fraction})")
        if self.mask_grasp_fit and not self.mask_empty:
            raise ValueError("mask_grasp_fit refines the material mask: it needs mask_empty")
        k = self.mask_fit_scale
        if not isinstance(k, int) or isinstance(k, bool) or k < 1 or (k > 1 and not self.mask_grasp_fit):
            raise ValueError(f"mask_fit_scale must be a positive int, and 1 unless mask_grasp_fit is on; got {k!r}")
        object.__setattr__(self, "hard_sets", check_training_sets(self.hard_sets))
        check_loss_cost(self.loss_cost)
        if self.guard_force is not None and not (math.isfinite(self.guard_force) and self.guard_force > 0):
            raise ValueError(f"guard_force must be a positive force in N (or None: unguarded), got {self.guard_force}")
        if not math.isfinite(self.slide_margin) or (self.slide_margin and self.task != "grasp_slide"):
            raise ValueError(f"slide_margin must be a finite number, and 0 unless task is 'grasp_slide'; got {self.slide_margin}")
        if self.episodes < 0 or not self.max_minutes >= 0:
            raise ValueError(f"episodes and max_minutes must be >= 0, got {self.episodes}, {self.max_minutes}")

    @classmethod
    def from_preset(cls, preset: str, /, **overrides) -> ClutterConfig:
        """The preset ``preset`` (see :func:`presets`) with ``overrides`` (fields, ``name`` among them) applied."""
        all_presets = presets()
        if preset in RETIRED_PRESETS:
            raise ValueError(f"preset {preset!r} is now a config file: train-clutter --config docs/configs/{preset}.yaml "
                             f"(ClutterConfig.from_file); presets: {list(all_presets)}")
        if preset not in all_presets:
            raise ValueError(f"unknown preset {preset!r}; valid: {list(all_presets)}")
        return cls(**{**all_presets[preset], **overrides, "preset": preset})

    @classmethod
    def values_from_file(cls, path: str | os.PathLike) -> dict:
        """The field values of a YAML or JSON config file, checked against the fields (names and types) but not yet
        a config; ValueError naming the file and the problem.

        A file gives any fields; missing ones come from its base, the preset it names as ``preset`` (default
        cpu-small), whose values lie under the file's (:meth:`from_file`, ``train-clutter --config``). A recipe of its
        own sets ``name``, the first part of its run folders' name; e.g. ``docs/configs/gs-cpu-equi-each.yaml``::

            preset: gs-cpu-equi-fit
            name: gs-cpu-equi-each
            loss_cost: 1.0
            ...

        trains what the preset ``gs-cpu-equi-each`` did, in ``gs-cpu-equi-each_equivariant_r16_px64_seed0``, and its
        ``config.json`` records ``preset: gs-cpu-equi-fit``, ``name: gs-cpu-equi-each``. A file written before a
        preset was retired (a run's ``config.json`` with ``preset: gs-cpu-equi-each``) reads as that: ``preset`` its
        base, ``name`` the old preset (:data:`RETIRED_PRESETS`).
        """
        values = super().values_from_file(path)
        if values.get("preset") in RETIRED_PRESETS:
            values["preset"], values["name"] = unretired(values["preset"], values.get("name"))
        return values

    @classmethod
    def from_file(cls, path: str | os.PathLike, **overrides) -> ClutterConfig:
        """The config of a YAML or JSON file (see :meth:`values_from_file`): its base preset's values, then the
        file's, then ``overrides`` (a ``preset`` among them replaces the file's base); what ``train-clutter --config``
        trains."""
        values = cls.values_from_file(path)
        preset = overrides.pop("preset", None) or values.pop("preset", "cpu-small")
        values.pop("preset", None)
        try:
            cls._check_values(overrides)
            return cls.from_preset(preset, **{**values, **overrides})
        except (TypeError, ValueError) as e:
            raise ValueError(f"config file {path}: {e}") from e

    @property
    def run_name(self) -> str:
        return f"{self.name or self.preset}_{self.backbone}_r{self.num_rotations}_px{self.heightmap_size}_seed{self.seed}"

    @property
    def env_id(self) -> str:
        """The task's env id (``ClutterGrasp-v1`` or ``ClutterGraspSlide-v1``)."""
        return TASKS[self.task][0]

    @property
    def primitives(self) -> tuple[str, ...]:
        """The task's primitive names, in the order of the action's primitive index."""
        return tuple(TASKS[self.task][1].PRIMITIVES)

    def primitive_margins(self, slide_margin: float | None = None) -> tuple[float, ...]:
        """The greedy choice's margin per primitive: 0 for grasps, ``slide_margin`` (default: the config's) for slides."""
        m = self.slide_margin if slide_margin is None else float(slide_margin)
        return tuple(0.0 if name == "grasp" else m for name in self.primitives)


@functools.cache
def _read_presets() -> tuple[dict[str, dict], dict[str, str]]:
    import yaml

    entries = yaml.safe_load(PRESETS_FILE.read_text())
    if not isinstance(entries, dict):
        raise ValueError(f"{PRESETS_FILE} must map preset names to their fields")
    fields, descriptions = {}, {}
    for name, values in entries.items():
        values = dict(values or {})
        description = values.pop("description", None)
        try:
            if not isinstance(description, str) or not description.strip() or "\n" in description.strip():
                raise ValueError(f"needs a one-line description, got {description!r}")
            if name in RETIRED_PRESETS:
                raise ValueError("is a retired preset's name (RETIRED_PRESETS)")
            if {"preset", "name"} & set(values):
                raise ValueError("a preset sets neither 'preset' nor 'name'")
            ClutterConfig._check_values(values)
        except ValueError as e:
            raise ValueError(f"{PRESETS_FILE}, preset {name!r}: {e}") from e
        fields[name], descriptions[name] = values, description.strip()
    return fields, descriptions


def presets() -> dict[str, dict]:
    """Every preset: its name -> the fields it sets (a fresh copy of what ``presets.yaml`` holds, checked against the
    fields' names and types)."""
    return {name: dict(values) for name, values in _read_presets()[0].items()}


def preset_descriptions() -> dict[str, str]:
    """Every preset: its name -> its one-line description (the help ``train-clutter --help`` lists)."""
    return dict(_read_presets()[1])


__all__ = [
    "ARCHITECTURE_FIELDS", "CHOICES", "ClutterConfig", "LOSSES", "OPTIMIZERS", "PRESETS_FILE", "RETIRED_PRESETS", "TASKS",
    "preset_descriptions", "presets", "unretired",
]
