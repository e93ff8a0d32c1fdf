"""Motion primitives of the pick-and-place robot: pick, place and slide, planned and executed.

Each primitive plans with OMPL (free-space motions), chained IK (straight segments), checks the result in
the simulator (finger gap and lift for a grasp, landing inside the bin for a place, object displacement for a
slide) and returns a :class:`PrimitiveResult`: ``ok``, the stage that failed and why. A planning failure is a
result, never an exception, so one bad action never kills an episode.

Every primitive is a program (:data:`~maniskill_pnp.planning.lockstep.Program`): its stages plan, then yield the
:class:`~maniskill_pnp.planning.lockstep.Motion` to execute. Calling ``prims.pick(...)`` runs the program at once on
the primitives' own env; ``prims.program("pick", ...)`` returns it unrun, so that the programs of all envs of a
batched (GPU) env, one :class:`MotionPrimitives` per env sharing one
:class:`~maniskill_pnp.planning.lockstep.LockstepExecutor`, execute together through
:func:`~maniskill_pnp.planning.lockstep.drive`. One CPU env takes the same path with ``num_envs = 1``.

Example:
    >>> prims = MotionPrimitives(env)                      # env: a ManiSkill env in pd_joint_pos mode
    >>> res = prims.pick(grasp_pose(cube_xyz, yaw=0.3), target="cube")
    >>> res.ok, res.stage, res.reason
    >>> prims.place(PlaceRegion(center=bin_xyz, half_size=(0.1, 0.1, 0.05)), target="cube")
    >>> lockstep = LockstepExecutor(gpu_env, panda_spec())  # a batched env: one MotionPrimitives per env
    >>> per_env = [MotionPrimitives(gpu_env, lockstep=lockstep, env_idx=i) for i in range(gpu_env.num_envs)]
    >>> results = drive(lockstep, [p.program("slide", start[i], direction[i]) for i, p in enumerate(per_env)])
"""

from __future__ import annotations

import time
from collections.abc import Collection
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import sapien
import torch

from maniskill_pnp.planning.collision import CollisionWorld, actor_pose
from maniskill_pnp.planning.executor import SimExecutor
from maniskill_pnp.planning.lockstep import LockstepExecutor, Motion, Program, drive
from maniskill_pnp.planning.kinematics import Kinematics, quat_angle
from maniskill_pnp.planning.robot import ArmSpec, panda_spec
from maniskill_pnp.planning.rrt import JointSpacePlanner, PlanCache
from maniskill_pnp.planning.trajectory import time_parameterize

# The TCP frame of ManiSkill's Panda points its z axis out of the fingers; a top-down grasp turns it to -z.
_TOP_DOWN = sapien.Pose(q=[0.0, 1.0, 0.0, 0.0])


def grasp_pose(position: np.ndarray, yaw: float) -> sapien.Pose:
    """Top-down parallel-jaw TCP pose at ``position`` (world, m) with the jaws closing across ``yaw`` (rad).

    ``yaw`` is the angle of the closing direction (the line between the fingers) from the world x axis.
    """
    # The TCP's y axis is the closing direction; after the top-down flip it points along -y, so turn by yaw + 90°.
    a = yaw + np.pi / 2
    turn = sapien.Pose(q=[np.cos(a / 2), 0.0, 0.0, np.sin(a / 2)])
    return sapien.Pose(p=np.asarray(position, dtype=np.float64)) * turn * _TOP_DOWN


@dataclass(frozen=True)
class PlaceRegion:
    """An axis-aligned box region where placed objects must come to rest (e.g. the inside of a bin).

    Attributes:
        center: Centre of the region's floor (world, m).
        half_size: Half extents (x, y, z) of the region above its floor (m).
        drop_height: Height above the floor at which the object is released (m).
    """

    center: tuple[float, float, float]
    half_size: tuple[float, float, float]
    drop_height: float = 0.15

    def contains(self, point: np.ndarray, margin: float = 0.0) -> bool:
        """True when ``point`` lies inside the region (grown by ``margin``)."""
        d = np.abs(np.asarray(point)[:2] - np.asarray(self.center)[:2])
        z = float(point[2]) - float(self.center[2])
        return bool(np.all(d <= np.asarray(self.half_size[:2]) + margin) and -margin <= z <= 2 * self.half_size[2] + margin)


@dataclass
class PrimitiveResult:
    """What a primitive did.

    Attributes:
        ok: True when every stage succeeded (and the sensed outcome matched).
        stage: The stage that failed, or ``"done"``.
        reason: Why it failed ("" when ok).
        grasped: A grasp was sensed (fingers stopped on an object and the object came up).
        placed: The object came to rest inside the place region.
        moved: Displacement (m) of the pushed object by a slide, when a target was named.
        held: Name of the object in the gripper after the primitive, if any.
        held_at_release: Place: whether the grasp sensor still felt the object when the gripper opened over the
            place region (False: it had dropped on the way); None when the gripper never opened.
        planning_time: Seconds spent in IK, RRT-Connect, time parameterization and the collision-world syncs.
        sim_steps: Physics steps executed.
        stages: Per-stage log: (stage name, ok, detail).
    """

    ok: bool = False
    stage: str = ""
    reason: str = ""
    grasped: bool = False
    placed: bool = False
    moved: float = 0.0
    held: str | None = None
    held_at_release: bool | None = None
    planning_time: float = 0.0
    sim_steps: int = 0
    stages: list[tuple[str, bool, str]] = field(default_factory=list)


class _StageFailed(Exception):
    def __init__(self, stage: str, reason: str):
        super().__init__(f"{stage}: {reason}")
        self.stage, self.reason = stage, reason


class MotionPrimitives:
    """Pick, place and slide for the Panda of a ManiSkill env.

    Args:
        env: ManiSkill env (``control_mode="pd_joint_pos"``, one sub-scene).
        arm: The arm description (ManiSkill's Panda by default).
        static_actors: Names of actors that never move (table, bin, belt...). Everything else with a collision
            shape counts as a movable object.
        non_obstacles: Actor names never treated as obstacles (e.g. visual goal markers).
        time_budget: Seconds RRT-Connect may search per free-space motion.
        clearance: Margin (m) by which obstacles grow for free-space motions (kept when start and goal allow).
        cache: Plan cache shared across calls (a fresh one by default).
        seed: Seed of IK restarts and OMPL.
        on_control_step: Callback after every control step (video recording).
        lockstep: The executor of all envs, shared by the per-env primitives of a batched env (a new one by default).
        env_idx: The env (sub-scene) these primitives plan for, sense and move.
        guard_force: Guarded descents: a grasp's descent and a slide's lowering stop, and the primitive fails, as soon
            as the contacts push the fingers or the hand up by more than this (N), like a real arm's collision reflex
            (see :attr:`GUARD_LINKS`); None (default): descents go to their depth whatever they strike.
    """

    #: Links whose upward contact force a guarded descent watches.
    GUARD_LINKS = ("panda_leftfinger", "panda_rightfinger", "panda_hand")

    #: The primitives :meth:`program` can build.
    PRIMITIVES = ("pick", "reach", "grasp", "place", "slide", "move_to", "go_home")

    #: Height of the pre-grasp pose above the grasp (m).
    PREGRASP_HEIGHT = 0.10
    #: Height the object is lifted after closing (m).
    LIFT_HEIGHT = 0.15
    #: Lift heights (m) tried in turn when the straight line up has no valid path (a joint jump near a singularity
    #: at the edge of the reach, a joint limit, a collision): each still lifts an object past :attr:`LIFTED`.
    LIFT_FALLBACKS = (0.10, 0.07)
    #: Fingers closer than this (m, per finger) mean the jaws closed on nothing.
    EMPTY_GAP = 0.002
    #: An object counts as lifted when it rose at least this much (m).
    LIFTED = 0.05
    #: Most control steps given to the gripper to close or open.
    GRIPPER_STEPS = 12
    #: Fewest control steps of a gripper command; after them it ends once the fingers have stopped (see
    #: :meth:`_gripper`).
    GRIPPER_MIN_STEPS = 2
    #: The fingers count as stopped when neither moved more than this (m) in the last control step...
    FINGERS_STILL = 0.0002
    #: ...or, opening, when both are within this (m) of open.
    OPEN_ENOUGH = 0.0015
    #: Heights (m) above the place region's drop height tried in turn for the release pose: where the held object
    #: would collide at the drop height (a filling bin, an object held off its centre), it is released higher.
    PLACE_LIFTS = (0.0, 0.08, 0.16)

    def __init__(
        self,
        env,
        *,
        arm: ArmSpec | None = None,
        static_actors: Collection[str] = (),
        non_obstacles: Collection[str] = ("goal_site",),
        time_budget: float = 2.0,
        clearance: float = 0.015,
        cache: PlanCache | None = None,
        seed: int = 0,
        on_control_step=None,
        lockstep: LockstepExecutor | None = None,
        env_idx: int = 0,
        guard_force: float | None = None,
    ):
        self.env = env.unwrapped
        self.arm = arm or panda_spec()
        self.executor = SimExecutor(env, self.arm, on_control_step, lockstep=lockstep, env_idx=env_idx)
        self.env_idx = env_idx
        base = self.env.agent.robot.pose.raw_pose[env_idx].cpu().numpy()
        self.world = CollisionWorld(self.arm, base_pose=base)
        self.kin = Kinematics(self.world, seed=seed)
        self.planner = JointSpacePlanner(self.world, time_budget=time_budget, cache=cache or PlanCache(), seed=seed)
        self.static_actors = frozenset(static_actors)
        self.non_obstacles = frozenset(non_obstacles)
        self.home = self.arm.home.copy()
        self.clearance = clearance
        self._ignored: set[str] = set()
        self._planning_time = 0.0
        self._defer = False
        self.held: str | None = None
        self.guard_force = check_guard_force(guard_force)

    def reset(self) -> None:
        """Forget per-episode state (held object, last gripper command); call after every ``env.reset``.

        The collision model, IK and the plan cache stay: one instance serves a whole training run.
        """
        self.held = None
        self.executor.reset()

    # ================================================================== primitives
    def pick(self, pose: sapien.Pose, target: str | None = None, *, candidates: Collection[str] | None = None) -> PrimitiveResult:
        """Pre-grasp above ``pose``, straight descent, close the jaws, lift.

        Args:
            pose: Grasp TCP pose (world); see :func:`grasp_pose`. Its 180° twin about the vertical is
                equivalent for parallel jaws; the one nearer the current configuration is used.
            target: Name of the object to grasp when known (it may be touched during the descent). When None,
                the descent may touch any movable object and the grasped object is found from finger contacts.
            candidates: Objects that can be grasped, for finding the held one (default: every movable object).

        Returns:
            ``grasped`` is the jaw sensor: fingers stopped short of closing and the object came up.
        """
        return self._run(self._pick, pose, target, candidates)

    def reach(self, pose: sapien.Pose) -> PrimitiveResult:
        """Move the TCP to ``pose`` (or its 180° twin about the vertical) by IK and an OMPL plan.

        The first half of :meth:`pick`; tasks that choose the approach point themselves (the conveyor's
        pre-pick coordinates) call it directly.
        """
        return self._run(self._reach, pose)

    def grasp(self, pose: sapien.Pose, target: str | None = None, *, candidates: Collection[str] | None = None) -> PrimitiveResult:
        """From wherever the TCP is, a straight line to ``pose``, close the jaws, lift; the second half of :meth:`pick`.

        Arguments and the ``grasped`` sensing are as for :meth:`pick`.
        """
        return self._run(self._grasp, pose, target, candidates)

    def place(self, region: PlaceRegion, target: str | None = None) -> PrimitiveResult:
        """Carry the held object above ``region``, release it, and check it came to rest inside."""
        return self._run(self._place, region, target)

    def slide(self, start: np.ndarray, direction: np.ndarray, length: float = 0.08, *, target: str | None = None) -> PrimitiveResult:
        """Lower the closed gripper tip at ``start`` and push it ``length`` m along ``direction`` (horizontal).

        Args:
            start: Where the fingertips go down (world, m); its z is the tip height during the push.
            direction: Push direction in the table plane (x, y), any length.
            length: Push length (m); the thesis uses 8 cm.
            target: An object whose displacement is reported in ``moved``.
        """
        return self._run(self._slide, np.asarray(start, np.float64), np.asarray(direction, np.float64), float(length), target)

    def move_to(self, q_goal: np.ndarray) -> PrimitiveResult:
        """Plan (RRT-Connect, every object an obstacle, a held one carried along) and move to arm joints ``q_goal``."""
        return self._run(self._move_free, np.asarray(q_goal, dtype=np.float64), "move")

    def go_home(self) -> PrimitiveResult:
        """Plan and move to the home configuration (above the workspace, out of the cameras' way)."""
        return self._run(self._move_free, self.home, "go_home")

    def program(self, primitive: str, *args, **kwargs) -> Program:
        """The program of ``primitive`` (one of :data:`PRIMITIVES`, with that method's arguments), not yet run: a
        generator for :func:`~maniskill_pnp.planning.lockstep.drive` that returns the :class:`PrimitiveResult`."""
        if primitive not in self.PRIMITIVES:
            raise ValueError(f"unknown primitive {primitive!r}; valid: {self.PRIMITIVES}")
        self._defer = True
        try:
            return getattr(self, primitive)(*args, **kwargs)
        finally:
            self._defer = False

    # ================================================================== stage logic (generators of Motions)
    def _pick(self, res: PrimitiveResult, pose: sapien.Pose, target: str | None, candidates) -> None:
        self._check_target(target)
        yield from self._reach(res, sapien.Pose(p=pose.p + [0.0, 0.0, self.PREGRASP_HEIGHT], q=pose.q), "pregrasp")
        yield from self._grasp(res, pose, target, candidates)

    def _reach(self, res: PrimitiveResult, pose: sapien.Pose, stage: str = "reach") -> None:
        # Free-space motion: every object is an obstacle.
        self._sync()
        ik = self._timed(self.kin.ik_any, grasp_twins(pose), self.executor.qpos())
        if not ik.ok:
            raise _StageFailed(f"{stage}_ik", ik.reason)
        yield from self._move_to(ik.q, f"move_to_{stage}", res)

    def _grasp(self, res: PrimitiveResult, pose: sapien.Pose, target: str | None, candidates) -> None:
        movable = self._check_target(target)
        yield self._gripper(1.0, self.GRIPPER_STEPS if self._fingers_closed() else 0)
        # Straight descent: the target (or, when unknown, any movable object) may be touched.
        self._sync(ignore={target} if target else movable)
        fk = self.kin.fk(self.executor.qpos())
        goal = min(grasp_twins(pose), key=lambda p: quat_angle(p.q, fk.q))
        yield from self._straight(goal, "descend", res, guarded=True)
        heights = self._object_heights(movable)
        yield self._gripper(-1.0, self.GRIPPER_STEPS)
        fingers = self.executor.finger_qpos()
        closed_on_something = self.jaws_on_something()
        self._sync(ignore=movable)  # lift straight up through whatever is around the grasp
        self.world.set_fingers(float(np.min(fingers)))
        up = yield from self._lift(goal, res)
        lifted = {n: h for n, h in self._object_heights(movable).items() if h - heights[n] > self.LIFTED}
        pool = set(candidates) if candidates is not None else movable
        held = [n for n in lifted if n in pool and (target is None or n == target)]
        res.grasped = self.jaws_on_something() and closed_on_something and bool(held)
        if not res.grasped:
            why = "jaws closed on nothing" if not closed_on_something else "object slipped or was not lifted"
            if lifted:  # it came up without a grasp (on a finger, or wedged): put it back before going anywhere
                yield from self._put_back(goal, up, sorted(lifted), res)
                why += f"; {sorted(lifted)} came up with the fingers and was put back"
            raise _StageFailed("grasp_check", why)
        self.held = res.held = max(held, key=lambda n: lifted[n])

    def _lift(self, goal: sapien.Pose, res: PrimitiveResult) -> sapien.Pose:
        """Lift straight up by :attr:`LIFT_HEIGHT`, or by the first of :attr:`LIFT_FALLBACKS` that has a straight
        line; return the pose reached. Where none has one, open the jaws where they are before failing, so that the
        way home does not carry the object out of the workspace on closed fingers."""
        start = self.kin.fk(self.executor.qpos()).p
        reasons = []
        for height in (self.LIFT_HEIGHT, *self.LIFT_FALLBACKS):
            up = sapien.Pose(p=start + [0.0, 0.0, height], q=goal.q)
            seg = self._timed(self.kin.straight_line, self.executor.qpos(), up)
            if seg.ok:
                yield from self._execute(seg.path, "lift", res, f"{height:.2f} m up, {len(seg.path)} waypoints")
                return up
            reasons.append(f"{height:.2f} m: {seg.reason}")
        yield self._gripper(1.0, self.GRIPPER_STEPS)
        raise _StageFailed("lift", "no straight lift (" + "; ".join(reasons) + "); the jaws opened where they were")

    def _put_back(self, down: sapien.Pose, up: sapien.Pose, names: list[str], res: PrimitiveResult) -> None:
        """Lower the jaws back to ``down``, open them and rise to ``up`` again, so that objects that came up
        without a grasp stay in the workspace instead of riding on the gripper (a straight move that fails is
        skipped: the jaws then open where they are)."""
        for pose, stage in ((down, "put_back"), (None, None), (up, "put_back_lift")):
            if pose is None:
                yield self._gripper(1.0, self.GRIPPER_STEPS)
                for name in names:
                    yield self._wait_at_rest(name)
                continue
            try:
                yield from self._straight(pose, stage, res)
            except _StageFailed as e:
                res.stages.append((e.stage, False, e.reason))

    def _check_target(self, target: str | None) -> set[str]:
        movable = self._movable()
        if target is not None and target not in movable:
            raise _StageFailed("input", f"unknown object {target!r}; movable objects: {sorted(movable)}")
        return movable

    def _place(self, res: PrimitiveResult, region: PlaceRegion, target: str | None) -> None:
        name = target or self.held
        if name is None:
            raise _StageFailed("input", "nothing is held: pick an object first or name the target")
        if name not in self.env.scene.actors:
            raise _StageFailed("input", f"unknown object {name!r}")
        res.held = name
        self._sync(ignore={name})
        self._attach(name)
        try:
            q_now = self.executor.qpos()
            tcp = self.kin.fk(q_now)
            yaw_turns = [sapien.Pose(q=[np.cos(a / 2), 0.0, 0.0, np.sin(a / 2)]) for a in (0.0, np.pi / 2, np.pi, -np.pi / 2)]
            for lift in self.PLACE_LIFTS:  # the lowest release pose whose IK is free of collisions
                drop = np.asarray(region.center, np.float64) + [0.0, 0.0, region.drop_height + lift]
                poses = [sapien.Pose(p=drop) * t * sapien.Pose(q=tcp.q) for t in yaw_turns]
                ik = self._timed(self.kin.ik_any, poses, q_now)
                if ik.ok:
                    break
            else:
                raise _StageFailed("place_ik", f"{ik.reason} (release up to {max(self.PLACE_LIFTS):.2f} m above the drop height)")
            yield from self._move_to(ik.q, "carry", res)
        finally:
            self.world.detach()
        res.held_at_release = self.jaws_on_something()
        yield self._gripper(1.0, self.GRIPPER_STEPS)
        self.held = None
        yield self._wait_at_rest(name)
        pos = self._actor_position(name)
        res.placed = region.contains(pos, margin=0.01)
        if not res.placed:
            raise _StageFailed("place_check", f"object came to rest at {np.round(pos, 3).tolist()}, outside the place region")

    def _slide(self, res: PrimitiveResult, start: np.ndarray, direction: np.ndarray, length: float, target: str | None) -> None:
        d = np.array([direction[0], direction[1], 0.0])
        if start.shape != (3,) or np.linalg.norm(d) < 1e-9 or not np.isfinite(start).all():
            raise _StageFailed("input", "slide needs a finite 3-D start and a non-zero horizontal direction")
        if not length > 0:
            raise _StageFailed("input", f"slide length must be positive, got {length}")
        d /= np.linalg.norm(d)
        before = self._actor_position(target) if target else None
        # Jaws closed, across the push direction so the closed fingers form a flat pusher.
        yaw = float(np.arctan2(d[1], d[0])) + np.pi / 2
        tip = grasp_pose(start, yaw)
        yield self._gripper(-1.0, self.GRIPPER_STEPS if not self._fingers_closed() else 0)
        above = sapien.Pose(p=start + [0.0, 0.0, self.PREGRASP_HEIGHT], q=tip.q)
        yield from self._reach(res, above, "preslide")
        movable = self._movable()
        self._sync(ignore=movable)  # the tip may come down on, and then push, any movable object
        q_tcp = self.kin.fk(self.executor.qpos()).q
        yield from self._straight(sapien.Pose(p=start, q=q_tcp), "lower", res, guarded=True)
        yield from self._straight(sapien.Pose(p=start + length * d, q=q_tcp), "push", res)
        yield from self._straight(sapien.Pose(p=start + length * d + [0.0, 0.0, self.PREGRASP_HEIGHT], q=q_tcp), "retract", res)
        if target:
            after = self._actor_position(target)
            res.moved = float(np.linalg.norm((after - before)[:2]))

    def _move_free(self, res: PrimitiveResult, q_goal: np.ndarray, stage: str) -> None:
        if q_goal.shape != (self.arm.arm_joints,) or not np.isfinite(q_goal).all():
            raise _StageFailed("input", f"a configuration is {self.arm.arm_joints} finite joint values, got {q_goal}")
        self._sync()
        if self.held:
            self._attach(self.held)
        try:
            yield from self._move_to(q_goal, stage, res)
        finally:
            self.world.detach()

    # ================================================================== helpers
    def _run(self, fn, *args) -> PrimitiveResult | Program:
        """Run the program of stage function ``fn`` on this env now (or return it unrun, for :meth:`program`)."""
        program = self._program(fn, *args)
        if self._defer:
            return program
        lockstep = self.executor.lockstep
        return drive(lockstep, [program if i == self.env_idx else None for i in range(lockstep.num_envs)])[self.env_idx]

    def _program(self, fn, *args) -> Program:
        res = PrimitiveResult()
        steps0, self._planning_time = self.executor.sim_steps, 0.0
        try:
            yield from fn(res, *args)
            res.ok, res.stage = True, "done"
        except _StageFailed as e:
            res.ok, res.stage, res.reason = False, e.stage, e.reason
            res.stages.append((e.stage, False, e.reason))
        res.planning_time = self._planning_time
        res.sim_steps = self.executor.sim_steps - steps0
        if res.held is None and self.held is not None and fn != self._place:
            res.held = self.held
        return res

    @contextmanager
    def _planning(self):
        """Count the block's time as planning (IK, plans, time parameterization and the collision-world syncs
        they need), the rest of a primitive's time being its execution."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._planning_time += time.perf_counter() - t0

    def _timed(self, fn, *args, **kwargs):
        with self._planning():
            return fn(*args, **kwargs)

    def _move_to(self, q_goal: np.ndarray, stage: str, res: PrimitiveResult) -> None:
        """Free-space motion: plan with the clearance margin; without it only when start or goal lie inside it."""
        with self._planning():
            self.world.sync_scene(self.env.scene, ignore=self._ignored, env_idx=self.env_idx, skip=self.non_obstacles,
                                  margin=self.clearance)
            plan = self.planner.plan(self.executor.qpos(), q_goal)
            if not plan.ok and plan.reason.startswith(("start", "goal")):
                self.world.sync_scene(self.env.scene, ignore=self._ignored, env_idx=self.env_idx,
                                      skip=self.non_obstacles)
                plan = self.planner.plan(self.executor.qpos(), q_goal)
        detail = ""
        if not plan.ok and plan.reason.startswith("start"):
            # The arm already touches movable objects (a failed lift or retract left it among them): moving away is
            # what frees it, so those objects are no obstacles for this motion.
            with self._planning():
                touching = {other for _, other in self.world.collisions(self.executor.qpos())} & self._movable()
                if touching:
                    self.world.sync_scene(self.env.scene, ignore=self._ignored | touching, env_idx=self.env_idx,
                                          skip=self.non_obstacles)
                    plan = self.planner.plan(self.executor.qpos(), q_goal)
                detail = f", leaving {sorted(touching)} that the arm touched at the start"
        if not plan.ok:
            raise _StageFailed(stage, plan.reason)
        yield from self._execute(plan.path, stage, res, ("cached plan" if plan.cached else f"{len(plan.path)} waypoints") + detail,
                                 free=True)

    def _straight(self, goal: sapien.Pose, stage: str, res: PrimitiveResult, guarded: bool = False) -> None:
        seg = self._timed(self.kin.straight_line, self.executor.qpos(), goal)
        if not seg.ok:
            raise _StageFailed(stage, seg.reason)
        guard = _Guard(self) if guarded and self.guard_force is not None else None
        yield from self._execute(seg.path, stage, res, f"{len(seg.path)} waypoints", stop=guard)
        if guard is not None and guard.tripped is not None:
            above = float(self.kin.fk(self.executor.qpos()).p[2] - goal.p[2])
            raise _StageFailed(stage, f"guarded move stopped on contact: {guard.tripped:.1f} N up on the gripper "
                                      f"(limit {self.guard_force:g} N), {above * 1000:.0f} mm above its goal")

    def _execute(self, path: np.ndarray, stage: str, res: PrimitiveResult, detail: str, stop=None,
                 free: bool = False) -> None:
        traj = self._timed(time_parameterize, path, self.executor.dt, *self.arm.limits(free))
        err = yield Motion(traj, stop=stop)
        res.stages.append((stage, True, f"{detail}, {len(traj)} control steps, final error {err:.3f} rad"))

    def _sync(self, ignore: Collection[str] = ()) -> None:
        self._ignored = set(ignore) | ({self.held} if self.held else set())
        with self._planning():
            self.world.sync_scene(self.env.scene, ignore=self._ignored, env_idx=self.env_idx, skip=self.non_obstacles)
            self.world.set_fingers(float(np.min(self.executor.finger_qpos())))

    def _attach(self, name: str) -> None:
        """Add the held object's bounding box (in the TCP frame) to the arm for collision checks."""
        with self._planning():
            meshes = self.env.scene.actors[name].get_collision_meshes(to_world_frame=True)
            mesh = meshes[self.env_idx if len(meshes) > 1 else 0]
            inv = self.kin.fk(self.executor.qpos()).inv().to_transformation_matrix()
            v = np.asarray(mesh.vertices) @ inv[:3, :3].T + inv[:3, 3]
            lo, hi = v.min(0), v.max(0)
            self.world.attach_box((hi - lo) / 2 + 0.005, np.concatenate([(hi + lo) / 2, [1.0, 0.0, 0.0, 0.0]]))

    def _movable(self) -> set[str]:
        names = set()
        for name, actor in self.env.scene.actors.items():
            if name in self.static_actors or name in self.non_obstacles:
                continue
            if actor.px_body_type == "dynamic":
                names.add(name)
        return names

    def jaws_on_something(self) -> bool:
        """The gripper's grasp sensor: the fingers, closing, stopped apart on something (their gap above
        :attr:`EMPTY_GAP`)."""
        return bool(np.min(self.executor.finger_qpos()) > self.EMPTY_GAP)

    def _fingers_closed(self) -> bool:
        return bool(np.max(self.executor.finger_qpos()) < self.arm.gripper_open - 0.005)

    def _actor_position(self, name: str) -> np.ndarray:
        return np.asarray(actor_pose(self.env.scene.actors[name], self.env_idx).p, dtype=np.float64)

    def _object_heights(self, names: Collection[str]) -> dict[str, float]:
        return {n: float(self._actor_position(n)[2]) for n in names}

    def _gripper(self, command: float, steps: int) -> Motion:
        """The gripper command for at most ``steps`` control steps, the arm held where it is: after
        :attr:`GRIPPER_MIN_STEPS` it ends as soon as the fingers stopped (closed on an object or on each other, or
        open). Fingers that close on an object stall in 3-5 steps, and their drives then press with the force they
        would press with after all 12 (a joint-position drive at rest); opening is at 96% after 7."""
        if steps <= 0:
            return Motion(gripper=command, settle_tol=None)
        least = min(steps, self.GRIPPER_MIN_STEPS)
        last = [self.executor.finger_qpos()]

        def stopped() -> bool:
            now = last[0], self.executor.finger_qpos()
            last[0] = now[1]
            if command > 0 and np.min(now[1]) >= self.arm.gripper_open - self.OPEN_ENOUGH:
                return True
            return bool(np.max(np.abs(now[1] - now[0])) < self.FINGERS_STILL)

        return Motion(gripper=command, min_steps=least, settle_tol=None, until=stopped, max_settle=steps - least)

    def _wait_at_rest(self, name: str, max_steps: int = 40) -> Motion:
        """Hold the arm (at least one step, at most ``max_steps``) until actor ``name`` moves slower than 1 cm/s."""
        actor = self.env.scene.actors[name]

        def at_rest() -> bool:
            return torch.linalg.norm(actor.linear_velocity[self.env_idx]).item() < 0.01

        return Motion(self.executor.qpos()[None], settle_tol=None, until=at_rest, max_settle=max_steps - 1)


def check_guard_force(guard_force) -> float | None:
    """``guard_force`` as a float (N), or None (unguarded); a ValueError names anything else."""
    if guard_force is None:
        return None
    if isinstance(guard_force, bool) or not isinstance(guard_force, (int, float, np.number)) or not guard_force > 0:
        raise ValueError(f"guard_force must be a positive force in N, or None (unguarded), got {guard_force!r}")
    return float(guard_force)


class _Guard:
    """The stop test of a guarded move: true once the contacts on :attr:`MotionPrimitives.GUARD_LINKS` push up by
    more than ``guard_force`` (the largest upward component over those links, in N); remembers that force
    (``tripped``, None while it has not tripped)."""

    def __init__(self, prims: MotionPrimitives):
        self.prims, self.tripped = prims, None

    def __call__(self) -> bool:
        p = self.prims
        forces = p.env.agent.robot.get_net_contact_forces(p.GUARD_LINKS)
        up = float(forces[p.env_idx if forces.shape[0] > 1 else 0, :, 2].max())
        if up <= p.guard_force:
            return False
        self.tripped = up
        return True


def grasp_twins(pose: sapien.Pose) -> list[sapien.Pose]:
    """A parallel-jaw pose and its 180° twin about the vertical: the same grasp for symmetric jaws."""
    return [pose, pose * sapien.Pose(q=[0.0, 0.0, 0.0, 1.0])]
