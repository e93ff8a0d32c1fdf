"""Everything a pixelwise DQN agent is built from, built from its :class:`~maniskill_pnp.agents.pixel.config.ClutterConfig`
in one place: training, evaluation, video and the benchmarks all call these, so they cannot drift apart.

* :func:`make_workspace`: the heightmap grid (size, pixel size, rotations);
* :func:`make_env` / :func:`make_worker_env`: the task as a TorchRL env, for a scenario (:data:`SCENARIOS`);
* :func:`make_model`: one pixel Q network per primitive;
* :func:`make_action_mask`: the actions that can touch something (see :mod:`~maniskill_pnp.agents.pixel.mask`);
* :func:`make_policy`: the greedy and the ε-greedy actor over the network and the mask;
* :func:`load_policy`: the greedy actor of a saved checkpoint, rebuilt from the checkpoint's own config.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from maniskill_pnp.agents.pixel.checkpoint import load_checkpoint
from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.fcn import MultiPrimitiveQNetwork
from maniskill_pnp.agents.pixel.mask import HeightmapActionMask
from maniskill_pnp.agents.pixel.policy import GreedyPixelActor, make_pixel_policy
from maniskill_pnp.cell.workspace import DEFAULT_ROBOT_BASE, WorkspaceSpec
from maniskill_pnp.runtime import freeze_long_lived_objects

#: Scenes an agent can be run on besides a positive object count: ``"train"`` (the config's object count), a
#: density preset of the task (``"min"``, ``"medium"``, ``"max"``) or ``"complicated"`` (ClutterGraspSlide-v1's
#: hand-designed locking layouts; for ClutterGrasp-v1 its 3-7 object preset) or ``"hard"`` (the scene files of
#: :func:`~maniskill_pnp.scenes.hard_scenes.hard_layout_files`: 24 generated tightly packed scenes, at least half of
#: their objects locked, and the 8 locking layouts; episode i plays file i mod 32) or ``"hard_unseen"`` (the 48 scene
#: files of :func:`~maniskill_pnp.scenes.packed_families.unseen_scene_files`: tightly packed arrangements of families
#: that no training draws) or ``"anywhere"`` (the 24 scene files of
#: :func:`~maniskill_pnp.scenes.anywhere_scenes.anywhere_scene_files`: packed arrangements of every family anywhere in
#: the workspace, half of them within a slide's length of its edge).
SCENARIOS = ("train", "min", "medium", "max", "complicated", "hard", "hard_unseen", "anywhere")
#: The scenarios that play scene files.
FILE_SCENARIOS = ("hard", "hard_unseen", "anywhere")


def is_scenario(name: str) -> bool:
    """Whether ``name`` is a scenario: one of :data:`SCENARIOS` or a positive object count."""
    return name in SCENARIOS or (name.isdigit() and int(name) > 0)


def scenario_options(name: str, task: str) -> dict:
    """Task keyword arguments of a scenario (see :data:`SCENARIOS`)."""
    if name == "train":
        return {}
    if name.isdigit():
        return dict(num_objects=int(name))
    if name == "complicated" and task == "grasp_slide":
        return dict(layout="complicated")
    if name in FILE_SCENARIOS:
        return dict(layout_file=[str(p) for p in scenario_layout_files(name)])
    return dict(num_objects=name)


def scenario_layout_files(name: str) -> list[Path] | None:
    """The scene files a scenario plays, one per episode in turn (:data:`FILE_SCENARIOS`), else None (drawn scenes)."""
    if name == "hard":
        from maniskill_pnp.scenes.hard_scenes import hard_layout_files

        return hard_layout_files()
    if name == "hard_unseen":
        from maniskill_pnp.scenes.packed_families import unseen_scene_files

        return unseen_scene_files()
    if name == "anywhere":
        from maniskill_pnp.scenes.anywhere_scenes import anywhere_scene_files

        return anywhere_scene_files()
    return None


def make_workspace(cfg: ClutterConfig) -> WorkspaceSpec:
    """The workspace of the config: its heightmap size, pixel size, rotations and fit heightmap scale (the rest at the
    task defaults)."""
    return WorkspaceSpec(
        heightmap_size=cfg.heightmap_size, pixel_size=cfg.workspace_side / cfg.heightmap_size, num_rotations=cfg.num_rotations,
        fit_scale=cfg.mask_fit_scale,
    )


def make_env(cfg: ClutterConfig, scenario: str = "train", **task_kwargs):
    """The config's task as a TorchRL env, with its heightmap size, rotations and object count, on the CPU, set up
    for ``scenario`` (see :data:`SCENARIOS`). ``task_kwargs`` override or add task and ManiSkill options, e.g.
    ``render_mode="rgb_array"`` or ``num_envs=16, sim_backend="physx_cuda", render_backend="sapien_cuda"``.

    The first call of a process freezes the objects alive then out of the garbage collector's sweeps
    (:func:`~maniskill_pnp.runtime.freeze_long_lived_objects`), which makes every later reset about 0.3 s faster."""
    from maniskill_pnp.torchrl_env import make_torchrl_env

    options = dict(num_objects=cfg.num_objects, workspace=make_workspace(cfg), planner_seed=cfg.seed,
                   sim_backend="physx_cpu", render_backend="cpu")
    if cfg.task == "grasp_slide":
        options["reward_scheme"] = cfg.reward_scheme
    if cfg.loss_cost:
        options["loss_cost"] = cfg.loss_cost
    if scenario == "train" and not {"layout", "layout_file"} & task_kwargs.keys():  # the training clutters only
        options.update({k: getattr(cfg, k) for k in ("packed_fraction", "hard_fraction") if getattr(cfg, k)})
        if cfg.hard_fraction:
            options["hard_sets"] = tuple(cfg.hard_sets)
    if scenario == "train" and cfg.guard_force is not None:
        options["guard_force"] = cfg.guard_force
    options.update(scenario_options(scenario, cfg.task), **task_kwargs)
    env = make_torchrl_env(cfg.env_id, **options)
    freeze_long_lived_objects()
    return env


def make_worker_env(cfg: ClutterConfig, seed: int):
    """The env of one collector worker: the config's task with its planner seeded by ``seed`` (picklable with
    ``functools.partial``)."""
    return make_env(dataclasses.replace(cfg, seed=seed))


def make_model(cfg: ClutterConfig) -> MultiPrimitiveQNetwork:
    """One pixel Q network per primitive of the task: ``(N, 4, H, W) -> (N, P, R, H, W)``."""
    return MultiPrimitiveQNetwork(
        cfg.primitives, num_rotations=cfg.num_rotations, backbone=cfg.backbone, use_depth=cfg.use_depth,
        head_channels=cfg.head_channels, pretrained_path=cfg.pretrained_path,
    )


def make_action_mask(cfg: ClutterConfig, enabled: tuple[str, ...] | None = None) -> HeightmapActionMask | None:
    """The action mask of the config: with ``mask_empty``, grasps on material and slides from bare table towards
    material within half a slide, with ``mask_keep_in`` only slides that keep what they push on the heightmap, with
    ``mask_reach`` only what the arm reaches, and
    with ``mask_grasp_fit`` only grasps the open gripper fits; only the ``enabled``
    primitives (e.g. ``("grasp",)`` for a G&S agent restricted to grasps); None when neither applies."""
    if not cfg.mask_empty and enabled is None:
        return None
    return HeightmapActionMask.for_workspace(
        cfg.primitives, make_workspace(cfg), min_height=cfg.mask_min_height if cfg.mask_empty else None, enabled=enabled,
        grasp_fit=cfg.mask_grasp_fit,  # the config allows it only with mask_empty
        keep_in=cfg.mask_keep_in and cfg.mask_empty and cfg.task == "grasp_slide",
        reach=reach_pixels(cfg) if cfg.mask_reach and cfg.mask_empty else None,
    )


def reach_pixels(cfg: ClutterConfig) -> torch.Tensor | None:
    """``bool (R, H, W)``: the rotations and pixels of the config's heightmap that the clutter cell's arm reaches; None
    where no reach table of its table height is at hand."""
    from maniskill_pnp.cell.reach_map import ReachMap

    reach = ReachMap.of(make_workspace(cfg), DEFAULT_ROBOT_BASE)
    return None if reach is None else torch.from_numpy(reach.pixels())


def make_policy(cfg: ClutterConfig, model: MultiPrimitiveQNetwork, action_spec, eps: float | None = None):
    """``(greedy, explore, egreedy)`` of :func:`~maniskill_pnp.agents.pixel.policy.make_pixel_policy` over ``model``,
    under the config's action mask and explore weights; ε follows the config's schedule, or stays at ``eps``."""
    schedule = (dict(eps_init=cfg.eps_start, eps_end=cfg.eps_end, annealing_num_steps=cfg.eps_decay_steps) if eps is None
                else dict(eps_init=eps, eps_end=eps, annealing_num_steps=1))
    return make_pixel_policy(model, action_spec, action_mask=make_action_mask(cfg), explore_weights=cfg.explore_weights or None,
                             primitive_margins=cfg.primitive_margins(), fit_heightmap=cfg.mask_fit_scale > 1, **schedule)


def load_policy(path: Path, device: torch.device, grasp_only: bool = False, slide_margin: float | None = None,
                mask_grasp_fit: bool | None = None, mask_fit_scale: int | None = None, mask_keep_in: bool | None = None,
                mask_reach: bool | None = None) -> tuple[GreedyPixelActor, ClutterConfig, dict]:
    """The greedy actor of a checkpoint (network in eval mode on ``device``, the training's action mask, and with
    ``grasp_only`` only the grasp primitive enabled; ``slide_margin`` replaces the run's own, see
    :attr:`ClutterConfig.slide_margin`, ``mask_grasp_fit`` the run's :attr:`ClutterConfig.mask_grasp_fit` and
    ``mask_fit_scale`` its :attr:`ClutterConfig.mask_fit_scale`, ``mask_keep_in`` and ``mask_reach`` the run's
    :attr:`ClutterConfig.mask_keep_in` and :attr:`ClutterConfig.mask_reach`), its config (the training's, with those mask fields
    as the actor uses them: make its env from it) and counters.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: ``path`` is not a readable clutter DQN checkpoint, or its weights do not fit its config.
    """
    payload = load_checkpoint(path)
    try:
        train_cfg = ClutterConfig.from_json(payload["config"])
        state = payload["model"]
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"checkpoint {path} has no usable config or model: {e}") from e
    # The checkpoint's weights replace any initialisation: do not read a pretrained file that may be gone by now.
    train_cfg = dataclasses.replace(train_cfg, pretrained_path=None)
    model = make_model(train_cfg)
    try:
        model.load_state_dict(state)
    except RuntimeError as e:
        raise ValueError(f"checkpoint {path}: the weights do not fit the network of its config: {e}") from e
    model.to(device).eval()
    acting = {k: v for k, v in dict(mask_grasp_fit=mask_grasp_fit, mask_fit_scale=mask_fit_scale,
                                    mask_keep_in=mask_keep_in, mask_reach=mask_reach).items() if v is not None}
    if acting.get("mask_grasp_fit") is False:
        acting.setdefault("mask_fit_scale", 1)
    train_cfg = dataclasses.replace(train_cfg, **acting)  # raises ValueError on a scale without the fit test
    mask = make_action_mask(train_cfg, enabled=("grasp",) if grasp_only else None)
    if slide_margin is not None and train_cfg.task != "grasp_slide":
        raise ValueError(f"checkpoint {path} is a grasp-only agent ({train_cfg.env_id}): a slide margin needs a G&S agent")
    margins = train_cfg.primitive_margins(slide_margin)
    return GreedyPixelActor(model, mask, margins), train_cfg, dict(payload.get("counters", {}))


__all__ = [
    "SCENARIOS", "is_scenario", "load_policy", "make_action_mask", "make_env", "make_model", "make_policy",
    "make_worker_env", "make_workspace", "scenario_options",
]
