"""Recipe: pixelwise DQN agents on the clutter tasks (thesis parts II and III), on TorchRL.

``task="grasp"`` trains one grasp FCN on ``ClutterGrasp-v1``; ``task="grasp_slide"`` trains the G&S agent, three
FCNs (grasp, left slide, right slide) on ``ClutterGraspSlide-v1``, acting by the maximum over all their maps.
One agent step is one whole primitive: the ε-greedy actor picks the argmax flat index over (primitive, rotation,
row, col) of the Q maps of the current heightmaps; the env executes it. After every step the transition goes into
a prioritized replay, ``updates_per_step`` batches are sampled, each followed by one SGD step on the pixelwise loss
(only the executed pixel is trained: the DQN loss, or with ``loss="bce"`` the thesis' binary-classification
baseline) and a refresh of the sampled priorities.

Run it with ``maniskill-pnp train-clutter --preset cpu-small --seed 1`` (``--preset gs-cpu-small`` for G&S); a run folder
``<out>/<run_name>/`` receives ``config.json``, ``checkpoint.pt`` (written atomically every ``checkpoint_interval``
steps and at the end), ``train_summary.json``, ``actions.csv`` (one row per action, see :data:`ACTION_COLUMNS`) and the CSV logs (``scalars/train/grasp_success.csv`` ...;
with ``logger="tensorboard"`` a TensorBoard event file instead).
``--resume`` continues from the run folder's checkpoint (model, optimizer, target network, ε, step and episode
counters, RNG states) and, with ``save_replay`` (the default), from the replay buffer saved beside it
(``replay_step<N>/``: TorchRL's ``ReplayBuffer.dumps`` of the storage, priorities and writer; about 40 kB per
transition at 64 px, 0.5 MB at 224 px). The checkpoint names the replay folder of its own step, written before
it, so a crash between the two leaves the previous pair intact.

With ``mask_empty`` (the default) the actor and the bootstrap range over the actions that can touch something:
grasps where the heightmap shows material, slides that start on bare table and meet material within half their
length (:class:`~maniskill_pnp.agents.pixel_mask.HeightmapActionMask`).

Metrics of the ε-greedy behaviour (DESIGN.md names), logged as running values over the last ``success_window``
actions: ``grasp_success`` (grasp attempts that lifted an object / grasp attempts) and ``success_rate`` (objects
placed in the bin / actions); per finished episode also ``episode/success_rate`` and ``episode/completion``.
"""

from __future__ import annotations

import random
import shutil
import time
from collections import deque
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.objectives import HardUpdate
from tqdm import tqdm

from maniskill_pnp.agents.collection import check_collection, make_collector, resolve_backend, streams, sync_weights, worker_seeds
from maniskill_pnp.agents.run_io import (
    RunConfig, atomic_write_bytes, check_logger, make_logger, require_logger, require_positive, write_json,
)
from maniskill_pnp.agents.pixel_fcn import BACKBONES, MultiPrimitiveQNetwork
from maniskill_pnp.agents.pixel_loss import PixelBCELoss, PixelDQNLoss
from maniskill_pnp.agents.pixel_mask import HeightmapActionMask
from maniskill_pnp.agents.pixel_policy import PrimitiveExploreMask, heightmap_input, make_pixel_policy
from maniskill_pnp.agents.pixel_replay import make_pixel_replay, pack_transition, unpack_transition
from maniskill_pnp.tasks.workspace import WorkspaceSpec

CHECKPOINT_FORMAT = "maniskill_pnp.clutter_dqn/1"
#: The tasks a run trains on: env id and the primitives of its action (one FCN each).
TASKS = {
    "grasp": dict(env_id="ClutterGrasp-v1", primitives=("grasp",)),
    "grasp_slide": dict(env_id="ClutterGraspSlide-v1", primitives=("grasp", "left_slide", "right_slide")),
}
LOSSES = ("dqn", "bce")
OPTIMIZERS = ("sgd", "adam")
#: Fields that fix the network's shape or the task: a resumed run must keep them.
ARCHITECTURE_FIELDS = (
    "task", "loss", "backbone", "use_depth", "head_channels", "num_rotations", "heightmap_size", "workspace_side",
)


@dataclass(frozen=True)
class ClutterConfig(RunConfig):
    """Everything a clutter-grasping DQN run depends on; saved as ``config.json`` in the run folder.

    The defaults are the ``cpu-small`` preset; :data:`PRESETS` holds the overrides of each preset.
    """

    preset: str = "cpu-small"
    """Name of the preset these values started from (part of the run name)."""
    task: str = "grasp"
    """"grasp": one grasp FCN on ClutterGrasp-v1; "grasp_slide": the G&S agent (3 FCNs) on ClutterGraspSlide-v1."""
    loss: str = "dqn"
    """"dqn": Huber loss to r + gamma max Q(s'); "bce": the binary-classification baseline (no bootstrapping, so it
    turns delay_value and double_dqn off)."""
    reward_scheme: str = "default"
    """Reward scheme of ClutterGraspSlide-v1 ("default" or "no_slide_reward"); must be "default" for task grasp."""
    backbone: str = "small"
    """Feature trunk of the Q network: "densenet121" (thesis), "resnet101" or "small" (ResNet-18 to layer2)."""
    pretrained_path: str | None = None
    """Local state_dict of the full torchvision classifier of the backbone (never downloaded); None: random init."""
    use_depth: bool = True
    """Keep the depth trunk beside the colour trunk (False: the thesis' colour-only ablation)."""
    head_channels: int = 64
    """Width of the hidden 1x1 convolution of the Q head."""
    num_rotations: int = 4
    """Grasp yaws evenly spaced over 360 degrees (the thesis uses 16)."""
    heightmap_size: int = 64
    """Heightmap pixels per side; the pixel size is ``workspace_side / heightmap_size``."""
    workspace_side: float = 0.448
    """Side (m) of the square workspace the heightmap covers (the thesis: 224 px of 2 mm)."""
    num_objects: int = 10
    """Objects dropped into the workspace each episode."""
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
    """Act, explore and bootstrap only over grasps where the heightmap shows material (see pixel_mask)."""
    mask_min_height: float = 0.01
    """Height (m) above the table from which a pixel counts as material for ``mask_empty``."""
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
    seed: int = 0
    """Seed of the network initialisation, the episodes, the planner and the exploration."""
    workers: int = 1
    """Env workers collecting in parallel (processes, or Ray actors); each has its own seed, recorded in
    train_summary.json."""
    collector: str = "auto"
    """Collector backend: "auto" (direct for one worker, process for more), "direct", "process" or "ray" (needs the
    ray extra, ``pip install maniskill_pnp[ray]``; joins the cluster named by RAY_ADDRESS)."""
    sync: bool = True
    """A multi-worker batch waits for every worker (False: each worker's frames as soon as they are ready)."""
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
    """Parent folder of the run folder ``<preset>_<backbone>_r<rotations>_px<size>_seed<seed>``."""

    def __post_init__(self):
        object.__setattr__(self, "out", Path(self.out))
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; valid: {list(PRESETS)}")
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r}; valid: {list(TASKS)}")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"unknown optimizer {self.optimizer!r}; valid: {list(OPTIMIZERS)}")
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; valid: {list(LOSSES)}")
        check_logger(self.logger)
        check_collection(self.workers, self.collector, self.sync)
        if self.task == "grasp" and self.reward_scheme != "default":
            raise ValueError(f"reward_scheme {self.reward_scheme!r} needs task 'grasp_slide' (ClutterGrasp-v1 has one scheme)")
        if self.loss == "bce" and (self.double_dqn or self.delay_value):
            object.__setattr__(self, "delay_value", False)  # no bootstrap, so no target network
            object.__setattr__(self, "double_dqn", False)
        if self.backbone not in BACKBONES:
            raise ValueError(f"unknown backbone {self.backbone!r}; valid: {sorted(BACKBONES)}")
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
        object.__setattr__(self, "explore_weights", tuple(float(w) for w in self.explore_weights))
        if self.explore_weights and len(self.explore_weights) != len(self.primitives):
            raise ValueError(f"explore_weights needs one weight per primitive {self.primitives}, got {self.explore_weights}")
        if self.explore_weights:
            PrimitiveExploreMask(self.explore_weights)  # raises on negative, non-finite or all-zero weights
        if self.episodes < 0 or not self.max_minutes >= 0:
            raise ValueError(f"episodes and max_minutes must be >= 0, got {self.episodes}, {self.max_minutes}")

    @classmethod
    def from_preset(cls, name: str, **overrides) -> ClutterConfig:
        """The preset ``name`` (a key of :data:`PRESETS`) with ``overrides`` applied."""
        if name not in PRESETS:
            raise ValueError(f"unknown preset {name!r}; valid: {list(PRESETS)}")
        return cls(**{**PRESETS[name], **overrides, "preset": name})

    @property
    def run_name(self) -> str:
        return f"{self.preset}_{self.backbone}_r{self.num_rotations}_px{self.heightmap_size}_seed{self.seed}"

    @property
    def primitives(self) -> tuple[str, ...]:
        return TASKS[self.task]["primitives"]


_THESIS = dict(
    backbone="densenet121", num_rotations=16, heightmap_size=224, num_objects=10, episodes=3000, steps=90_000,
    batch_size=1, replay_capacity=50_000, eps_decay_steps=10_000, target_update_interval=500, checkpoint_interval=500,
    log_interval=50, success_window=200,
)
_GS = dict(task="grasp_slide")
_GS_THESIS = dict(_THESIS, **_GS)
#: Overrides of the dataclass defaults per preset: part II (grasp) and part III (G&S) with the thesis' ablations.
PRESETS: dict[str, dict] = {
    "cpu-small": {},  # grasp-only, small trunk, 4 rotations, 64 px: learns on 2 CPU cores
    "thesis": _THESIS,  # part II: DenseNet-121, 16 rotations, 224 px of 2 mm, 3000 episodes of 10 objects
    "gs-cpu-small": _GS,
    "gs-thesis": _GS_THESIS,  # part III: G&S, DenseNet-121 trunks
    "gs-resnet101": dict(_GS_THESIS, backbone="resnet101"),
    "gs-bce": dict(_GS_THESIS, loss="bce"),  # binary-classification baseline
    "gs-no-slide-reward": dict(_GS_THESIS, reward_scheme="no_slide_reward"),
    "gs-no-depth": dict(_GS_THESIS, use_depth=False),
    "gs-double-dqn": dict(_GS_THESIS, double_dqn=True),  # the thesis' future work
}


# ----------------------------------------------------------------------------- factories
def make_workspace(cfg: ClutterConfig) -> WorkspaceSpec:
    """The workspace of the config: its heightmap size, pixel size and rotations (the rest at the task defaults)."""
    return WorkspaceSpec(
        heightmap_size=cfg.heightmap_size, pixel_size=cfg.workspace_side / cfg.heightmap_size, num_rotations=cfg.num_rotations
    )


def make_env(cfg: ClutterConfig, **task_kwargs):
    """The config's task as a TorchRL env, with its heightmap size, rotations and object count, on the CPU
    (``task_kwargs`` override or add task and ManiSkill options, e.g. ``num_objects="medium"``,
    ``layout="complicated"``, or ``num_envs=16, sim_backend="physx_cuda", render_backend="sapien_cuda"``)."""
    from maniskill_pnp.torchrl_env import make_torchrl_env

    import maniskill_pnp  # noqa: F401  (registers the task ids)

    options = dict(num_objects=cfg.num_objects, workspace=make_workspace(cfg), planner_seed=cfg.seed,
                   sim_backend="physx_cpu", render_backend="cpu")
    if cfg.task == "grasp_slide":
        options["reward_scheme"] = cfg.reward_scheme
    options.update(task_kwargs)
    return make_torchrl_env(TASKS[cfg.task]["env_id"], **options)


def make_worker_env(cfg: ClutterConfig, seed: int):
    """The env of one collector worker: the config's task with its planner seeded by ``seed`` (picklable with
    ``functools.partial``)."""
    return make_env(replace(cfg, seed=seed))


def make_action_mask(cfg: ClutterConfig, enabled: tuple[str, ...] | None = None) -> HeightmapActionMask | None:
    """The action mask of the config: with ``mask_empty``, grasps on material and slides from bare table towards
    material within half a slide; only the ``enabled`` primitives (e.g. ``("grasp",)`` for a G&S agent restricted to
    grasps); None when neither applies."""
    if not cfg.mask_empty and enabled is None:
        return None
    return HeightmapActionMask.for_workspace(
        cfg.primitives, make_workspace(cfg), min_height=cfg.mask_min_height if cfg.mask_empty else None, enabled=enabled
    )


def make_model(cfg: ClutterConfig) -> MultiPrimitiveQNetwork:
    """One pixel Q network per primitive of the task: ``(N, 4, H, W) -> (N, P, R, H, W)``."""
    return MultiPrimitiveQNetwork(
        cfg.primitives, num_rotations=cfg.num_rotations, backbone=cfg.backbone, use_depth=cfg.use_depth,
        head_channels=cfg.head_channels, pretrained_path=cfg.pretrained_path,
    )


def to_transitions(batch: TensorDictBase) -> TensorDict:
    """Flat collector frames -> the transitions the loss reads (heightmap ``"observation"`` built from the env keys)."""
    nxt = batch.get("next")
    n = batch.batch_size[0]
    return TensorDict(
        {
            "observation": heightmap_input(batch.get("color_heightmap"), batch.get("depth_heightmap")),
            "action": batch.get("action").reshape(n),
            "next": {
                "observation": heightmap_input(nxt.get("color_heightmap"), nxt.get("depth_heightmap")),
                "reward": nxt.get("reward").reshape(n),
                "terminated": nxt.get("terminated").reshape(n),
                "done": nxt.get("done").reshape(n),
            },
        },
        batch_size=[n],
    )


# ----------------------------------------------------------------------------- metrics
class OutcomeTracker:
    """Running DESIGN.md metrics of the actions taken, read from the rewards (no env info needed).

    A grasp attempt is an action of primitive 0; it lifted an object when its reward is at least the task's
    ``rewards["grasp"]``; an object was placed when the reward is at least ``rewards["place"]``.

    With ``log_path`` every action is appended as a row of :data:`ACTION_COLUMNS` to that CSV (``actions.csv`` of a
    run, read by :mod:`maniskill_pnp.agents.clutter_curves`); rows past ``start_step`` (written after the checkpoint
    a run resumes from) are dropped first, so the file always matches the checkpoint's history.

    Args:
        rewards: The task's reward table (``env.base_env.rewards``: ``place``, ``grasp`` and maybe ``slide``).
        actions_per_primitive: ``R * H * W``.
        window: Actions in the running ``grasp_success`` / ``success_rate``.
        log_path: Optional per-action CSV.
        start_step: Actions already taken (the checkpoint's step counter) when resuming.
    """

    def __init__(self, rewards: dict, actions_per_primitive: int, window: int, log_path: Path | None = None,
                 start_step: int = 0):
        self.place, self.grasp = float(rewards["place"]), float(rewards["grasp"])
        self.per_primitive = int(actions_per_primitive)
        self.grasps: deque[bool] = deque(maxlen=window)
        self.placed: deque[bool] = deque(maxlen=window)
        self.last_grasps = 0
        self.step = int(start_step)
        self._episodes: dict = {}  # stream (worker, trajectory) -> actions and placed objects so far
        self._log = None
        if log_path is not None:
            self._log = _open_action_log(Path(log_path), self.step)

    def add(self, action: torch.Tensor, reward: torch.Tensor, done: torch.Tensor, terminated: torch.Tensor,
            stream=0) -> list[dict]:
        """Record consecutive steps of one env (in order; ``stream`` names the env's episode when several workers
        interleave, see :func:`~maniskill_pnp.agents.collection.streams`); returns the episodes they finished."""
        finished, self.last_grasps = [], 0
        for a, r, d, t in zip(action.reshape(-1).tolist(), reward.reshape(-1).tolist(), done.reshape(-1).tolist(),
                              terminated.reshape(-1).tolist()):
            placed = r >= self.place
            primitive = a // self.per_primitive
            if primitive == 0:
                self.grasps.append(r >= self.grasp)
                self.last_grasps += int(r >= self.grasp)
            self.placed.append(placed)
            self.step += 1
            if self._log is not None:
                self._log.write(f"{self.step},{primitive},{a},{r:.4g},{int(primitive == 0)},"
                                f"{int(primitive == 0 and r >= self.grasp)},{int(placed)},{int(d)}\n")
            e = self._episodes.setdefault(stream, dict(actions=0, placed=0))
            e["actions"] += 1
            e["placed"] += int(placed)
            if d:
                finished.append(dict(e, success_rate=e["placed"] / e["actions"], completed=bool(t)))
                del self._episodes[stream]
        if self._log is not None:
            self._log.flush()
        return finished

    def close(self) -> None:
        if self._log is not None:
            self._log.close()

    @property
    def grasp_success(self) -> float:
        """Grasp attempts that lifted an object / grasp attempts, over the window (0 before any attempt)."""
        return sum(self.grasps) / len(self.grasps) if self.grasps else 0.0

    @property
    def success_rate(self) -> float:
        """Objects placed / actions, over the window."""
        return sum(self.placed) / len(self.placed) if self.placed else 0.0


#: Columns of a run's ``actions.csv``: one row per action of the ε-greedy behaviour.
ACTION_COLUMNS = ("step", "primitive", "action", "reward", "grasp_attempt", "grasped", "placed", "episode_end")


def _open_action_log(path: Path, start_step: int):
    """Open ``path`` for appending, after dropping the rows past ``start_step`` (and any torn last line)."""
    keep = []
    if path.is_file() and start_step > 0:
        lines = path.read_text().splitlines()
        for line in lines[1:]:
            parts = line.split(",")
            if len(parts) == len(ACTION_COLUMNS) and parts[0].isdigit() and int(parts[0]) <= start_step:
                keep.append(line)
    with open(path, "w") as f:
        f.write(",".join(ACTION_COLUMNS) + "\n" + "".join(line + "\n" for line in keep))
    return open(path, "a")


# ----------------------------------------------------------------------------- checkpoints
def _rng_state() -> dict:
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    return dict(
        torch=torch.get_rng_state(), python=random.getstate(),
        numpy=dict(kind=kind, keys=torch.from_numpy(keys.astype(np.int64)), pos=pos, has_gauss=has_gauss, cached=cached),
    )


def _set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    random.setstate(state["python"])
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"]))


def save_checkpoint(path: Path, *, cfg, model, loss, optimizer, egreedy, counters: dict, replay_meta: dict) -> None:
    """``torch.save`` everything a resumed run needs, atomically (temp file + ``os.replace``)."""
    payload = dict(
        format=CHECKPOINT_FORMAT, config=cfg.to_json(), model=model.state_dict(), loss=loss.state_dict(),
        optimizer=optimizer.state_dict(), egreedy=egreedy.state_dict(), counters=dict(counters),
        rng=_rng_state(), replay=dict(replay_meta),
    )
    atomic_write_bytes(path, lambda f: torch.save(payload, f))


def checkpoint_file(path: Path) -> Path:
    """The checkpoint file of ``path``: ``checkpoint.pt`` inside it when it is a run folder, else ``path`` itself."""
    path = Path(path)
    return path / "checkpoint.pt" if path.is_dir() else path


def load_checkpoint(path: Path) -> dict:
    """The payload of :func:`save_checkpoint` (``path``: the file or its run folder); ValueError naming the file if
    it is not one."""
    path = checkpoint_file(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for truncated / foreign files
        first_line = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise ValueError(f"checkpoint {path} is unreadable (truncated or not a torch.save file): {first_line}") from e
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"checkpoint {path} is not a clutter DQN checkpoint (expected format {CHECKPOINT_FORMAT!r})")
    return payload


def export_weights(checkpoint: Path, dest: Path, half: bool = True) -> Path:
    """A shareable agent from a training checkpoint: only its config, counters and network weights (float16 with
    ``half``), in the checkpoint format, so ``eval-clutter`` and ``record-clutter`` load it like the original.
    Optimizer, target network, RNG and replay are dropped: it cannot be resumed."""
    payload = load_checkpoint(checkpoint)
    model = {k: v.half() if half and v.is_floating_point() else v for k, v in payload["model"].items()}
    slim = dict(format=CHECKPOINT_FORMAT, config=payload["config"], model=model, counters=payload.get("counters", {}))
    atomic_write_bytes(Path(dest), lambda f: torch.save(slim, f))
    return Path(dest)


# ----------------------------------------------------------------------------- main
def crossed(step: int, n: int, interval: int) -> bool:
    """Whether the last ``n`` steps, ending at ``step``, passed a multiple of ``interval``."""
    return step // interval > (step - n) // interval


def main(cfg: ClutterConfig) -> dict:
    """Train one pixelwise DQN grasping agent; returns a summary (run folder, steps, episodes, grasp success)."""
    require_logger(cfg.logger)  # a missing tensorboard extra fails before anything is built
    run_dir = cfg.run_dir
    ckpt_path = run_dir / "checkpoint.pt"
    payload = None
    if cfg.resume:
        payload = load_checkpoint(ckpt_path)
        saved = ClutterConfig.from_json(payload["config"])
        changed = [f for f in ARCHITECTURE_FIELDS if getattr(saved, f) != getattr(cfg, f)]
        if changed:
            raise ValueError(f"cannot resume {ckpt_path}: {changed} differ from the checkpoint's config")
    counters = dict(payload["counters"]) if payload else dict(steps=0, episodes=0, updates=0, grasps=0)
    torch.manual_seed(cfg.seed)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "config.json", cfg.to_json())

    # 1. make the env (a fresh episode seed on resume, so finished episodes are not replayed); with several workers
    #    it only gives the specs and the reward table, and each worker builds its own
    env = make_env(cfg)
    env_seed = cfg.seed + counters["episodes"]
    env.set_seed(env_seed)
    rewards = env.base_env.rewards

    # 2. make the model and its greedy / ε-greedy actors
    model = make_model(cfg)
    mask = make_action_mask(cfg)
    _, explore, egreedy = make_pixel_policy(
        model, env.action_spec, eps_init=cfg.eps_start, eps_end=cfg.eps_end, annealing_num_steps=cfg.eps_decay_steps,
        action_mask=mask, explore_weights=cfg.explore_weights or None,
    )

    # 3. make the prioritized replay (packed heightmaps, memory-mapped in the run folder's scratch "replay/";
    #    a resumed run loads the contents its checkpoint names)
    shutil.rmtree(run_dir / "replay", ignore_errors=True)
    replay = make_pixel_replay(
        cfg.replay_capacity, run_dir / "replay", cfg.replay_alpha, cfg.replay_beta, batch_size=cfg.batch_size
    )
    if payload is not None and payload["replay"].get("dir"):
        saved_replay = run_dir / payload["replay"]["dir"]
        if not saved_replay.is_dir():
            raise ValueError(f"cannot resume {ckpt_path}: its replay folder {saved_replay} is missing")
        replay.loads(saved_replay)

    # 4. make the loss, the target-network updater and the optimizer
    if cfg.loss == "bce":
        loss, loss_key = PixelBCELoss(model), "loss_bce"
    else:
        loss, loss_key = PixelDQNLoss(model, gamma=cfg.gamma, delay_value=cfg.delay_value, double_dqn=cfg.double_dqn,
                                      action_mask=None if mask is None else mask.from_observation), "loss_qvalue"
    updater = HardUpdate(loss, value_network_update_interval=cfg.target_update_interval) if cfg.delay_value else None
    if cfg.optimizer == "adam":
        optimizer = torch.optim.Adam(loss.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    else:
        optimizer = torch.optim.SGD(loss.parameters(), lr=cfg.lr, momentum=cfg.momentum, weight_decay=cfg.weight_decay)

    if payload is not None:
        model.load_state_dict(payload["model"])
        loss.load_state_dict(payload["loss"])
        optimizer.load_state_dict(payload["optimizer"])
        egreedy.load_state_dict(payload["egreedy"])
        _set_rng_state(payload["rng"])

    # 5. make the collector (one action per worker per batch, exploration on)
    remaining = cfg.steps - counters["steps"]
    backend = resolve_backend(cfg.collector, cfg.workers)
    summary = dict(run_dir=str(run_dir), start_step=counters["steps"],
                   collection=dict(backend=backend, workers=cfg.workers, sync=cfg.sync,
                                   worker_seeds=worker_seeds(env_seed, cfg.workers)))
    if remaining <= 0 or (cfg.episodes and counters["episodes"] >= cfg.episodes):
        env.close()
        return dict(summary, **counters, note="nothing left to train")
    model.eval()  # acting uses BatchNorm's running statistics; each SGD step switches to train mode and back
    if backend != "direct":
        env.close()
        env = None
    collector = make_collector(
        partial(make_worker_env, cfg), explore, seed=env_seed, total_frames=remaining, workers=cfg.workers,
        backend=backend, sync=cfg.sync, env=env,
    )

    # 6. make the logger (CSV files or TensorBoard events in the run folder)
    logger = make_logger(run_dir, cfg.logger)

    def checkpoint() -> None:
        replay_meta = dict(size=len(replay), capacity=cfg.replay_capacity, dir=None)
        if cfg.save_replay:
            replay_meta["dir"] = f"replay_step{counters['steps']}"
            shutil.rmtree(run_dir / replay_meta["dir"], ignore_errors=True)
            replay.dumps(run_dir / replay_meta["dir"])
        save_checkpoint(ckpt_path, cfg=cfg, model=model, loss=loss, optimizer=optimizer, egreedy=egreedy,
                        counters=counters, replay_meta=replay_meta)
        logger.flush()  # the logs reach the disk with every checkpoint
        for old in run_dir.glob("replay_step*"):
            if old.name != replay_meta["dir"]:
                shutil.rmtree(old, ignore_errors=True)

    # 7. main loop: collect one action, store it, prioritized SGD steps, refresh priorities, log, checkpoint
    tracker = OutcomeTracker(rewards, cfg.num_rotations * cfg.heightmap_size**2, cfg.success_window,
                             log_path=run_dir / "actions.csv", start_step=counters["steps"])
    last_loss = float("nan")
    t0 = time.perf_counter()
    bar = tqdm(total=cfg.steps, initial=counters["steps"], desc=f"{cfg.task} {cfg.run_name}", unit="action")
    for batch in collector:
        n = batch.numel()
        egreedy.step(n)
        replay.extend(pack_transition(to_transitions(batch.reshape(-1))))
        finished = []
        for stream, frames in streams(batch):  # per worker and episode, in time order
            nxt = frames.get("next")
            finished += tracker.add(frames.get("action"), nxt.get("reward"), nxt.get("done"), nxt.get("terminated"),
                                    stream=stream)
            counters["grasps"] += tracker.last_grasps
        counters["steps"] += n
        counters["episodes"] += len(finished)
        for episode in finished:
            logger.log_scalar("episode/success_rate", episode["success_rate"], step=counters["episodes"])
            logger.log_scalar("episode/completion", float(episode["completed"]), step=counters["episodes"])
            logger.log_scalar("episode/actions", episode["actions"], step=counters["episodes"])

        if len(replay) >= cfg.learning_starts:
            model.train()
            for _ in range(cfg.updates_per_step * n):
                sample = unpack_transition(replay.sample())
                loss_td = loss(sample)
                optimizer.zero_grad(set_to_none=True)
                loss_td[loss_key].backward()
                optimizer.step()
                if updater is not None:
                    updater.step()
                replay.update_tensordict_priority(sample)
                counters["updates"] += 1
                last_loss = loss_td[loss_key].item()
            model.eval()
        sync_weights(collector)  # the workers act with the new weights and ε

        running = tracker.grasp_success
        bar.update(n)
        bar.set_postfix(grasp=f"{running:.2f}", success=f"{tracker.success_rate:.2f}", eps=f"{egreedy.eps.item():.2f}",
                        loss=f"{last_loss:.3g}", episodes=counters["episodes"])
        step = counters["steps"]
        out_of_time = cfg.max_minutes and time.perf_counter() - t0 >= 60 * cfg.max_minutes
        done = step >= cfg.steps or (cfg.episodes and counters["episodes"] >= cfg.episodes) or out_of_time
        if crossed(step, n, cfg.log_interval) or done:
            logger.log_scalar("train/loss", last_loss, step=step)
            logger.log_scalar("train/epsilon", egreedy.eps.item(), step=step)
            logger.log_scalar("train/reward", float(batch.get(("next", "reward")).mean()), step=step)
            logger.log_scalar("train/grasp_success", running, step=step)
            logger.log_scalar("train/success_rate", tracker.success_rate, step=step)
            logger.log_scalar("train/episodes", counters["episodes"], step=step)
            logger.log_scalar("time/wall_s", time.perf_counter() - t0, step=step)
        if crossed(step, n, cfg.checkpoint_interval) or done:
            checkpoint()
        if done:
            break
    bar.close()
    tracker.close()
    logger.close()  # flushes TensorBoard's buffered events into the file
    collector.shutdown()
    if env is not None:
        env.close()

    # 8. summary (the loop wrote the final checkpoint)
    summary.update(counters, running_grasp_success=running, running_success_rate=tracker.success_rate,
                   wall_s=time.perf_counter() - t0, stopped_by_time=bool(out_of_time))
    write_json(run_dir / "train_summary.json", summary)
    return summary


__all__ = [
    "ACTION_COLUMNS", "ClutterConfig", "checkpoint_file", "export_weights", "LOSSES", "OutcomeTracker", "PRESETS", "TASKS", "load_checkpoint", "main", "make_action_mask", "make_env", "make_workspace", "make_model", "make_worker_env",
    "save_checkpoint", "to_transitions",
]
