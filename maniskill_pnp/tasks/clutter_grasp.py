"""ClutterGrasp-v1: grasp objects out of a loosely packed clutter, one pixelwise grasp per step (thesis part II).

One step is a whole grasp: the action picks a pixel of the current heightmap and one of the rotations; the arm
grasps at that pixel's 3-D point with that yaw (:meth:`WorkspaceSpec.grasp_tcp_height` says how high), places
a grasped object in the bin, and returns to a home pose out of the cameras' view; then both cameras are
rendered and fused into the next heightmaps.

Objects: a pool of procedural objects (:mod:`maniskill_pnp.tasks.objects`) is built once, with a fixed library
seed; each episode draws ``num_objects`` of them, drops them into the workspace and lets them settle. Pool
objects not in the episode wait on the floor far from the robot and the cameras. With ``layout=`` the pool is
exactly the layout's objects, placed at its poses every episode.

Subclasses with more primitives (``ClutterGraspSlide-v1``) override the hooks :meth:`ClutterGraspEnv._execute`
(run the decoded action) and :meth:`ClutterGraspEnv._judge` (reward and success from what it did and the
heightmaps before and after), and may offer several layouts (:meth:`ClutterGraspEnv._resolve_layouts`).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import sapien
import torch
from gymnasium import spaces

from mani_skill.agents.robots import Panda
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.scene_builder.table import TableSceneBuilder

from maniskill_pnp.planning.primitives import MotionPrimitives, grasp_pose
from maniskill_pnp.planning.robot import panda_spec
from maniskill_pnp.tasks.bin import build_bin
from maniskill_pnp.tasks.primitive_env import PrimitiveStepEnv, parse_discrete_action, register_primitive_env
from maniskill_pnp.tasks.clutter import density_range, object_status, random_specs, sample_clutter, settle, validate_layout
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
        self.prims: MotionPrimitives | None = None
        self._episode_ready = False
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
        s = self.workspace.heightmap_size
        return spaces.Dict(
            color_heightmap=spaces.Box(0, 255, (1, s, s, 3), np.uint8),
            depth_heightmap=spaces.Box(0.0, self.workspace.max_height, (1, s, s), np.float32),
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

    def _park_pose(self, i: int) -> sapien.Pose:
        spec = self.pool_specs[i]
        return sapien.Pose(p=[1.6 + 0.15 * (i % 6), -0.5 + 0.15 * (i // 6), FLOOR_Z + spec.extents[2] / 2 + 1e-3])

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        self.table_scene.initialize(env_idx)
        self.agent.robot.set_qpos(torch.as_tensor(np.concatenate([self.home_qpos, [0.04, 0.04]]), dtype=torch.float32)[None])
        self.agent.controller.reset()  # controller targets follow the home pose set above
        rng = np.random.default_rng(int(self._batched_episode_rng[0].randint(2**31)))
        for i, actor in enumerate(self.pool):
            actor.set_pose(self._park_pose(i))
            actor.set_linear_velocity(torch.zeros(1, 3))
            actor.set_angular_velocity(torch.zeros(1, 3))
        self.layout_index = -1
        if self.layouts is not None:
            self.layout_index = self._choose_layout(rng, options)
            chosen = self.layout_slots[self.layout_index]
            poses = [pose for _, pose in self.layouts[self.layout_index]]
        else:
            lo, hi = self.num_objects_range
            n = int(rng.integers(lo, hi + 1))
            chosen = sorted(rng.choice(len(self.pool), size=n, replace=False).tolist())
            poses = sample_clutter(rng, [self.pool_specs[i] for i in chosen], self.workspace, self.loosely_packed, self.min_gap)
        for i, pose in zip(chosen, poses):
            self.pool[i].set_pose(pose)
        self.active = [self.pool_names[i] for i in chosen]
        self._active_actors = [self.pool[i] for i in chosen]
        hold = torch.as_tensor(np.concatenate([self.home_qpos, [1.0]]), dtype=torch.float32, device=self.device)[None]
        self.settle_steps = settle(self, self._active_actors, hold)
        self.num_actions = 0
        self.consecutive_failures = 0
        self.num_grasps = 0
        self.num_placed = 0
        self.last = dict(grasp_success=False, place_success=False, stage="reset", reason="", action=-1, fault="")
        self._episode_ready = True
        if self.prims is not None:
            self.prims.reset()

    # ------------------------------------------------------------------ reset and step
    def _primitives(self) -> MotionPrimitives:
        if self.prims is None:
            arm = replace(panda_spec(), home=self.home_qpos.copy())
            self.prims = MotionPrimitives(self, arm=arm, static_actors={"table-workspace", "ground", "bin"}, seed=self.planner_seed,
                                          on_control_step=self._on_control_step)
        return self.prims

    def step(self, action):
        if not self._episode_ready:
            raise RuntimeError("call reset() before step()")
        index = self._check_action(action)
        primitive, rot, row, col = (int(v) for v in self.action_layout.decode(index))
        prims = self._primitives()
        before = self._height
        t0, sim0 = time.perf_counter(), prims.executor.sim_steps
        outcome = self._execute(primitive, rot, row, col)
        home = prims.go_home()
        if not home.ok:  # one more plan (RRT is randomized) before leaving the arm in the cameras' view
            outcome["planning_time"] += home.planning_time
            home = prims.go_home()
        t_motion = time.perf_counter() - t0
        self._elapsed_steps += 1
        obs = self.get_obs()
        reward, success = self._judge(outcome, before, self._height)
        self.num_actions += 1
        self.num_grasps += int(outcome["grasp_success"])
        self.num_placed += int(outcome["place_success"])
        self.consecutive_failures = 0 if success else self.consecutive_failures + 1
        outcome["planning_time"] += home.planning_time
        self.last = dict(outcome, home_ok=bool(home.ok), action=index, pixel=(rot, row, col), time_motion=t_motion,
                         sim_steps=prims.executor.sim_steps - sim0, fault=self.detect_fault())
        info = self.get_info()
        info["time_render"], info["time_heightmap"] = self._t_render, self._t_heightmap
        terminated = torch.tensor([info["objects_remaining"] == 0], device=self.device)
        truncated = torch.tensor(
            [not terminated.item() and (self.consecutive_failures >= self.max_consecutive_failures or self.num_actions >= self.max_actions
                                        or bool(self.last["fault"]))],
            device=self.device,
        )
        self._last_obs = obs
        return obs, torch.tensor([reward], dtype=torch.float32, device=self.device), terminated, truncated, info

    @property
    def step_timings(self) -> dict:
        """Where the last step's time went, in seconds: ``render`` and ``heightmap`` of its closing observation,
        ``planning`` (IK, RRT-Connect, time parameterization), ``motion`` (the primitive and the way home, planning
        included), and its ``sim_steps`` (physics steps)."""
        last = getattr(self, "last", {})
        return dict(render=self._t_render, heightmap=self._t_heightmap, planning=float(last.get("planning_time", 0.0)),
                    motion=float(last.get("time_motion", 0.0)), sim_steps=int(last.get("sim_steps", 0)))

    def _execute(self, primitive: int, rot: int, row: int, col: int) -> dict:
        """Run the decoded action (the arm is left where the primitive ends; ``step`` sends it home).

        Returns:
            Info fields of the step; at least ``grasp_success``, ``place_success``, ``stage``, ``reason`` and
            ``planning_time``.
        """
        return self._grasp_at(rot, row, col)

    def _judge(self, outcome: dict, height_before: np.ndarray, height_after: np.ndarray) -> tuple[float, bool]:
        """Reward of the step and whether it counts as a success (a failure extends the run of failures).

        ``outcome`` is what :meth:`_execute` returned (a subclass may add fields to it); the heightmaps are those
        seen before and after the action.
        """
        grasped, placed = outcome["grasp_success"], outcome["place_success"]
        r = self.rewards
        return (r["place"] if placed else r["grasp"] if grasped else 0.0), grasped

    @property
    def rewards(self) -> dict[str, float]:
        """Reward per outcome: ``place`` (the object landed in the bin), ``grasp`` (grasped but not placed)."""
        return {"place": 1.0, "grasp": 0.5}

    def _grasp_at(self, rot: int, row: int, col: int) -> dict:
        """Grasp top-down at pixel ``(row, col)`` with rotation ``rot``; place a grasped object in the bin."""
        prims = self._primitives()
        surface = float(self._height[row, col])
        xyz = self.workspace.pixel_to_world(row, col, 0.0)
        xyz[2] = self.workspace.grasp_tcp_height(surface)
        yaw = float(self.workspace.rotation_to_yaw(rot))
        pick = prims.pick(grasp_pose(xyz, yaw), target=None, candidates=self._in_workspace())
        placed, place_stage, place_reason, planning_time = False, "", "", pick.planning_time
        if pick.grasped:
            place = prims.place(self.workspace.bin.region())
            placed, place_stage, place_reason = place.placed, place.stage, place.reason
            planning_time += place.planning_time
            if not placed:
                # Carrying failed (object still held) or it had not come to rest yet: open wide, wait, look again.
                prims.executor.gripper(1.0, self.RELEASE_STEPS)
                prims.held = None
                placed = self._status()[self.active.index(pick.held)] == "bin"
        return dict(
            grasp_success=bool(pick.grasped), place_success=bool(placed), stage=pick.stage, reason=pick.reason,
            place_stage=place_stage, place_reason=place_reason, grasp_position=[float(v) for v in xyz], grasp_yaw=yaw,
            planning_time=planning_time,
        )

    def _check_action(self, action) -> int:
        """The action as an int in the valid range; ValueError naming the range otherwise (before anything moves)."""
        n = self.action_layout.size
        if len(self.PRIMITIVES) > 1:
            grid = f"(primitive, rotation, row, col) = {self.action_layout.shape}, primitives {self.PRIMITIVES}"
        else:
            grid = f"(rotation, row, col) = {self.action_layout.shape[1:]}"
        return parse_discrete_action(action, n, f"one integer flat index in 0..{n - 1} over {grid}")

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

    def detect_fault(self) -> str:
        """Why the episode cannot go on ("" when it can), checked after every action with the arm at home:

        * a physics blow-up: an object with a non-finite pose or velocity, or faster than :attr:`MAX_OBJECT_SPEED`;
        * an object resting on the gripper (in contact with a finger or the hand at the home pose), which would
          make every later plan start in collision.

        ``step`` puts the reason in ``info["fault"]`` and truncates the episode; objects thrown out of the workspace
        are counted in ``info["lost_objects"]`` as usual.
        """
        for name, actor in zip(self.active, self._active_actors):
            p, v = actor.pose.p[0], actor.linear_velocity[0]
            if not (torch.isfinite(p).all() and torch.isfinite(v).all()) or float(v.norm()) > self.MAX_OBJECT_SPEED:
                return f"physics blow-up: {name} at {p.tolist()} moving at {float(v.norm()):.3g} m/s"
        links = (self.agent.finger1_link, self.agent.finger2_link, self.agent.robot.links_map["panda_hand"])
        for name, actor in zip(self.active, self._active_actors):
            for link in links:
                if float(self.scene.get_pairwise_contact_forces(link, actor).norm()) > self.GRIPPER_CONTACT_FORCE:
                    return f"{name} rests on the gripper ({link.name}) at the home pose"
        return ""

    # ------------------------------------------------------------------ observation, evaluation, reward
    def _in_workspace(self) -> list[str]:
        if not self._episode_ready:
            return []
        status = self._status()
        return [name for name, s in zip(self.active, status) if s == "workspace"]

    def _status(self) -> list[str]:
        pos = np.stack([a.pose.p[0].cpu().numpy() for a in self._active_actors]) if self._active_actors else np.zeros((0, 3))
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
        self._height = height[0].cpu().numpy()
        obs = dict(color_heightmap=color, depth_heightmap=height)
        if self.include_camera_data:
            obs["sensor_data"] = data
            obs["sensor_param"] = params
        return obs

    def evaluate(self):
        if not getattr(self, "_episode_ready", False):
            return {}
        status = self._status()
        remaining = status.count("workspace")
        return dict(
            success=torch.tensor([remaining == 0], device=self.device),
            objects_remaining=remaining,
            objects_in_bin=status.count("bin"),
            lost_objects=status.count("lost"),
            num_objects=len(self.active),
            num_actions=self.num_actions,
            num_grasps=self.num_grasps,
            consecutive_failures=self.consecutive_failures,
            settle_steps=self.settle_steps,
            layout_index=self.layout_index,
            **self.last,
        )

    def compute_dense_reward(self, obs, action, info):
        return info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info)


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
