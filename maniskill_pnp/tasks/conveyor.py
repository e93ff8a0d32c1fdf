"""ConveyorProximity-v1: pick objects off a moving conveyor belt, sensed by ray-type proximity sensors only.

Part I of the thesis (chapter 4). One agent step is a whole phase of the pick: waiting for the object and
sensing it, moving to a pre-pick coordinate (OMPL), or descending to a grasp coordinate, closing, lifting and,
after a good grasp, placing in the bin. The object keeps riding the belt while the arm moves, because every
motion steps the real simulation: which grasp coordinate is right depends on the sensed speed and alignment.

Belt model: the belt is a static box, and belt and objects are frictionless (PhysX averages the coefficients of
a contact pair, so any friction there would brake the object against the drive); while an object lies on the
belt, the task applies each physics sub-step the force a belt with friction coefficient ``belt_grip`` would,
``m (v_belt - v) / tau`` capped at ``belt_grip * m * g``. A kinematic moving surface would have to be re-positioned every episode and drives
objects only through PhysX friction, which lets spheres roll and slip; setting velocities directly would push
an object through the finger that stops it. The capped force carries objects at belt speed, lets a closed
finger hold one back, and stops acting once the object leaves the belt (lifted, or fallen off the end: an
object that is not picked falls off past ``belt_y[1]`` onto the table and is missed).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import sapien
import torch
from gymnasium import spaces

from mani_skill.agents.robots import Panda
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.scene_builder.table import TableSceneBuilder

from maniskill_pnp.planning.lockstep import LockstepExecutor, Motion
from maniskill_pnp.planning.primitives import MotionPrimitives, PrimitiveResult, grasp_pose
from maniskill_pnp.planning.robot import panda_spec
from maniskill_pnp.cell.bin import build_bin
from maniskill_pnp.tasks.primitive_env import Decision, Judgement, PrimitiveStepEnv
from maniskill_pnp.tasks.registration import register_task
from maniskill_pnp.tasks.conveyor_config import (
    ALIGNMENTS, OBJECT_KINDS, REWARD_SCHEMES, SPEEDS, UNKNOWN, ConveyorSpec,
)

ROBOT_BASE = (-0.615, 0.0, 0.0)
GRAVITY = 9.81
#: Procedural objects: two sizes per kind (half extents / radius and half height, m); ≤ 6 cm across the jaws.
OBJECT_VARIANTS = {
    "cuboid": ({"half_size": (0.02, 0.02, 0.02)}, {"half_size": (0.015, 0.022, 0.025)}),
    "cylinder": ({"radius": 0.02, "half_length": 0.025}, {"radius": 0.017, "half_length": 0.02}),
    "sphere": ({"radius": 0.02}, {"radius": 0.024}),
}
#: The primitive each phase's action runs (the action chooses its coordinate).
PHASE_PRIMITIVES = {"initial": "wait", "pre_pick": "pre_pick", "grasp": "grasp"}
OBJECT_COLORS = {"cuboid": (0.85, 0.2, 0.15, 1), "cylinder": (0.2, 0.6, 0.25, 1), "sphere": (0.9, 0.7, 0.1, 1)}


def _check_choice(name: str, value: str | None, valid: tuple[str, ...]) -> None:
    if value is not None and value not in valid:
        raise ValueError(f"unknown {name} {value!r}; valid: {list(valid)} or None (random)")


@register_task("ConveyorProximity-v1", max_episode_steps=10)
class ConveyorProximityEnv(PrimitiveStepEnv):
    """**Task Description:**
    Objects (cuboid, cylinder or sphere) ride a conveyor belt toward the Panda one at a time. Ray-type proximity
    sensors at the workspace end of the belt sense the arrival, the alignment across the belt and the belt speed.
    The agent chooses a pre-pick coordinate above the belt, then a grasp coordinate along the belt below it; the
    arm reaches them with planned motions while the object keeps moving, grasps, and places the object in the bin.
    Phases: ``initial`` (action 0: wait and sense) → ``pre_pick`` → ``grasp`` → ``done``. The observation is one
    discrete state id (phase, sensed speed, sensed alignment, last chosen coordinate); ``info`` decodes it and
    holds the raw ray readings. ``info["action_mask"]`` (bool, ``(1, 9)``) marks the actions the phase offers
    (``env.action_space.sample(mask=info["action_mask"])`` draws one); any other action of ``Discrete(9)`` is a
    failed attempt: nothing moves, the failure reward, ``info["invalid_action"]``, and the episode ends.

    **Randomizations:**
    - object kind (from ``object_kinds``) and size variant; yaw uniform
    - alignment (left / center / right lane, with a small jitter) unless fixed by ``alignment``
    - belt speed class (slow / medium / fast) unless fixed by ``speed``

    **Success Conditions:**
    - the object came to rest inside the bin (reward 1; 0.5 when grasped but not placed; 0 otherwise, or -1 with
      the "negative" schemes; +1 more with the "bonus" schemes for the hand-marked optimal coordinates)
    """

    SUPPORTED_ROBOTS = ["panda"]
    agent: Panda
    PRIMITIVES = ("wait", "pre_pick", "grasp")

    def __init__(
        self,
        *args,
        robot_uids="panda",
        conveyor: ConveyorSpec | None = None,
        object_kinds: tuple[str, ...] = OBJECT_KINDS,
        alignment: str | None = None,
        speed: str | None = None,
        reward_scheme: str = "normal",
        planner_seed: int = 0,
        **kwargs,
    ):
        """Args beyond ManiSkill's: ``conveyor`` (geometry, sensors, coordinate sets), ``object_kinds`` (subset of
        cuboid/cylinder/sphere), fixed ``alignment`` and/or ``speed`` class, ``reward_scheme`` (one of
        ``REWARD_SCHEMES``) and the seed of the motion planner. ``reset(options=dict(alignment=..., speed=...))``
        fixes them for one episode."""
        if reward_scheme not in REWARD_SCHEMES:
            raise ValueError(f"unknown reward_scheme {reward_scheme!r}; valid schemes: {list(REWARD_SCHEMES)}")
        kinds = (object_kinds,) if isinstance(object_kinds, str) else tuple(object_kinds)
        unknown = [k for k in kinds if k not in OBJECT_KINDS]
        if unknown or not kinds:
            raise ValueError(f"unknown object kinds {unknown or kinds!r}; choose a non-empty subset of {list(OBJECT_KINDS)}")
        _check_choice("alignment", alignment, ALIGNMENTS)
        _check_choice("speed", speed, SPEEDS)
        self.conveyor = conveyor or ConveyorSpec()
        self.object_kinds = kinds
        self.fixed_alignment = alignment
        self.fixed_speed = speed
        self.reward_scheme = reward_scheme
        self.planner_seed = planner_seed
        self.prims: MotionPrimitives | None = None
        self._episode_ready = False
        super().__init__(*args, robot_uids=robot_uids, **kwargs)
        self._use_discrete_actions(self.conveyor.action_n)

    # ------------------------------------------------------------------ spaces
    @property
    def single_observation_space(self):
        return spaces.Discrete(self.conveyor.num_states)

    @property
    def observation_space(self):
        return spaces.MultiDiscrete([self.conveyor.num_states])

    # ------------------------------------------------------------------ scene
    @property
    def _default_sensor_configs(self):
        return []

    @property
    def _default_human_render_camera_configs(self):
        pose = sapien_utils.look_at(eye=[0.45, -0.6, 0.6], target=[-0.15, -0.05, 0.05])
        return CameraConfig("render_camera", pose, 512, 512, 1, 0.01, 100)

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=list(ROBOT_BASE)))

    def _load_scene(self, options: dict):
        s = self.conveyor
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=0.0)
        self.table_scene.build()
        y0, y1 = s.belt_y
        builder = self.scene.create_actor_builder()
        half = (s.belt_width / 2, (y1 - y0) / 2, s.belt_top / 2)
        slick = sapien.physx.PhysxMaterial(static_friction=0.0, dynamic_friction=0.0, restitution=0.0)
        builder.add_box_collision(half_size=half, material=slick)
        builder.add_box_visual(half_size=half, material=sapien.render.RenderMaterial(base_color=[0.15, 0.15, 0.15, 1]))
        builder.initial_pose = sapien.Pose(p=[s.belt_x, (y0 + y1) / 2, s.belt_top / 2])
        self.belt = builder.build_static(name="belt")
        self.bin = build_bin(self.scene, s.bin)
        self.objects: dict[tuple[str, int], object] = {}
        self.object_half_heights: dict[tuple[str, int], float] = {}
        for kind in OBJECT_KINDS:
            for v, size in enumerate(OBJECT_VARIANTS[kind]):
                key = (kind, v)
                self.objects[key], self.object_half_heights[key] = self._build_object(kind, size, f"{kind}_{v}")
        self._park_all()

    def _build_object(self, kind: str, size: dict, name: str):
        builder = self.scene.create_actor_builder()
        material = sapien.render.RenderMaterial(base_color=list(OBJECT_COLORS[kind]))
        # Frictionless objects: PhysX averages the two materials' coefficients, so only a frictionless pair leaves
        # the belt drive alone in charge; against the Panda's finger pads (2.0) the pair still grips at 1.0.
        slick = sapien.physx.PhysxMaterial(static_friction=0.0, dynamic_friction=0.0, restitution=0.0)
        if kind == "cuboid":
            builder.add_box_collision(half_size=size["half_size"], material=slick)
            builder.add_box_visual(half_size=size["half_size"], material=material)
            h = size["half_size"][2]
        elif kind == "cylinder":
            upright = sapien.Pose(q=[np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])  # SAPIEN cylinders lie along x
            builder.add_cylinder_collision(pose=upright, radius=size["radius"], half_length=size["half_length"], material=slick)
            builder.add_cylinder_visual(pose=upright, radius=size["radius"], half_length=size["half_length"], material=material)
            h = size["half_length"]
        else:
            builder.add_sphere_collision(radius=size["radius"], material=slick)
            builder.add_sphere_visual(radius=size["radius"], material=material)
            h = size["radius"]
        builder.initial_pose = sapien.Pose(p=[0.4, 0.0, h])
        return builder.build(name=name), h

    def _park_all(self):
        """Unused objects wait in a row on the table, out of the arm's way."""
        for i, (key, actor) in enumerate(self.objects.items()):
            actor.set_pose(sapien.Pose(p=[0.35, -0.3 + 0.1 * i, self.object_half_heights[key]]))

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        s = self.conveyor
        fixed_alignment = options.get("alignment", self.fixed_alignment)
        fixed_speed = options.get("speed", self.fixed_speed)
        _check_choice("alignment", fixed_alignment, ALIGNMENTS)
        _check_choice("speed", fixed_speed, SPEEDS)
        rng = self._batched_episode_rng[0]
        self.table_scene.initialize(env_idx)
        self._park_all()
        kind = self.object_kinds[rng.randint(len(self.object_kinds))]
        variant = int(rng.randint(len(OBJECT_VARIANTS[kind])))
        alignment = ALIGNMENTS[rng.randint(len(ALIGNMENTS))]
        speed = SPEEDS[rng.randint(len(SPEEDS))]
        alignment, speed = fixed_alignment or alignment, fixed_speed or speed  # draws kept: same seed, same object
        yaw = rng.uniform(-np.pi, np.pi)
        x = s.belt_x + s.lane_offsets[ALIGNMENTS.index(alignment)] + rng.uniform(-s.lane_jitter, s.lane_jitter)
        self.obj = self.objects[(kind, variant)]
        self.obj_name = f"{kind}_{variant}"
        z = s.belt_top + self.object_half_heights[(kind, variant)] + 1e-4
        self.obj.set_pose(sapien.Pose(p=[x, s.spawn_y, z], q=[np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]))
        self.belt_speed = s.speeds[SPEEDS.index(speed)]
        self.truth = dict(kind=kind, variant=variant, alignment=alignment, speed=speed, belt_speed=self.belt_speed, yaw=yaw, x=x)
        self._obj_body = self.obj._bodies[0]
        self._obj_mass = self._obj_body.get_mass()
        self._obj_half_height = self.object_half_heights[(kind, variant)]
        self._start_velocity = True
        # Sensing state and MDP state.
        self.phase = "initial"
        self.sensed_speed: str | None = None
        self.sensed_alignment: str | None = None
        self.last_coord: int | None = None
        self.prepick_choice: int | None = None
        self.sim_time = 0.0
        self.gate_times: list[float | None] = [None, None]
        n_rays = len(s.align_ray_x)
        self.ray_log: dict = dict(  # raw readings; nan until a ray has fired
            gate_distances=[np.nan, np.nan], gate_times=[np.nan, np.nan], align_distances=[np.nan] * n_rays, speed_estimate=np.nan,
        )
        self.outcome = "pending"
        self.results: list[PrimitiveResult] = []
        self.last[0] = self._initial_last()
        self._episode_ready = True
        if self.prims is not None:
            self.prims.reset()

    # ------------------------------------------------------------------ belt and sensors
    def _on_belt(self, p: np.ndarray) -> bool:
        s = self.conveyor
        bottom = p[2] - self._obj_half_height
        return (
            abs(p[0] - s.belt_x) <= s.belt_width / 2 and s.belt_y[0] <= p[1] <= s.belt_y[1]
            and bottom <= s.belt_top + 0.004
        )

    def _before_simulation_step(self):
        if not self._episode_ready:
            return
        p = self._obj_body.entity_pose.p
        if not self._on_belt(p):
            return
        if self._start_velocity:  # objects are put on the belt already moving with it
            self._obj_body.set_linear_velocity([0.0, self.belt_speed, 0.0])
            self._start_velocity = False
        v = self._obj_body.get_linear_velocity()
        slip = np.array([0.0 - v[0], self.belt_speed - v[1], 0.0])
        force = self._obj_mass * slip / self.conveyor.belt_response
        cap = self.conveyor.belt_grip * self._obj_mass * GRAVITY
        norm = float(np.linalg.norm(force))
        if norm > cap:
            force *= cap / norm
        self._obj_body.add_force_torque(force, [0.0, 0.0, 0.0])

    def _after_simulation_step(self):
        if not self._episode_ready:
            return
        self.sim_time += self.sim_timestep
        if self.phase == "initial":
            self._sense()

    def _ray(self, origin, direction, distance) -> float:
        """Distance to the object along one ray, or inf when the ray hits nothing or something else."""
        hit = self.scene.px.raycast(np.asarray(origin, np.float32), np.asarray(direction, np.float32), float(distance))
        if hit is None or hit.component is not self._obj_body:
            return float("inf")
        return float(hit.distance)

    def _sense(self):
        s = self.conveyor
        span = s.belt_width + 0.1
        for g, y in enumerate(s.gate_y):
            if self.gate_times[g] is not None:
                continue
            d = self._ray([s.belt_x - span / 2, y, s.belt_top + s.gate_height], [1.0, 0.0, 0.0], span)
            if np.isfinite(d):
                self.gate_times[g] = self.sim_time
                self.ray_log["gate_distances"][g] = d
                self.ray_log["gate_times"][g] = self.sim_time
        if self.gate_times[1] is not None and self.sensed_alignment is None:
            top = s.belt_top + s.align_ray_height
            dists = [self._ray([s.belt_x + dx, s.gate_y[1] - 0.005, top], [0.0, 0.0, -1.0], s.align_ray_height) for dx in s.align_ray_x]
            self.ray_log["align_distances"] = dists
            hits = [dx for dx, d in zip(s.align_ray_x, dists) if np.isfinite(d)]
            if hits:
                centre = float(np.mean(hits))
                self.sensed_alignment = ALIGNMENTS[int(np.argmin([abs(centre - o) for o in s.lane_offsets]))]
            if self.gate_times[0] is not None:
                dt = self.gate_times[1] - self.gate_times[0]
                v = (s.gate_y[1] - s.gate_y[0]) / max(dt, 1e-6)
                self.sensed_speed = SPEEDS[int(np.argmin([abs(v - c) for c in s.speeds]))]
                self.ray_log["speed_estimate"] = v

    # ------------------------------------------------------------------ step hooks
    @property
    def primitive_programs(self):
        return {"wait": self._wait_program, "pre_pick": self._pre_pick_program, "grasp": self._grasp_program}

    @property
    def _lockstep(self) -> LockstepExecutor:
        if self.prims is None:
            v, a = self.conveyor.arm_velocity, self.conveyor.arm_acceleration
            arm = replace(panda_spec(), max_velocity=v, max_acceleration=a, free_velocity=v, free_acceleration=a)
            self.prims = MotionPrimitives(self, arm=arm, static_actors={"table-workspace", "ground", "bin", "belt"},
                                          seed=self.planner_seed, on_control_step=self._on_control_step)
        return self.prims.executor.lockstep

    def _check_can_step(self) -> None:
        if self.phase == "done":
            raise RuntimeError("the episode is over (one object per episode); call reset()")

    def _action_description(self) -> str:
        return f"one integer index in 0..{self.conveyor.action_n - 1} (the current phase's valid ones: info['action_mask'])"

    def _decode(self, env: int, index: int) -> Decision:
        primitive = PHASE_PRIMITIVES[self.phase]
        return Decision(index, primitive, (index,), valid=index < self.conveyor.num_actions[self.phase])

    def _why_invalid(self, env: int) -> str:
        return f"phase {self.phase!r} has actions 0..{self.conveyor.num_actions[self.phase] - 1}"

    def _on_invalid(self, env: int, decision: Decision) -> None:
        self.outcome = f"invalid action {decision.index} in phase {self.phase!r}"
        self.phase = "done"

    def _failure_reward(self, env: int) -> float:
        return -1.0 if self.reward_scheme in ("negative", "negative_bonus") else 0.0

    def _wait_program(self, env: int, index: int):
        """Hold the arm still and let the belt run until the sensors have the object's alignment and speed (or the
        object is gone past the belt's end); then choose a pre-pick coordinate, or miss it."""
        hold = self.prims.executor.qpos()

        def arrived() -> bool:
            return (self.sensed_alignment is not None and self.sensed_speed is not None) or self.obj.pose.p[0, 1].item() > self.conveyor.belt_y[1]

        yield Motion(hold[None], settle_tol=None, until=arrived, max_settle=int(self.conveyor.wait_timeout * self.control_freq) - 1)
        if self.sensed_alignment is None:
            self.phase, self.outcome = "done", "missed"
        else:
            self.phase = "pre_pick"
        return dict(grasp_success=False, place_success=False)

    def _pre_pick_program(self, env: int, index: int):
        """Reach pre-pick coordinate ``index`` above the belt."""
        self.prepick_choice = self.last_coord = index
        res = yield from self.prims.program("reach", grasp_pose(self.conveyor.prepick_coords[index], self.conveyor.grasp_yaw))
        self.results.append(res)
        if res.ok:
            self.phase = "grasp"
        else:
            self.phase, self.outcome = "done", f"pre-pick failed: {res.stage}: {res.reason}"
        return dict(grasp_success=False, place_success=False, reached=bool(res.ok))

    def _grasp_program(self, env: int, index: int):
        """Descend to grasp coordinate ``index`` under the chosen pre-pick coordinate, close, lift, and place a
        grasped object in the bin."""
        self.last_coord = index
        xyz = self.conveyor.grasp_coord(self.prepick_choice, index)
        res = yield from self.prims.program("grasp", grasp_pose(xyz, self.conveyor.grasp_yaw), target=self.obj_name)
        self.results.append(res)
        placed = False
        if res.grasped:
            place = yield from self.prims.program("place", self.conveyor.bin.region(), target=self.obj_name)
            self.results.append(place)
            placed = place.placed
            self.outcome = "placed" if placed else f"grasped, place failed: {place.stage}: {place.reason}"
        else:
            self.outcome = f"grasp failed: {res.stage}: {res.reason}"
        self.phase = "done"
        return dict(grasp_success=bool(res.grasped), place_success=bool(placed), placed_objects=int(bool(placed)))

    def _judge(self, env: int, decision: Decision, result: dict, before) -> Judgement:
        if decision.primitive == "grasp":
            reward = self._reward(grasped=result["grasp_success"], placed=result["place_success"])
            return Judgement(reward, result["place_success"], result)
        if self.phase == "done":  # missed, or the pre-pick coordinate could not be reached
            return Judgement(self._reward(grasped=False, placed=False), False, result)
        return Judgement(0.0, True, result)

    def _episode_end(self, faults):
        return np.array([self.phase == "done"]), np.zeros(1, dtype=bool)

    # ------------------------------------------------------------------ observation, evaluation, reward
    def state_id(self) -> int:
        """The current discrete state id."""
        return self.conveyor.encode_state(self.phase, self.sensed_speed, self.sensed_alignment, self.last_coord)

    def get_obs(self, info: dict | None = None, unflattened: bool = False):
        return torch.tensor([self.state_id()], dtype=torch.int64, device=self.device)

    def _env_info(self, env: int) -> dict:
        region = self.conveyor.bin.region()
        p = self.obj.pose.p[0].cpu().numpy()
        mask = np.zeros(self.conveyor.action_n, dtype=bool)
        if self.phase != "done":
            mask[: self.conveyor.num_actions[self.phase]] = True
        return dict(
            success=self.outcome == "placed",
            fail=self.phase == "done" and self.outcome != "placed",
            phase=self.phase,
            sensed_speed=self.sensed_speed or UNKNOWN,
            sensed_alignment=self.sensed_alignment or UNKNOWN,
            last_coord=-1 if self.last_coord is None else self.last_coord,
            action_mask=mask,
            outcome=self.outcome,
            rays={k: list(v) if isinstance(v, list) else v for k, v in self.ray_log.items()},
            object_in_bin=bool(region.contains(p, margin=0.01)),
            truth=dict(self.truth),
        )

    def _reward(self, grasped: bool, placed: bool) -> float:
        if placed:
            r = 1.0
        elif grasped:
            r = 0.5
        else:
            r = -1.0 if self.reward_scheme in ("negative", "negative_bonus") else 0.0
        if self.reward_scheme in ("bonus", "negative_bonus") and self.is_optimal_choice():
            r += 1.0
        return r

    def is_optimal_choice(self) -> bool:
        """True when the chosen pre-pick and grasp coordinates are the hand-marked best for the sensed case."""
        if self.sensed_alignment is None or self.sensed_speed is None:
            return False
        return self.conveyor.best(self.sensed_alignment, self.sensed_speed) == (self.prepick_choice, self.last_coord)

