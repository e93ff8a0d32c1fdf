"""ClutterGrasp-v1: grasp objects out of a loosely packed clutter, one pixelwise grasp per step (thesis part II).

One step is a whole grasp: the action picks a pixel of the current heightmap and one of the rotations; the arm
grasps at that pixel's 3-D point with that yaw (:meth:`WorkspaceSpec.grasp_tcp_height` says how high), places
a grasped object in the bin, and returns to a home pose out of the cameras' view; then both cameras are
rendered and fused into the next heightmaps.

Objects: a pool of procedural objects (:class:`~maniskill_pnp.scenes.clutter_pool.ClutterPool`) is built once,
with a fixed library seed; each episode draws ``num_objects`` of them, drops them into the workspace and lets them
settle. ``objects="ycb"`` (ManiSkill's YCB models that fit the gripper, :mod:`~maniskill_pnp.scenes.ycb`) or
``objects=[...]`` (YCB model ids and/or :class:`~maniskill_pnp.scenes.objects.ObjectSpec`, e.g. mesh files) fill the
pool from those instead. Pool objects not in the episode wait on the floor far from the robot and the cameras. With ``layout=`` the
pool is exactly the layout's objects, placed at its poses every episode; ``layout_file=`` reads such layouts from
scene files (:mod:`~maniskill_pnp.scenes.scene_file`), and :meth:`ClutterGraspEnv.export_scene` writes the current
scene as one.

Batched: with ManiSkill's GPU simulation (``num_envs > 1``) every sub-scene draws its own clutter from the same
pool, each env's action is decoded into a primitive program of its own arm (:class:`MotionPrimitives` with
``env_idx``), and the step pipeline of :class:`~maniskill_pnp.tasks.primitive_env.PrimitiveStepEnv` executes all
programs in shared control steps (an env whose program is done holds still). The heightmaps of all envs are
computed together. On the CPU (``num_envs = 1``) the same code runs with one env. ``info`` holds ``(num_envs,)``
tensors for numbers (also for one env; the outcome keys of
:data:`~maniskill_pnp.tasks.primitive_env.OUTCOME_KEYS` among them), and text as it is for one env, listed per env
for several.

Tasks with more primitives (``ClutterGraspSlide-v1``) declare them in :attr:`ClutterGraspEnv.PRIMITIVES` and
:attr:`ClutterGraspEnv.primitive_programs`, judge them in :meth:`ClutterGraspEnv._judge`, and may offer several
layouts (:meth:`ClutterGraspEnv._resolve_layouts`).
"""

from __future__ import annotations

import math

from contextlib import contextmanager
import logging
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import sapien
import torch
from gymnasium import spaces

from mani_skill.agents.robots import Panda
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import common, sapien_utils
from mani_skill.utils.scene_builder.table import TableSceneBuilder

from maniskill_pnp.planning.lockstep import LockstepExecutor, Motion, Program
from maniskill_pnp.planning.primitives import MotionPrimitives, check_guard_force, grasp_pose
from maniskill_pnp.planning.robot import panda_spec
from maniskill_pnp.cell.bin import build_bin
from maniskill_pnp.scenes.clutter import density_range, validate_layout
from maniskill_pnp.scenes.rolling import LEVER_ARM, RollingResistance
from maniskill_pnp.scenes.clutter_pool import ClutterPool, SettleSpec
from maniskill_pnp.cell.heightmap import heightmaps_from_sensors
from maniskill_pnp.scenes.objects import KINDS, ObjectSpec
from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.tasks.primitive_env import Decision, Judgement, PrimitiveStepEnv
from maniskill_pnp.tasks.registration import register_task
from maniskill_pnp.tasks.render_boxes import RenderBoxes
from maniskill_pnp.scenes.scene_file import load_scene, save_scene
from maniskill_pnp.cell.view_volume import ViewVolumes
from maniskill_pnp.cell.workspace import DEFAULT_ROBOT_BASE, WorkspaceSpec

ROBOT_BASE = DEFAULT_ROBOT_BASE
logger = logging.getLogger(__name__)

#: Why an action lost an object (it left the workspace other than into the bin): the ``info`` key that counts the
#: step's objects lost that way, and its meaning. The four add up to ``info["knocked_out"]``. An object that comes back
#: into the workspace (pushed or bounced back) and leaves again is counted at each leaving.
LOSS_CAUSES = {
    "lost_by_slide": "pushed out of the workspace or off the table by a slide",
    "lost_by_grasp": "an object other than the grasped one, rolled or pushed off during a grasp (the descent, the lift, "
                     "the carry or the way home), whether the grasp succeeded or not",
    "lost_in_transit": "the grasped object, dropped before the gripper opened over the bin (the grasp sensor felt "
                       "nothing in the jaws there)",
    "lost_at_release": "the grasped object, lost once the gripper opened: thrown or bounced out of the bin, or let go "
                       "beside it after a carry that did not reach it",
}


def loss_causes(before: list[str], after: list[str], names: list[str], primitive: str, held: str | None = None,
                held_at_release: bool | None = None) -> dict[str, int]:
    """How many objects one action lost, by cause (:data:`LOSS_CAUSES`).

    Args:
        before, after: Each object's status (``"workspace"``, ``"bin"``, ``"lost"``) before and after the action.
        names: The objects' names, in the same order.
        primitive: The action's primitive; any other than ``"grasp"`` is a slide.
        held: The object the grasp lifted (None: it lifted none).
        held_at_release: Whether the grasp sensor still felt ``held`` when the gripper opened.
    """
    counts = dict.fromkeys(LOSS_CAUSES, 0)
    for name, was, now in zip(names, before, after, strict=True):
        if now != "lost" or was == "lost":
            continue
        if primitive != "grasp":
            counts["lost_by_slide"] += 1
        elif name != held:
            counts["lost_by_grasp"] += 1
        else:
            counts["lost_in_transit" if held_at_release is False else "lost_at_release"] += 1
    return counts


def check_loss_cost(loss_cost) -> float:
    """``loss_cost`` (reward taken off per object an action loses) as a float.

    Raises:
        ValueError: not a finite number >= 0.
    """
    if isinstance(loss_cost, bool) or not isinstance(loss_cost, (int, float)) or not 0.0 <= loss_cost < math.inf:  # NaN fails
        raise ValueError(f"loss_cost must be a finite number >= 0 (reward taken off per object lost), got {loss_cost!r}")
    return float(loss_cost)


def resolve_objects(objects) -> tuple[ObjectSpec, ...]:
    """The objects of ``objects=``: ``"ycb"`` (every YCB model that fits the gripper; the others are logged and left
    out) or a non-empty list of YCB model ids (each must fit) and ObjectSpecs.

    Raises:
        ValueError: another value, an unknown or unfit YCB model, or no object at all.
        FileNotFoundError: YCB models asked for without ManiSkill's YCB assets (the message gives the download command).
    """
    from maniskill_pnp.scenes.ycb import YCB_SOURCE, ycb_spec, ycb_specs

    if isinstance(objects, str):
        if objects != YCB_SOURCE:
            raise ValueError(f"objects must be {YCB_SOURCE!r} or a list of YCB model ids and ObjectSpecs, got {objects!r}")
        specs, skipped = ycb_specs()
        for model_id, reason in skipped.items():
            logger.info("objects='ycb': %s left out: %s", model_id, reason)
        if not specs:
            raise ValueError(f"objects='ycb': no YCB model fits the gripper ({len(skipped)} left out)")
        return tuple(specs)
    if not isinstance(objects, (list, tuple)) or not objects:
        raise ValueError(f"objects must be {YCB_SOURCE!r} or a non-empty list of YCB model ids and ObjectSpecs, got {objects!r}")
    out = []
    for k, item in enumerate(objects):
        if isinstance(item, ObjectSpec):
            out.append(item)
        elif isinstance(item, str):
            out.append(ycb_spec(item))
        else:
            raise ValueError(f"objects[{k}] must be a YCB model id or an ObjectSpec, got {item!r}")
    return tuple(out)


def camera_clear_home() -> np.ndarray:
    """The Panda's rest configuration turned 90° about its base axis: the arm beside the workspace, out of view."""
    q = panda_spec().home.copy()
    q[0] = -np.pi / 2
    return q


@register_task("ClutterGrasp-v1", max_episode_steps=None)
class ClutterGraspEnv(PrimitiveStepEnv):
    """**Task Description:**
    A loosely packed clutter of regular and irregular objects lies in the workspace in front of the Panda; a bin
    stands beside it. Each step the agent picks one flat index over (rotation, row, col) of the 224×224
    heightmap; the arm grasps top-down at that pixel's 3-D point with the rotation's yaw, puts a grasped object
    into the bin and goes back out of the cameras' view. Observation: ``color_heightmap`` (uint8 H×W×3) and
    ``depth_heightmap`` (float32 H×W, metres above the table), fused from a top-down narrow-FOV camera and a
    perspective camera (plus raw camera data with ``include_camera_data=True``, and ``fit_heightmap``, the heights on
    a k-times finer grid, with the workspace's ``fit_scale`` k > 1).
    Reward: 1 placed in the bin, 0.5 grasped but not placed, 0 otherwise; with ``loss_cost=c``, c less per object the
    action lost off the workspace (``info["knocked_out"]``, whatever moved it).

    **Randomizations:**
    - which pool objects form the clutter and how many (``num_objects``: an int, a (min, max) range, or a
      density preset name of :data:`~maniskill_pnp.scenes.clutter.DENSITY_PRESETS`)
    - their xy positions and yaws (loosely packed: footprints ``min_gap`` apart) or full poses (any packing),
      then a physics settle; with ``packed_fraction`` that share of episodes packs them upright into tight clusters
      a few millimetres apart instead (``clutter.packed`` says which envs got one)
    - or an explicit layout (``layout=``), or one of the scene files of ``layout_file=`` per episode (a seeded
      draw unless ``reset(options={"layout_index": k})`` picks one)

    **Success Conditions:**
    - the workspace is clear (episode terminates); it is truncated after ``max_consecutive_failures`` failed
      grasps in a row or ``max_actions`` actions. Objects that leave the workspace other than into the bin are
      counted in ``info["lost_objects"]``. Objects that came to rest in the bin are taken out of it after each
      step (they keep counting as in the bin), so every place drops into an empty bin.
    """

    SUPPORTED_ROBOTS = ["panda"]
    BATCHED = True
    agent: Panda
    #: Seed of the object library (the pool's shapes, sizes and colours).
    LIBRARY_SEED = 1234
    #: Pool size when drawing random clutters (at least the largest object count).
    POOL_SIZE = 20
    #: Control steps the gripper is held open after a place that did not land in the bin, before checking again.
    RELEASE_STEPS = 20
    PRIMITIVES = ("grasp",)
    #: Speed (m/s) above which an object counts as blown up by the physics (nothing in the task moves this fast).
    MAX_OBJECT_SPEED = 5.0
    #: Contact force (N) between an object and the gripper at home above which the object rests on the gripper.
    GRIPPER_CONTACT_FORCE = 1e-3
    #: The settle after dropping the clutter.
    SETTLE = SettleSpec()
    #: Times the objects of a random clutter that settled outside the workspace are dropped again (and settle).
    REDROP_ROUNDS = 5

    def __init__(
        self,
        *args,
        robot_uids="panda",
        workspace: WorkspaceSpec | None = None,
        num_objects: int | tuple[int, int] | str = (10, 15),
        object_kinds: tuple[str, ...] = KINDS,
        loosely_packed: bool = True,
        min_gap: float = 0.01,
        packed_fraction: float = 0.0,
        hard_fraction: float = 0.0,
        hard_sets: tuple[str, ...] = ("hard_train",),
        layout=None,
        layout_file=None,
        objects=None,
        max_consecutive_failures: int = 10,
        max_actions: int | None = None,
        include_camera_data: bool = False,
        planner_seed: int = 0,
        guard_force: float | None = None,
        loss_cost: float = 0.0,
        rolling_lever_arm: float = LEVER_ARM,
        **kwargs,
    ):
        """Args beyond ManiSkill's: ``workspace`` (geometry, cameras, bin), ``num_objects``, ``object_kinds``,
        ``loosely_packed`` and ``min_gap`` (clutter), ``packed_fraction`` (share of random clutters packed into tight
        clusters instead, see :func:`~maniskill_pnp.scenes.clutter.sample_packed`), ``hard_fraction`` (share of random
        clutters replaced by one of the hard *training* arrangements of
        :func:`~maniskill_pnp.scenes.hard_scenes.hard_train_files`, at a random yaw; never the test set's),
        ``hard_sets`` (the training arrangement sets it draws from, names of
        :data:`~maniskill_pnp.scenes.packed_families.TRAINING_SETS`: ``"hard_train"``, ``"packed_train"``),
        ``layout`` (explicit list of (ObjectSpec, pose); overrides the
        random clutter), ``layout_file`` (a scene file, or a list of them: one layout each, episodes draw among them;
        not with ``layout``), ``objects`` (what random clutters are made of instead of procedural ``object_kinds``:
        ``"ycb"`` for every YCB model of ManiSkill's assets that fits the gripper, or a list of YCB model ids and/or
        ObjectSpecs; not with ``layout``, ``layout_file`` or ``object_kinds``), ``max_consecutive_failures`` and
        ``max_actions`` (truncation; default 3 × the largest object count), ``include_camera_data`` (raw RGB-D and
        camera parameters in the observation), the motion planner's seed, and ``guard_force`` (N: grasp descents and
        slide lowerings stop, and fail, when contacts push the gripper up by more than this, see
        :class:`~maniskill_pnp.planning.primitives.MotionPrimitives`; None: unguarded), and ``loss_cost`` (what each
        object an action loses off the workspace, by any cause, takes off its reward; 0: losses cost nothing beyond
        the reward they forgo), and ``rolling_lever_arm`` (m: the lever arm of the rolling friction of spheres on the
        table, which PhysX leaves out, see :mod:`~maniskill_pnp.scenes.rolling`; 0: none, as PhysX alone; the CPU
        simulation only)."""
        guard_force = check_guard_force(guard_force)  # here: the primitives are only built at the first step
        loss_cost = check_loss_cost(loss_cost)
        self.workspace = workspace or WorkspaceSpec()
        if isinstance(num_objects, str):
            num_objects = density_range(num_objects)
        lo, hi = (num_objects, num_objects) if isinstance(num_objects, (int, np.integer)) else tuple(num_objects)
        if not (isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer)) and 1 <= lo <= hi):
            raise ValueError(f"num_objects must be a positive int or a (min, max) range with 1 <= min <= max, got {num_objects!r}")
        kinds = (object_kinds,) if isinstance(object_kinds, str) else tuple(object_kinds)
        if not kinds or any(k not in KINDS for k in kinds):
            raise ValueError(f"object_kinds must be a non-empty subset of {list(KINDS)}, got {object_kinds!r}")
        library = None
        if objects is not None:
            if layout is not None or layout_file is not None:
                raise ValueError("objects= chooses what random clutters are made of: not with layout= or layout_file=, "
                                 "whose objects are their own")
            if kinds != KINDS:
                raise ValueError("give object_kinds= (procedural kinds) or objects= (YCB models, ObjectSpecs), not both")
            library = resolve_objects(objects)
        if not min_gap >= 0:
            raise ValueError(f"min_gap must be >= 0, got {min_gap!r}")
        if not 0.0 <= packed_fraction <= 1.0:
            raise ValueError(f"packed_fraction must be in [0, 1], got {packed_fraction!r}")
        if packed_fraction and (layout is not None or layout_file is not None):
            raise ValueError("packed_fraction packs random clutters: not with layout= or layout_file=")
        if not 0.0 <= hard_fraction <= 1.0:
            raise ValueError(f"hard_fraction must be in [0, 1], got {hard_fraction!r}")
        if hard_fraction and (layout is not None or layout_file is not None):
            raise ValueError("hard_fraction replaces random clutters: not with layout= or layout_file=")
        if not (isinstance(max_consecutive_failures, int) and max_consecutive_failures >= 1):
            raise ValueError(f"max_consecutive_failures must be a positive int, got {max_consecutive_failures!r}")
        kwargs.setdefault("obs_mode", "rgb+depth")
        if kwargs["obs_mode"] != "rgb+depth":
            raise ValueError(f"ClutterGrasp-v1 observes RGB-D heightmaps: obs_mode must be 'rgb+depth', got {kwargs['obs_mode']!r}")
        #: The scene files the layouts were read from (empty without ``layout_file``).
        self.layout_files: tuple[Path, ...] = ()
        layouts = self._resolve_layouts(layout) if layout_file is None else self._load_layout_files(layout_file, layout)
        num_objects_range = (int(lo), int(hi)) if layouts is None else (min(map(len, layouts)), max(map(len, layouts)))
        n = int(kwargs.get("num_envs", 1))  # ManiSkill's __init__ resets the envs, so the per-env state comes first
        # PhysX carries contact and broad-phase state from one episode into the next, so the same drop settles into
        # another scene after other episodes; a new PhysX scene per episode makes reset(seed) depend on the seed alone.
        # GPU-batched envs reset one env at a time, which ManiSkill cannot combine with a reconfiguration.
        kwargs.setdefault("reconfiguration_freq", 1 if n == 1 else 0)
        #: The objects: the pool of actors and each env's episode objects.
        self.clutter = ClutterPool(self.workspace, n, layouts, num_objects_range, kinds, bool(loosely_packed), float(min_gap),
                                   packed_fraction=float(packed_fraction), size=self.POOL_SIZE, library_seed=self.LIBRARY_SEED, settle=self.SETTLE,
                                   max_speed=self.MAX_OBJECT_SPEED, library=library,
                                   arrangements=self._hard_training_layouts(tuple(hard_sets)) if hard_fraction else None,
                                   arrangement_fraction=float(hard_fraction))
        self.max_consecutive_failures = max_consecutive_failures
        self.max_actions = int(max_actions) if max_actions is not None else 3 * num_objects_range[1]
        self.include_camera_data = include_camera_data
        self.planner_seed = planner_seed
        self.guard_force = guard_force
        self.loss_cost = loss_cost
        if isinstance(rolling_lever_arm, bool) or not isinstance(rolling_lever_arm, (int, float)):
            raise ValueError(f"rolling_lever_arm must be a length in m (0: no rolling friction), got {rolling_lever_arm!r}")
        self.rolling = RollingResistance(self.workspace.table_z, float(rolling_lever_arm))
        self._rolling_bodies: list = []  # (PhysX body, radius) of every pool sphere, CPU simulation only
        s = self.workspace.heightmap_size
        self.action_layout = PixelActionLayout(len(self.PRIMITIVES), self.workspace.num_rotations, s, s)
        self.home_qpos = camera_clear_home()
        self._view_volumes = ViewVolumes(self.workspace)
        self._render_boxes_of, self._render_boxes = None, None  # the sub-scene they were found in, and its boxes
        self.prims: list[MotionPrimitives] | None = None
        self.settle_steps = np.zeros(n, dtype=np.int64)
        self.num_actions = np.zeros(n, dtype=np.int64)
        self.consecutive_failures = np.zeros(n, dtype=np.int64)
        self.num_grasps = np.zeros(n, dtype=np.int64)
        super().__init__(*args, robot_uids=robot_uids, **kwargs)
        self._use_discrete_actions(self.action_layout.size)

    @property
    def layouts(self) -> list | None:
        """The explicit layouts (lists of ``(ObjectSpec, pose)``) episodes are drawn from, or None (random clutter)."""
        return self.clutter.layouts

    @property
    def num_objects_range(self) -> tuple[int, int]:
        """(min, max) objects of an episode."""
        return self.clutter.num_objects

    @property
    def primitive_programs(self):
        return {"grasp": self._grasp_program}

    # ------------------------------------------------------------------ spaces
    @property
    def single_observation_space(self):
        return self._observation_space(())

    @property
    def observation_space(self):
        return self._observation_space((self.num_envs,))

    def _observation_space(self, batch: tuple[int, ...]) -> spaces.Dict:
        ws = self.workspace
        s, top = ws.heightmap_size, ws.max_height
        boxes = dict(color_heightmap=spaces.Box(0, 255, (*batch, s, s, 3), np.uint8),
                     depth_heightmap=spaces.Box(0.0, top, (*batch, s, s), np.float32))
        if ws.fit_scale > 1:
            f = ws.fit_grid.heightmap_size
            boxes["fit_heightmap"] = spaces.Box(0.0, top, (*batch, f, f), np.float32)
        return spaces.Dict(boxes)

    # ------------------------------------------------------------------ scene
    @property
    def _default_sensor_configs(self):
        return [
            CameraConfig(c.name, sapien_utils.look_at(c.eye, c.target, c.up), c.width, c.height, c.fov, c.near, c.far)
            for c in self.workspace.cameras
        ]

    @property
    def _default_human_render_camera_configs(self):
        cx, cy = self.workspace.center
        pose = sapien_utils.look_at(eye=[cx + 0.6, cy - 0.6, 0.7], target=[cx - 0.05, cy + 0.1, 0.0])
        return CameraConfig("render_camera", pose, 512, 512, 1, 0.01, 100)

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=list(ROBOT_BASE)))

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=0.0)
        self.table_scene.build()
        self.bin = build_bin(self.scene, self.workspace.bin)
        self.clutter.build(self.scene)
        self.prims = None  # a new scene (reconfiguration) needs new primitives
        self._rolling_bodies = [] if self.gpu_sim_enabled or not self.rolling.lever_arm else [
            (body, spec.size[0]) for spec, actor in zip(self.clutter.specs, self.clutter.actors) if spec.kind == "sphere"
            for body in actor._bodies
        ]

    def _before_simulation_step(self):
        self.rolling.apply(self._rolling_bodies, 1.0 / self.sim_freq)

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        envs = [int(e) for e in torch.as_tensor(env_idx).reshape(-1).tolist()]
        self.table_scene.initialize(env_idx)
        qpos = torch.as_tensor(np.concatenate([self.home_qpos, [0.04, 0.04]]), dtype=torch.float32, device=self.device)
        self.agent.robot.set_qpos(qpos.expand(len(envs), -1))
        self.agent.controller.reset()  # controller targets of the reset envs follow the home pose set above
        rngs = [np.random.default_rng(int(self._batched_episode_rng[e].randint(2**31))) for e in envs]
        self.clutter.draw(envs, rngs, lambda rng: self._choose_layout(rng, options), self.device)
        for e in envs:
            self.num_actions[e] = self.consecutive_failures[e] = self.num_grasps[e] = 0
            self.last[e] = self._initial_last()
        prims = self._primitives()
        for e in envs:
            prims[e].reset()
        lockstep = self._lockstep
        steps0 = lockstep.control_steps
        settling = list(envs)
        with self._all_envs_live():  # the other envs' arms hold while the reset ones settle
            for round_ in range(1 + self.REDROP_ROUNDS):
                lockstep.run([self.clutter.settle_motion(e, self.home_qpos) if e in settling else None for e in range(self.num_envs)])
                if round_ == self.REDROP_ROUNDS:
                    break
                # objects of a dense drop that rolled off the workspace fall again, so the scene starts with all it drew
                counts = self.clutter.redrop(envs, rngs, self.device)
                settling = [e for e, n in zip(envs, counts) if n]
                if not settling:
                    break
        self.settle_steps[envs] = lockstep.control_steps - steps0
        self._episode_ready = True

    def _initial_last(self) -> dict:
        """The ``last`` entry of an env before its first action."""
        return dict(super()._initial_last(), stage="reset", reason="", **dict.fromkeys(LOSS_CAUSES, 0))

    def _primitives(self) -> list[MotionPrimitives]:
        """Each env's motion primitives, all driving one shared :class:`LockstepExecutor`."""
        if self.prims is None:
            arm = replace(panda_spec(), home=self.home_qpos.copy())
            lockstep = LockstepExecutor(self, arm, on_control_step=self._on_control_step)
            self.prims = [
                MotionPrimitives(self, arm=arm, static_actors={"table-workspace", "ground", "bin"}, seed=self.planner_seed + e,
                                 lockstep=lockstep, env_idx=e, guard_force=self.guard_force)
                for e in range(self.num_envs)
            ]
        return self.prims

    @property
    def _lockstep(self) -> LockstepExecutor:
        return self._primitives()[0].executor.lockstep

    # ------------------------------------------------------------------ step hooks
    def _action_description(self) -> str:
        n = self.action_layout.size
        if len(self.PRIMITIVES) > 1:
            grid = f"(primitive, rotation, row, col) = {self.action_layout.shape}, primitives {self.PRIMITIVES}"
        else:
            grid = f"(rotation, row, col) = {self.action_layout.shape[1:]}"
        return f"one integer flat index in 0..{n - 1} over {grid}"

    def _decode(self, env: int, index: int) -> Decision:
        primitive, rot, row, col = (int(v) for v in self.action_layout.decode(index))
        return Decision(index, self.PRIMITIVES[primitive], (rot, row, col))

    def _snapshot(self, env: int) -> dict:
        return dict(height=self._height[env], status=self.clutter.status(env))

    def _object_moves(self, env: int, before: dict, primitive: str, result: dict) -> dict:
        """The objects env ``env``'s action put into the bin (``placed_objects``) and out of the workspace other than
        into the bin (``knocked_out``, and by cause: :data:`LOSS_CAUSES`), from the statuses ``before`` it
        (:meth:`_snapshot`) and the primitive's ``result`` (which object a grasp held, and whether it still did when
        the gripper opened)."""
        status = self.clutter.status(env)
        causes = loss_causes(before["status"], status, self.clutter.active[env], primitive, result.get("held"),
                             result.get("held_at_release"))
        return dict(placed_objects=max(0, status.count("bin") - before["status"].count("bin")),
                    knocked_out=sum(causes.values()), **causes)

    def _step_program(self, env: int, decision: Decision) -> Program:
        """Env ``env``'s whole step as one program: the decoded primitive, then the way home (planned a second time
        if the first plan fails, before leaving the arm in the cameras' view)."""
        prims = self.prims[env]
        outcome = yield from super()._step_program(env, decision)
        home = yield from prims.program("go_home")
        if not home.ok:  # RRT is randomized: one more plan
            outcome["planning_time"] += home.planning_time
            home = yield from prims.program("go_home")
        outcome["planning_time"] += home.planning_time
        return dict(outcome, home_ok=bool(home.ok), pixel=decision.args)

    def _after_programs(self) -> None:
        with self._all_envs_live():
            self.clutter.empty_bin(range(self.num_envs), self.device)

    def _judge(self, env: int, decision: Decision, result: dict, before: dict) -> Judgement:
        """The primitive's judgement (:meth:`_judge_action`), less ``loss_cost`` per object the action lost."""
        judged = self._judge_action(env, decision, result, before)
        lost = int(judged.outcome["knocked_out"])
        if not (self.loss_cost and lost):
            return judged
        return Judgement(judged.reward - self.loss_cost * lost, judged.success, judged.outcome)

    def _judge_action(self, env: int, decision: Decision, result: dict, before: dict) -> Judgement:
        """A grasp's reward: ``place`` when its object reached the bin, ``grasp`` when it was only grasped."""
        grasped, placed = result["grasp_success"], result["place_success"]
        r = self.rewards
        moves = self._object_moves(env, before, decision.primitive, result)
        outcome = dict({k: v for k, v in result.items() if k not in ("held", "held_at_release")}, **moves)
        return Judgement(r["place"] if placed else r["grasp"] if grasped else 0.0, bool(grasped), outcome)

    def _record(self, env: int, decision: Decision, judged: Judgement) -> None:
        self.num_actions[env] += 1
        self.num_grasps[env] += int(judged.outcome.get("grasp_success", False))
        self.consecutive_failures[env] = 0 if judged.success else self.consecutive_failures[env] + 1

    def _episode_end(self, faults: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        remaining = np.array([self.clutter.status(e).count("workspace") for e in range(self.num_envs)])
        terminated = remaining == 0
        truncated = ~terminated & ((self.consecutive_failures >= self.max_consecutive_failures)
                                   | (self.num_actions >= self.max_actions) | faults)
        return terminated, truncated

    @property
    def rewards(self) -> dict[str, float]:
        """Reward per outcome: ``place`` (the object landed in the bin), ``grasp`` (grasped but not placed)."""
        return {"place": 1.0, "grasp": 0.5}

    # ------------------------------------------------------------------ primitive programs
    def _grasp_program(self, env: int, rot: int, row: int, col: int) -> Program:
        """Program: grasp top-down at pixel ``(row, col)`` of env ``env`` with rotation ``rot``; place a grasped
        object in the bin."""
        prims = self.prims[env]
        surface = float(self._height[env][row, col])
        xyz = self.workspace.pixel_to_world(row, col, 0.0)
        xyz[2] = self.workspace.grasp_tcp_height(surface)
        yaw = float(self.workspace.rotation_to_yaw(rot))
        pick = yield from prims.program("pick", grasp_pose(xyz, yaw), target=None, candidates=self.clutter.in_workspace(env))
        placed, place_stage, place_reason, planning_time = False, "", "", pick.planning_time
        held_at_release = None
        if pick.grasped:
            place = yield from prims.program("place", self.workspace.bin.region())
            placed, place_stage, place_reason = place.placed, place.stage, place.reason
            planning_time += place.planning_time
            held_at_release = place.held_at_release
            if not placed:
                # Carrying failed (object still held) or it had not come to rest yet: open wide, wait, look again.
                if held_at_release is None:  # the place never opened the gripper: feel the jaws before this does
                    held_at_release = prims.jaws_on_something()
                yield Motion(gripper=1.0, min_steps=self.RELEASE_STEPS, settle_tol=None)
                prims.held = None
                placed = self.clutter.status(env)[self.clutter.active[env].index(pick.held)] == "bin"
        return dict(
            grasp_success=bool(pick.grasped), place_success=bool(placed), stage=pick.stage, reason=pick.reason,
            place_stage=place_stage, place_reason=place_reason, grasp_position=[float(v) for v in xyz], grasp_yaw=yaw,
            planning_time=planning_time, held=pick.held if pick.grasped else None, held_at_release=held_at_release,
        )

    # ------------------------------------------------------------------ layouts
    def _resolve_layouts(self, layout) -> list[list[tuple[ObjectSpec, sapien.Pose]]] | None:
        """The episode layouts of the ``layout`` option, validated: None (random clutter) or a list of layouts.

        ClutterGrasp-v1 takes one explicit layout (a list of ``(ObjectSpec, pose)``); subclasses may offer more.
        """
        return None if layout is None else [validate_layout(layout, self.workspace)]

    def _hard_training_layouts(self, sets: tuple[str, ...]) -> list[list[tuple[ObjectSpec, sapien.Pose]]]:
        """The training arrangements of the sets ``sets`` (``hard_fraction``), in this task's workspace."""
        from maniskill_pnp.scenes.packed_families import training_arrangement_files

        return [load_scene(f, self.workspace) for f in training_arrangement_files(sets)]

    def _load_layout_files(self, layout_file, layout) -> list[list[tuple[ObjectSpec, sapien.Pose]]]:
        """The layouts of the scene file(s) ``layout_file`` (one path or a list of them), validated.

        Raises:
            ValueError: ``layout`` given as well, no file, or a file that does not load (the message names it).
            FileNotFoundError: a file does not exist.
        """
        if layout is not None:
            raise ValueError("layout= and layout_file= are mutually exclusive: give the layout as a list or as scene files, not both")
        many = not isinstance(layout_file, (str, os.PathLike)) and hasattr(layout_file, "__iter__")
        files = list(layout_file) if many else [layout_file]
        if not files or not all(isinstance(f, (str, os.PathLike)) for f in files):
            raise ValueError(f"layout_file must be a scene file path or a non-empty list of them, got {layout_file!r}")
        self.layout_files = tuple(Path(f) for f in files)
        return [load_scene(f, self.workspace) for f in self.layout_files]

    def export_scene(self, path, env_idx: int = 0, *, frame: str = "workspace", name: str | None = None,
                     description: str | None = None, orientation: str = "quaternion") -> Path:
        """Write env ``env_idx``'s objects still in the workspace, at their current poses, as the scene file ``path``
        (YAML or JSON by its extension; :func:`~maniskill_pnp.scenes.scene_file.save_scene`), to replay it with
        ``layout_file=``. Objects in the bin or lost are left out. The layout is validated by its shapes as any other
        (:func:`~maniskill_pnp.scenes.clutter.validate_layout`: objects at rest pass it); call it between steps or
        after a reset, when the objects are at rest.

        Raises:
            ValueError: no object left in the workspace, a layout that does not validate (e.g. two objects pressed
                more than 1 mm into each other), or a bad env index, frame, orientation or extension.
        """
        layout = self.clutter.workspace_layout(int(env_idx))
        if not layout:
            raise ValueError(f"env {env_idx} has no object left in the workspace: no scene to export")
        return save_scene(path, layout, self.workspace, frame=frame, name=name, description=description,
                          orientation=orientation)

    def _choose_layout(self, rng: np.random.Generator, options: dict) -> int:
        """This episode's layout: ``reset(options={"layout_index": k})`` when given, else a seeded draw.

        Raises:
            ValueError: ``layout_index`` is not an index of :attr:`layouts`.
        """
        n = len(self.layouts)
        k = options.get("layout_index")
        if k is None:
            return int(rng.integers(n)) if n > 1 else 0
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < n:
            raise ValueError(f"layout_index must be an int in 0..{n - 1}, got {k!r}")
        return int(k)

    def detect_faults(self) -> list[str]:
        """Per env, why its episode cannot go on ("" when it can), checked after every action with the arms at home:

        * a physics blow-up: an object with a non-finite pose or velocity, or faster than :attr:`MAX_OBJECT_SPEED`;
        * an object resting on the gripper (in contact with a finger or the hand after the step, whether the arm
          reached its home pose or not), which would make every later plan start in collision.

        ``step`` sets ``info["fault"]`` (the reason in ``info["fault_reason"]``) and truncates that env's episode;
        objects thrown out of the workspace are counted in ``info["lost_objects"]`` as usual.
        """
        faults = self.clutter.blow_ups()
        links = (self.agent.finger1_link, self.agent.finger2_link, self.agent.robot.links_map["panda_hand"])
        qpos = self.agent.robot.get_qpos()[:, : len(self.home_qpos)].cpu().numpy()
        at_home = np.abs(qpos - self.home_qpos).max(axis=1) < 0.05
        pairwise_forces = self._gripper_contact_forces(links)
        for i in self.clutter.in_play():
            for link in links:
                force = pairwise_forces(link, self.clutter.actors[i]).norm(dim=-1).reshape(-1)
                for e in range(self.num_envs):
                    if not faults[e] and i in self.clutter.active_index[e] and float(force[e]) > self.GRIPPER_CONTACT_FORCE:
                        where = "at the home pose" if at_home[e] else "away from the home pose (the way home failed)"
                        faults[e] = f"{self.clutter.names[i]} rests on the gripper ({link.name}) {where}"
        return faults

    def _gripper_contact_forces(self, links):
        """ManiSkill's ``scene.get_pairwise_contact_forces`` for pairs of one of ``links`` and an object. On the CPU that
        fetches every contact of the scene per pair; here they are fetched once and kept to those of ``links`` (in
        their order), so each pair's force is ManiSkill's own sum over the same contacts."""
        scene = self.scene
        if self.gpu_sim_enabled:
            return scene.get_pairwise_contact_forces
        entities = {link._bodies[0].entity for link in links}
        contacts = [c for c in scene.px.get_contacts() if c.bodies[0].entity in entities or c.bodies[1].entity in entities]

        def force(link, actor) -> torch.Tensor:
            impulse = sapien_utils.get_pairwise_contact_impulse(contacts, link._bodies[0].entity, actor._bodies[0].entity)
            return common.to_tensor(impulse)[None, :] / scene.px.timestep

        return force

    # ------------------------------------------------------------------ observation and info
    def get_obs(self, info: dict | None = None, unflattened: bool = False):
        t0 = time.perf_counter()
        self.scene.update_render(update_sensors=True, update_human_render_cameras=False)
        with self._unseen_bodies_hidden():
            self.capture_sensor_data()
            data = {
                name: self.scene.sensors[name].get_obs(rgb=True, depth=True, position=False, segmentation=False)
                for name in (c.name for c in self.workspace.cameras)
            }
        params = self.get_sensor_params()
        t1 = time.perf_counter()
        color, height, *fit = heightmaps_from_sensors(data, params, self.workspace, fit=self.workspace.fit_scale > 1)
        self._t_render, self._t_heightmap = t1 - t0, time.perf_counter() - t1
        self._height = height.cpu().numpy()  # (num_envs, H, W)
        self._fit_height = fit[0] if fit else None  # (num_envs, kH, kW), with a fit heightmap only
        obs = dict(color_heightmap=color, depth_heightmap=height)
        if fit:
            obs["fit_heightmap"] = fit[0]
        if self.include_camera_data:
            obs["sensor_data"] = data
            obs["sensor_param"] = params
        return obs

    def _observation_timing(self) -> dict:
        return dict(render=self._t_render, heightmap=self._t_heightmap)

    @contextmanager
    def _unseen_bodies_hidden(self):
        """Leave out of the sensor render every body whose bounding box lies outside every camera's view volume of the
        workspace (:class:`~maniskill_pnp.cell.view_volume.ViewVolumes`): the robot at home, the parked pool objects,
        the floor. The heightmaps are then the same bit for bit, and lavapipe renders the two cameras in a little over half
        of the time. Raw camera data (``include_camera_data``) and GPU-batched renders show everything."""
        if self.include_camera_data or self.gpu_sim_enabled:
            yield
            return
        boxes = self._body_boxes
        unseen = [b for b, out in zip(boxes.bodies, self._view_volumes.outside(*boxes.world())) if out]
        for b in unseen:
            b.visibility = 0.0
        try:
            yield
        finally:
            for b in unseen:
                b.visibility = 1.0

    @property
    def _body_boxes(self) -> RenderBoxes:
        """The boxes of the (one) sub-scene's render bodies (conservative: each local box, moved), their local boxes
        found once per scene (a reconfiguration builds a new one)."""
        scene = self.scene.sub_scenes[0]
        if self._render_boxes_of is not scene:
            self._render_boxes = RenderBoxes(rb for e in scene.entities
                                             for rb in [e.find_component_by_type(sapien.render.RenderBodyComponent)] if rb is not None)
            self._render_boxes_of = scene
        return self._render_boxes

    def _env_info(self, env: int) -> dict:
        status = self.clutter.status(env)
        remaining = status.count("workspace")
        return dict(
            success=remaining == 0,
            objects_remaining=remaining,
            objects_in_bin=status.count("bin"),
            lost_objects=status.count("lost"),
            num_objects=len(self.clutter.active[env]),
            num_actions=int(self.num_actions[env]),
            num_grasps=int(self.num_grasps[env]),
            consecutive_failures=int(self.consecutive_failures[env]),
            settle_steps=int(self.settle_steps[env]),
            layout_index=int(self.clutter.layout_index[env]),
        )
