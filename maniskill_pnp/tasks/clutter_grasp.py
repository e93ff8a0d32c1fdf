"""ClutterGrasp-v1: grasp objects out of a loosely packed clutter, one pixelwise grasp per step (thesis part II).

One step is a whole grasp: the action picks a pixel of the current heightmap and one of the rotations; the arm
grasps at that pixel's 3-D point with that yaw (:meth:`WorkspaceSpec.grasp_tcp_height` says how high), places
a grasped object in the bin, and returns to a home pose out of the cameras' view; then both cameras are
rendered and fused into the next heightmaps.

Objects: a pool of procedural objects (:mod:`maniskill_pnp.tasks.objects`) is built once, with a fixed library
seed; each episode draws ``num_objects`` of them, drops them into the workspace and lets them settle. Pool
objects not in the episode wait on the floor far from the robot and the cameras. With ``layout=`` the pool is
exactly the layout's objects, placed at its poses every episode.

Batched: with ManiSkill's GPU simulation (``num_envs > 1``) every sub-scene draws its own clutter from the same
pool, each env's action is decoded into a primitive program of its own arm (:class:`MotionPrimitives` with
``env_idx``), and :func:`~maniskill_pnp.planning.lockstep.drive` executes all programs in shared control steps
(an env whose program is done holds still). The heightmaps of all envs are computed together. On the CPU
(``num_envs = 1``) the same code runs with one env. Per-env state (:attr:`active`, :attr:`last`, the counters)
is a list or array indexed by env; ``info`` holds one env's values as scalars, and ``(num_envs,)`` tensors (or
lists, for text) when there are several.

Subclasses with more primitives (``ClutterGraspSlide-v1``) override the hooks :meth:`ClutterGraspEnv._execute`
(the program of one env's decoded action) and :meth:`ClutterGraspEnv._judge` (reward and success from what it did
and the heightmaps before and after), and may offer several layouts (:meth:`ClutterGraspEnv._resolve_layouts`).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import sapien
import torch
from gymnasium import spaces

from mani_skill.agents.robots import Panda
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.pose import Pose

from maniskill_pnp.planning.lockstep import LockstepExecutor, Motion, Program, drive
from maniskill_pnp.planning.primitives import MotionPrimitives, grasp_pose
from maniskill_pnp.planning.robot import panda_spec
from maniskill_pnp.tasks.bin import build_bin
from maniskill_pnp.tasks.primitive_env import PrimitiveStepEnv, parse_discrete_actions, register_primitive_env
from maniskill_pnp.tasks.clutter import density_range, object_status, random_specs, sample_clutter, validate_layout
from maniskill_pnp.tasks.heightmap import heightmaps_from_sensors
from maniskill_pnp.tasks.objects import KINDS, ObjectSpec, build_object
from maniskill_pnp.tasks.pixel_action import PixelActionLayout
from maniskill_pnp.tasks.workspace import WorkspaceSpec

ROBOT_BASE = (-0.615, 0.0, 0.0)
#: Height of the floor under ManiSkill's table scene (where unused pool objects wait).
FLOOR_Z = -0.9196


def camera_clear_home() -> np.ndarray:
    """The Panda's rest configuration turned 90° about its base axis: the arm beside the workspace, out of view."""
    q = panda_spec().home.copy()
    q[0] = -np.pi / 2
    return q


@register_primitive_env("ClutterGrasp-v1", max_episode_steps=None)
class ClutterGraspEnv(PrimitiveStepEnv):
    """**Task Description:**
    A loosely packed clutter of regular and irregular objects lies in the workspace in front of the Panda; a bin
    stands beside it. Each step the agent picks one flat index over (rotation, row, col) of the 224×224
    heightmap; the arm grasps top-down at that pixel's 3-D point with the rotation's yaw, puts a grasped object
    into the bin and goes back out of the cameras' view. Observation: ``color_heightmap`` (uint8 H×W×3) and
    ``depth_heightmap`` (float32 H×W, metres above the table), fused from a top-down narrow-FOV camera and a
    perspective camera (plus raw camera data with ``include_camera_data=True``).
    Reward: 1 placed in the bin, 0.5 grasped but not placed, 0 otherwise.

    **Randomizations:**
    - which pool objects form the clutter and how many (``num_objects``: an int, a (min, max) range, or a
      density preset name of :data:`~maniskill_pnp.tasks.clutter.DENSITY_PRESETS`)
    - their xy positions and yaws (loosely packed: footprints ``min_gap`` apart) or full poses (any packing),
      then a physics settle

    **Success Conditions:**
    - the workspace is clear (episode terminates); it is truncated after ``max_consecutive_failures`` failed
      grasps in a row or ``max_actions`` actions. Objects that leave the workspace other than into the bin are
      counted in ``info["lost_objects"]``.
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
    #: Primitive names, in the order of the action's primitive index.
    PRIMITIVES = ("grasp",)
    #: Speed (m/s) above which an object counts as blown up by the physics (nothing in the task moves this fast).
    MAX_OBJECT_SPEED = 5.0
    #: Contact force (N) between an object and the gripper at home above which the object rests on the gripper.
    GRIPPER_CONTACT_FORCE = 1e-3
    #: The settle after dropping the clutter: at least SETTLE_MIN_STEPS, at most SETTLE_MAX_STEPS control steps,
    #: until every object moves slower than SETTLE_LINEAR m/s and SETTLE_ANGULAR rad/s.
    SETTLE_MIN_STEPS, SETTLE_MAX_STEPS, SETTLE_LINEAR, SETTLE_ANGULAR = 3, 60, 0.005, 0.05

    def __init__(
        self,
        *args,
        robot_uids="panda",
        workspace: WorkspaceSpec | None = None,
        num_objects: int | tuple[int, int] | str = (10, 15),
        object_kinds: tuple[str, ...] = KINDS,
        loosely_packed: bool = True,
        min_gap: float = 0.01,
        layout=None,
        max_consecutive_failures: int = 10,
        max_actions: int | None = None,
        include_camera_data: bool = False,
        planner_seed: int = 0,
        **kwargs,
    ):
        """Args beyond ManiSkill's: ``workspace`` (geometry, cameras, bin), ``num_objects``, ``object_kinds``,
        ``loosely_packed`` and ``min_gap`` (clutter), ``layout`` (explicit list of (ObjectSpec, pose); overrides the
        random clutter), ``max_consecutive_failures`` and ``max_actions`` (truncation; default 3 × the largest
        object count), ``include_camera_data`` (raw RGB-D and camera parameters in the observation), and the
        motion planner's seed."""
        self.workspace = workspace or WorkspaceSpec()
        if isinstance(num_objects, str):
            num_objects = density_range(num_objects)
        lo, hi = (num_objects, num_objects) if isinstance(num_objects, (int, np.integer)) else tuple(num_objects)
        if not (isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer)) and 1 <= lo <= hi):
            raise ValueError(f"num_objects must be a positive int or a (min, max) range with 1 <= min <= max, got {num_objects!r}")
        kinds = (object_kinds,) if isinstance(object_kinds, str) else tuple(object_kinds)
        if not kinds or any(k not in KINDS for k in kinds):
            raise ValueError(f"object_kinds must be a non-empty subset of {list(KINDS)}, got {object_kinds!r}")
        if not min_gap >= 0:
            raise ValueError(f"min_gap must be >= 0, got {min_gap!r}")
        if not (isinstance(max_consecutive_failures, int) and max_consecutive_failures >= 1):
            raise ValueError(f"max_consecutive_failures must be a positive int, got {max_consecutive_failures!r}")
        kwargs.setdefault("obs_mode", "rgb+depth")
        if kwargs["obs_mode"] != "rgb+depth":
            raise ValueError(f"ClutterGrasp-v1 observes RGB-D heightmaps: obs_mode must be 'rgb+depth', got {kwargs['obs_mode']!r}")
        self.layouts = self._resolve_layouts(layout)
        if self.layouts is None:
            self.num_objects_range = (int(lo), int(hi))
        else:
            self.num_objects_range = (min(map(len, self.layouts)), max(map(len, self.layouts)))
        self.object_kinds = kinds
        self.loosely_packed = bool(loosely_packed)
        self.min_gap = float(min_gap)
        self.max_consecutive_failures = max_consecutive_failures
        self.max_actions = int(max_actions) if max_actions is not None else 3 * self.num_objects_range[1]
        self.include_camera_data = include_camera_data
        self.planner_seed = planner_seed
        s = self.workspace.heightmap_size
        self.action_layout = PixelActionLayout(len(self.PRIMITIVES), self.workspace.num_rotations, s, s)
        self.home_qpos = camera_clear_home()
        self.prims: list[MotionPrimitives] | None = None
        self._episode_ready = False
        n = int(kwargs.get("num_envs", 1))  # ManiSkill's __init__ resets the envs, so the per-env state comes first
        #: Per env: the pool indices of the episode's objects, their names and actors.
        self.active_index: list[list[int]] = [[] for _ in range(n)]
        self.active: list[list[str]] = [[] for _ in range(n)]
        self._active_actors: list[list] = [[] for _ in range(n)]
        #: Per env: what its last action did (the ``info`` fields of the step).
        self.last: list[dict] = [{} for _ in range(n)]
        self.layout_index = np.full(n, -1)
        self.settle_steps = np.zeros(n, dtype=np.int64)
        self.num_actions = np.zeros(n, dtype=np.int64)
        self.consecutive_failures = np.zeros(n, dtype=np.int64)
        self.num_grasps = np.zeros(n, dtype=np.int64)
        self.num_placed = np.zeros(n, dtype=np.int64)
        super().__init__(*args, robot_uids=robot_uids, **kwargs)
        self._use_discrete_actions(self.action_layout.size)

    # ------------------------------------------------------------------ spaces
    @property
    def single_observation_space(self):
        s = self.workspace.heightmap_size
        return spaces.Dict(
            color_heightmap=spaces.Box(0, 255, (s, s, 3), np.uint8),
            depth_heightmap=spaces.Box(0.0, self.workspace.max_height, (s, s), np.float32),
        )

    @property
    def observation_space(self):
        s, n = self.workspace.heightmap_size, self.num_envs
        return spaces.Dict(
            color_heightmap=spaces.Box(0, 255, (n, s, s, 3), np.uint8),
            depth_heightmap=spaces.Box(0.0, self.workspace.max_height, (n, s, s), np.float32),
        )

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
        if self.layouts is not None:
            self.pool_specs, self.layout_slots = _shared_pool(self.layouts)
        else:
            rng = np.random.default_rng(self.LIBRARY_SEED)
            self.pool_specs = random_specs(rng, max(self.POOL_SIZE, self.num_objects_range[1]), self.object_kinds)
        self.pool_names = [f"obj_{i}_{spec.kind}" for i, spec in enumerate(self.pool_specs)]
        self.pool = [build_object(self.scene, spec, name, self._park_pose(i)) for i, (spec, name) in enumerate(zip(self.pool_specs, self.pool_names))]
        self.prims = None  # a new scene (reconfiguration) needs new primitives

    def _park_pose(self, i: int) -> sapien.Pose:
        spec = self.pool_specs[i]
        return sapien.Pose(p=[1.6 + 0.15 * (i % 6), -0.5 + 0.15 * (i // 6), FLOOR_Z + spec.extents[2] / 2 + 1e-3])

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        envs = [int(e) for e in torch.as_tensor(env_idx).reshape(-1).tolist()]
        b = len(envs)
        self.table_scene.initialize(env_idx)
        qpos = torch.as_tensor(np.concatenate([self.home_qpos, [0.04, 0.04]]), dtype=torch.float32, device=self.device)
        self.agent.robot.set_qpos(qpos.expand(b, -1))
        self.agent.controller.reset()  # controller targets of the reset envs follow the home pose set above
        poses = [[self._park_pose(i)] * b for i in range(len(self.pool))]  # pool index -> pose in each reset env
        for k, e in enumerate(envs):
            chosen, placed = self._draw_clutter(e, options)
            for i, pose in zip(chosen, placed):
                poses[i][k] = pose
            self.active_index[e] = chosen
            self.active[e] = [self.pool_names[i] for i in chosen]
            self._active_actors[e] = [self.pool[i] for i in chosen]
            self.num_actions[e] = self.consecutive_failures[e] = self.num_grasps[e] = self.num_placed[e] = 0
            self.last[e] = self._initial_last()
        zeros = torch.zeros(b, 3, device=self.device)
        for actor, actor_poses in zip(self.pool, poses):
            p = torch.as_tensor(np.stack([pose.p for pose in actor_poses]), dtype=torch.float32, device=self.device)
            q = torch.as_tensor(np.stack([pose.q for pose in actor_poses]), dtype=torch.float32, device=self.device)
            actor.set_pose(Pose.create_from_pq(p=p, q=q))
            actor.set_linear_velocity(zeros)
            actor.set_angular_velocity(zeros)
        prims = self._primitives()
        for e in envs:
            prims[e].reset()
        self.settle_steps[envs] = self._settle(envs)
        self._episode_ready = True

    def _draw_clutter(self, env: int, options: dict) -> tuple[list[int], list[sapien.Pose]]:
        """Env ``env``'s episode objects (pool indices) and their drop poses, from its seeded episode RNG."""
        rng = np.random.default_rng(int(self._batched_episode_rng[env].randint(2**31)))
        self.layout_index[env] = -1
        if self.layouts is not None:
            k = self.layout_index[env] = self._choose_layout(rng, options)
            return list(self.layout_slots[k]), [pose for _, pose in self.layouts[k]]
        lo, hi = self.num_objects_range
        chosen = sorted(rng.choice(len(self.pool), size=int(rng.integers(lo, hi + 1)), replace=False).tolist())
        return chosen, sample_clutter(rng, [self.pool_specs[i] for i in chosen], self.workspace, self.loosely_packed, self.min_gap)

    def _initial_last(self) -> dict:
        """The ``last`` entry of an env before its first action."""
        return dict(grasp_success=False, place_success=False, stage="reset", reason="", action=-1, fault="")

    def _settle(self, envs: list[int]) -> int:
        """Let the dropped clutter of ``envs`` come to rest, their arms at home and grippers open, the other envs'
        arms holding; returns the control steps taken."""
        home = self.home_qpos[None]

        def at_rest(e: int):
            def test() -> bool:
                return all(float(torch.linalg.norm(a.linear_velocity[e])) < self.SETTLE_LINEAR
                           and float(torch.linalg.norm(a.angular_velocity[e])) < self.SETTLE_ANGULAR
                           for a in self._active_actors[e])
            return test

        motions = [None] * self.num_envs
        for e in envs:
            motions[e] = Motion(home, gripper=1.0, min_steps=self.SETTLE_MIN_STEPS, settle_tol=None, until=at_rest(e),
                                max_settle=self.SETTLE_MAX_STEPS - self.SETTLE_MIN_STEPS)
        lockstep = self._lockstep
        steps0 = lockstep.control_steps
        with self._all_envs_live():
            lockstep.run(motions)
        return lockstep.control_steps - steps0

    @contextmanager
    def _all_envs_live(self):
        """Step the whole scene inside ``_initialize_episode``: the poses set so far are applied (GPU simulation)
        and ManiSkill's reset mask, which limits setters to the envs being reset, is lifted meanwhile."""
        mask = self.scene._reset_mask
        self.scene._reset_mask = torch.ones(self.num_envs, dtype=torch.bool, device=self.device)
        if self.gpu_sim_enabled:
            self.scene._gpu_apply_all()
            self.scene.px.gpu_update_articulation_kinematics()
            self.scene._gpu_fetch_all()
        try:
            yield
        finally:
            self.scene._reset_mask = mask

    # ------------------------------------------------------------------ reset and step
    def _primitives(self) -> list[MotionPrimitives]:
        """Each env's motion primitives, all driving one shared :class:`LockstepExecutor`."""
        if self.prims is None:
            arm = replace(panda_spec(), home=self.home_qpos.copy())
            lockstep = LockstepExecutor(self, arm, on_control_step=self._on_control_step)
            self.prims = [
                MotionPrimitives(self, arm=arm, static_actors={"table-workspace", "ground", "bin"}, seed=self.planner_seed + e,
                                 lockstep=lockstep, env_idx=e)
                for e in range(self.num_envs)
            ]
        return self.prims

    @property
    def _lockstep(self) -> LockstepExecutor:
        return self._primitives()[0].executor.lockstep

    def step(self, action):
        if not self._episode_ready:
            raise RuntimeError("call reset() before step()")
        indices = self._check_action(action)
        lockstep = self._lockstep
        before = self._height
        t0, sim0 = time.perf_counter(), lockstep.sim_steps
        outcomes = drive(lockstep, [self._action_program(e, index) for e, index in enumerate(indices)])
        t_motion = time.perf_counter() - t0
        self._elapsed_steps += 1
        obs = self.get_obs()
        faults = self.detect_faults()
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        for e, (index, outcome) in enumerate(zip(indices, outcomes)):
            rewards[e], success = self._judge(e, outcome, before[e], self._height[e])
            self.num_actions[e] += 1
            self.num_grasps[e] += int(outcome["grasp_success"])
            self.num_placed[e] += int(outcome["place_success"])
            self.consecutive_failures[e] = 0 if success else self.consecutive_failures[e] + 1
            self.last[e] = dict(outcome, action=index, time_motion=t_motion, sim_steps=lockstep.sim_steps - sim0,
                                fault=faults[e])
        info = self.get_info()
        info["time_render"], info["time_heightmap"] = self._t_render, self._t_heightmap
        remaining = np.array([self._status(e).count("workspace") for e in range(self.num_envs)])
        terminated = remaining == 0
        truncated = ~terminated & ((self.consecutive_failures >= self.max_consecutive_failures)
                                   | (self.num_actions >= self.max_actions) | np.array([bool(f) for f in faults]))
        self._last_obs = obs
        return (obs, torch.as_tensor(rewards, device=self.device), torch.as_tensor(terminated, device=self.device),
                torch.as_tensor(truncated, device=self.device), info)

    def _action_program(self, env: int, index: int) -> Program:
        """Env ``env``'s whole step as one program: the decoded action (:meth:`_execute`), then the way home (planned
        a second time if the first plan fails, before leaving the arm in the cameras' view)."""
        primitive, rot, row, col = (int(v) for v in self.action_layout.decode(index))
        prims = self.prims[env]
        outcome = yield from self._execute(env, primitive, rot, row, col)
        home = yield from prims.program("go_home")
        if not home.ok:  # RRT is randomized: one more plan
            outcome["planning_time"] += home.planning_time
            home = yield from prims.program("go_home")
        outcome["planning_time"] += home.planning_time
        return dict(outcome, home_ok=bool(home.ok), pixel=(rot, row, col))

    @property
    def step_timings(self) -> dict:
        """Where the last step's time went, in seconds: ``render`` and ``heightmap`` of its closing observation,
        ``planning`` (IK, RRT-Connect, time parameterization; summed over the envs, which plan one after another),
        ``motion`` (the primitives of all envs and their way home, planning included), and its ``sim_steps``
        (physics steps, shared by the envs)."""
        last = self.last[0]
        return dict(render=self._t_render, heightmap=self._t_heightmap,
                    planning=float(sum(entry.get("planning_time", 0.0) for entry in self.last)),
                    motion=float(last.get("time_motion", 0.0)), sim_steps=int(last.get("sim_steps", 0)))

    def _execute(self, env: int, primitive: int, rot: int, row: int, col: int) -> Program:
        """The program of env ``env``'s decoded action (the arm is left where the primitive ends; the step's program
        goes on home).

        Returns (as the program's return value):
            Info fields of the step; at least ``grasp_success``, ``place_success``, ``stage``, ``reason`` and
            ``planning_time``.
        """
        return (yield from self._grasp_at(env, rot, row, col))

    def _judge(self, env: int, outcome: dict, height_before: np.ndarray, height_after: np.ndarray) -> tuple[float, bool]:
        """Reward of env ``env``'s step and whether it counts as a success (a failure extends the run of failures).

        ``outcome`` is what :meth:`_execute` returned (a subclass may add fields to it); the heightmaps are the env's
        before and after the action.
        """
        grasped, placed = outcome["grasp_success"], outcome["place_success"]
        r = self.rewards
        return (r["place"] if placed else r["grasp"] if grasped else 0.0), grasped

    @property
    def rewards(self) -> dict[str, float]:
        """Reward per outcome: ``place`` (the object landed in the bin), ``grasp`` (grasped but not placed)."""
        return {"place": 1.0, "grasp": 0.5}

    def _grasp_at(self, env: int, rot: int, row: int, col: int) -> Program:
        """Program: grasp top-down at pixel ``(row, col)`` of env ``env`` with rotation ``rot``; place a grasped
        object in the bin."""
        prims = self.prims[env]
        surface = float(self._height[env][row, col])
        xyz = self.workspace.pixel_to_world(row, col, 0.0)
        xyz[2] = self.workspace.grasp_tcp_height(surface)
        yaw = float(self.workspace.rotation_to_yaw(rot))
        pick = yield from prims.program("pick", grasp_pose(xyz, yaw), target=None, candidates=self._in_workspace(env))
        placed, place_stage, place_reason, planning_time = False, "", "", pick.planning_time
        if pick.grasped:
            place = yield from prims.program("place", self.workspace.bin.region())
            placed, place_stage, place_reason = place.placed, place.stage, place.reason
            planning_time += place.planning_time
            if not placed:
                # Carrying failed (object still held) or it had not come to rest yet: open wide, wait, look again.
                yield Motion(gripper=1.0, min_steps=self.RELEASE_STEPS, settle_tol=None)
                prims.held = None
                placed = self._status(env)[self.active[env].index(pick.held)] == "bin"
        return dict(
            grasp_success=bool(pick.grasped), place_success=bool(placed), stage=pick.stage, reason=pick.reason,
            place_stage=place_stage, place_reason=place_reason, grasp_position=[float(v) for v in xyz], grasp_yaw=yaw,
            planning_time=planning_time,
        )

    def _check_action(self, action) -> list[int]:
        """Each env's action as an int in the valid range; ValueError naming the range otherwise (before anything
        moves)."""
        n = self.action_layout.size
        if len(self.PRIMITIVES) > 1:
            grid = f"(primitive, rotation, row, col) = {self.action_layout.shape}, primitives {self.PRIMITIVES}"
        else:
            grid = f"(rotation, row, col) = {self.action_layout.shape[1:]}"
        return parse_discrete_actions(action, self.num_envs, n, f"one integer flat index in 0..{n - 1} over {grid}")

    # ------------------------------------------------------------------ layouts
    def _resolve_layouts(self, layout) -> list[list[tuple[ObjectSpec, sapien.Pose]]] | None:
        """The episode layouts of the ``layout`` option, validated: None (random clutter) or a list of layouts.

        ClutterGrasp-v1 takes one explicit layout (a list of ``(ObjectSpec, pose)``); subclasses may offer more.
        """
        return None if layout is None else [validate_layout(layout, self.workspace)]

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
        * an object resting on the gripper (in contact with a finger or the hand at the home pose), which would
          make every later plan start in collision.

        ``step`` puts the reason in ``info["fault"]`` and truncates that env's episode; objects thrown out of the
        workspace are counted in ``info["lost_objects"]`` as usual. Each pool object in play in some env is read
        once for all envs.
        """
        faults = [""] * self.num_envs
        used = sorted({i for index in self.active_index for i in index})
        pose = {i: self.pool[i].pose.p for i in used}
        vel = {i: self.pool[i].linear_velocity for i in used}
        for e in range(self.num_envs):
            for i in self.active_index[e]:
                p, v = pose[i][e], vel[i][e]
                if not (torch.isfinite(p).all() and torch.isfinite(v).all()) or float(v.norm()) > self.MAX_OBJECT_SPEED:
                    faults[e] = f"physics blow-up: {self.pool_names[i]} at {p.tolist()} moving at {float(v.norm()):.3g} m/s"
                    break
        links = (self.agent.finger1_link, self.agent.finger2_link, self.agent.robot.links_map["panda_hand"])
        for i in used:
            for link in links:
                force = self.scene.get_pairwise_contact_forces(link, self.pool[i]).norm(dim=-1).reshape(-1)
                for e in range(self.num_envs):
                    if not faults[e] and i in self.active_index[e] and float(force[e]) > self.GRIPPER_CONTACT_FORCE:
                        faults[e] = f"{self.pool_names[i]} rests on the gripper ({link.name}) at the home pose"
        return faults

    # ------------------------------------------------------------------ observation, evaluation, reward
    def _in_workspace(self, env: int) -> list[str]:
        """Names of env ``env``'s objects still in the workspace."""
        if not self._episode_ready:
            return []
        return [name for name, s in zip(self.active[env], self._status(env)) if s == "workspace"]

    def _status(self, env: int) -> list[str]:
        """Where each of env ``env``'s objects is (:func:`~maniskill_pnp.tasks.clutter.object_status`)."""
        actors = self._active_actors[env]
        pos = np.stack([a.pose.p[env].cpu().numpy() for a in actors]) if actors else np.zeros((0, 3))
        return object_status(pos, self.workspace)

    def get_obs(self, info: dict | None = None, unflattened: bool = False):
        t0 = time.perf_counter()
        self.scene.update_render(update_sensors=True, update_human_render_cameras=False)
        self.capture_sensor_data()
        data = {
            name: self.scene.sensors[name].get_obs(rgb=True, depth=True, position=False, segmentation=False)
            for name in (c.name for c in self.workspace.cameras)
        }
        params = self.get_sensor_params()
        t1 = time.perf_counter()
        color, height = heightmaps_from_sensors(data, params, self.workspace)
        self._t_render, self._t_heightmap = t1 - t0, time.perf_counter() - t1
        self._height = height.cpu().numpy()  # (num_envs, H, W)
        obs = dict(color_heightmap=color, depth_heightmap=height)
        if self.include_camera_data:
            obs["sensor_data"] = data
            obs["sensor_param"] = params
        return obs

    def evaluate(self):
        if not getattr(self, "_episode_ready", False):
            return {}
        return batch_infos([self._env_info(e) for e in range(self.num_envs)], self.device)

    def _env_info(self, env: int) -> dict:
        """Env ``env``'s ``info`` fields: the episode's counts, then what its last action did."""
        status = self._status(env)
        remaining = status.count("workspace")
        return dict(
            success=remaining == 0,
            objects_remaining=remaining,
            objects_in_bin=status.count("bin"),
            lost_objects=status.count("lost"),
            num_objects=len(self.active[env]),
            num_actions=int(self.num_actions[env]),
            num_grasps=int(self.num_grasps[env]),
            consecutive_failures=int(self.consecutive_failures[env]),
            settle_steps=int(self.settle_steps[env]),
            layout_index=int(self.layout_index[env]),
            **self.last[env],
        )

    def compute_dense_reward(self, obs, action, info):
        return info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info)


def batch_infos(infos: list[dict], device) -> dict:
    """One ``info`` from the per-env ones: one env's values as they are (``success`` as a ``(1,)`` tensor, as ManiSkill
    has it); for several envs, each key's values as a ``(num_envs,)`` tensor when they are all numbers, else a list."""
    if len(infos) == 1:
        return dict(infos[0], success=torch.tensor([infos[0]["success"]], device=device))
    out = {}
    for key in infos[0]:
        values = [info.get(key) for info in infos]
        numeric = all(isinstance(v, (bool, int, float, np.integer, np.floating)) for v in values)
        out[key] = torch.tensor(values, device=device) if numeric else values
    return out


def _shared_pool(layouts) -> tuple[list[ObjectSpec], list[list[int]]]:
    """One pool for several layouts: each distinct spec as many times as the layout that uses it most.

    Returns:
        The pool's specs and, per layout, the pool index of each of its entries.
    """
    pool: list[ObjectSpec] = []
    slots = []
    for layout in layouts:
        used: dict[ObjectSpec, int] = {}
        indices = []
        for spec, _ in layout:
            copies = [i for i, s in enumerate(pool) if s == spec]
            k = used.get(spec, 0)
            if k == len(copies):
                pool.append(spec)
                copies.append(len(pool) - 1)
            indices.append(copies[k])
            used[spec] = k + 1
        slots.append(indices)
    return pool, slots
