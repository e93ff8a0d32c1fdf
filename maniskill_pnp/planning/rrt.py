"""Joint-space motion planning with OMPL's RRT-Connect, path simplification and a scene-aware plan cache.

The thesis planned the arm's motions with OMPL inside V-REP; here the same planner (RRT-Connect, through
OMPL's official 2.x Python bindings) runs against the FCL collision world built from the ManiSkill scene.

Example:
    >>> planner = JointSpacePlanner(world)
    >>> result = planner.plan(q_now, q_goal)
    >>> result.ok, result.path.shape, result.reason
"""

from __future__ import annotations

import functools
import hashlib
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from maniskill_pnp.planning.collision import CollisionWorld


@dataclass(frozen=True)
class PlanResult:
    """Outcome of a joint-space query.

    Attributes:
        path: Waypoints (N×dof), start and goal included, when a collision-free path was found; else None.
        reason: Why planning failed ("" on success).
        planning_time: Wall-clock seconds spent (0 for a cache hit).
        cached: True when the path came from the plan cache.
    """

    path: np.ndarray | None
    reason: str = ""
    planning_time: float = 0.0
    cached: bool = False

    @property
    def ok(self) -> bool:
        return self.path is not None


class PlanCache:
    """Plans saved for reuse between fixed configurations, keyed by the scene they were planned in.

    The key joins the start and goal (rounded to ``decimals``) with the collision world's fingerprint, so a
    plan is reused only in a scene whose obstacles are the same; a hit is re-checked against the current world
    anyway before use. Least recently used plans are dropped beyond ``capacity``.
    """

    def __init__(self, capacity: int = 256, decimals: int = 3):
        if capacity < 1:
            raise ValueError(f"plan cache capacity must be >= 1, got {capacity}")
        self.capacity = capacity
        self.decimals = decimals
        self._plans: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def key(self, q_start: np.ndarray, q_goal: np.ndarray, scene: str) -> tuple:
        r = lambda q: tuple(np.round(np.asarray(q, dtype=np.float64), self.decimals).tolist())  # noqa: E731
        return r(q_start), r(q_goal), scene

    def get(self, key: tuple) -> np.ndarray | None:
        path = self._plans.get(key)
        if path is None:
            self.misses += 1
            return None
        self._plans.move_to_end(key)
        self.hits += 1
        return path

    def put(self, key: tuple, path: np.ndarray) -> None:
        self._plans[key] = path
        self._plans.move_to_end(key)
        while len(self._plans) > self.capacity:
            self._plans.popitem(last=False)

    def __len__(self) -> int:
        return len(self._plans)


class JointSpacePlanner:
    """RRT-Connect in the arm's joint space, validity from a :class:`CollisionWorld`.

    Args:
        world: Collision world (joint limits, self-collision, scene obstacles).
        time_budget: Default seconds RRT-Connect may search before giving up.
        max_step: RRT-Connect's maximum extension per step (rad).
        resolution: Joint-space distance (rad, L2) between validity checks along a motion; finer than the
            final dense check of :meth:`CollisionWorld.path_valid`, so OMPL rarely returns what that check rejects.
        simplify_steps: Rounds of OMPL's path simplifier on a solution (each: remove redundant vertices, then
            shortcut partially); counted in rounds, not seconds, so a plan does not depend on the machine's load.
        cache: Plan cache (a fresh one by default); pass ``None`` to disable caching.
        attempts: RRT-Connect runs per query before giving up (a new run after a failed final check).
        seed: Base seed of the plans (None: OMPL's own seeding, plans not reproducible). Each RRT-Connect query is
            seeded from this seed, its start, goal and scene alone (:func:`query_seed`), so the same query gives
            the same path whatever was planned before in the process; only a search that runs out of its time
            budget can end differently on a slower machine.
        swept_motions: Check OMPL's motions with :meth:`CollisionWorld.motion_valid` (the same answers as OMPL's
            default validator, faster where the swept link balls certify a stretch clear); False: OMPL's
            default, one state validity call per configuration.
    """

    def __init__(
        self,
        world: CollisionWorld,
        *,
        time_budget: float = 2.0,
        max_step: float = 0.3,
        resolution: float = 0.004,
        simplify_steps: int = 1,
        cache: PlanCache | None | str = "default",
        attempts: int = 3,
        seed: int | None = 0,
        swept_motions: bool = True,
    ):
        from ompl import base as ob
        from ompl import geometric as og
        from ompl import util as ou

        ou.setLogLevel(ou.LOG_WARN)
        self._ou = ou
        self.seed = seed
        self.world = world
        self.time_budget = time_budget
        self.attempts = attempts
        self.cache = PlanCache() if cache == "default" else cache
        dof = world.arm.arm_joints
        self._dof = dof
        self._space = ob.RealVectorStateSpace(dof)
        bounds = ob.RealVectorBounds(dof)
        for i in range(dof):
            bounds.setLow(i, float(world.arm.lower[i]))
            bounds.setHigh(i, float(world.arm.upper[i]))
        self._space.setBounds(bounds)
        self._setup = og.SimpleSetup(self._space)
        self._setup.setStateValidityChecker(self._valid_state)
        si = self._setup.getSpaceInformation()
        si.setStateValidityCheckingResolution(resolution / self._space.getMaximumExtent())
        if swept_motions:
            self._motion_validator = _swept_motion_validator_type()(si, self._space, world)
            si.setMotionValidator(self._motion_validator)
        self._max_step = max_step
        # The space's one-time set-up draws from OMPL's generators; done here, it precedes every seeded search.
        si.setup()
        if simplify_steps < 0:
            raise ValueError(f"simplify_steps must be >= 0, got {simplify_steps!r}")
        self._simplify_steps = int(simplify_steps)
        self._og = og
        self._q = np.zeros(dof)

    def _valid_state(self, state) -> bool:
        q = self._q
        for i in range(self._dof):
            q[i] = state[i]
        return self.world.is_valid(q)

    def _state(self, q: np.ndarray):
        s = self._space.allocState()
        for i in range(self._dof):
            s[i] = float(q[i])
        return s

    def plan(self, q_start: np.ndarray, q_goal: np.ndarray, *, time_budget: float | None = None) -> PlanResult:
        """A collision-free joint path from ``q_start`` to ``q_goal``, or a result that says why there is none.

        Tries the straight joint-space segment first (free when it is valid), then the cache, then RRT-Connect
        with simplification. The caller's scene must already be synced into the collision world.
        """
        q_start = np.asarray(q_start, dtype=np.float64)
        q_goal = np.asarray(q_goal, dtype=np.float64)
        if q_start.shape != (self._dof,) or q_goal.shape != (self._dof,):
            raise ValueError(f"start and goal must be {self._dof} joint values, got {q_start.shape} and {q_goal.shape}")
        for name, q in (("start", q_start), ("goal", q_goal)):
            if not self.world.is_valid(q):
                pairs = self.world.collisions(q)
                why = f"collides ({pairs[0][0]}/{pairs[0][1]})" if pairs else "is outside the joint limits"
                return PlanResult(None, f"{name} configuration {why}")
        t0 = time.perf_counter()
        if self.world.segment_valid(q_start, q_goal):
            return PlanResult(np.stack([q_start, q_goal]), planning_time=time.perf_counter() - t0)
        key = None
        if self.cache is not None:
            key = self.cache.key(q_start, q_goal, self.world.fingerprint())
            path = self.cache.get(key)
            if path is not None and self.world.path_valid(path):
                return PlanResult(path.copy(), cached=True)
        for attempt in range(self.attempts):
            if self.seed is not None:
                _reseed_ompl(self._ou, query_seed(self.seed, q_start, q_goal, self.world.fingerprint(), attempt))
            path, reason = self._rrt_connect(q_start, q_goal, time_budget or self.time_budget)
            if path is not None:
                break
        elapsed = time.perf_counter() - t0
        if path is None:
            return PlanResult(None, reason, planning_time=elapsed)
        if self.cache is not None:
            self.cache.put(key, path)
        return PlanResult(path, planning_time=elapsed)

    def _rrt_connect(self, q_start: np.ndarray, q_goal: np.ndarray, budget: float) -> tuple[np.ndarray | None, str]:
        ss = self._setup
        # A new RRT-Connect per search: its sampler and trees take their generators from OMPL's (re)seeded seed
        # generator (a cleared planner keeps state from earlier searches, so its next search would not repeat).
        rrt = self._og.RRTConnect(ss.getSpaceInformation())
        rrt.setRange(self._max_step)
        ss.setPlanner(rrt)
        ss.clear()  # and no solution of an earlier search
        ss.setStartAndGoalStates(self._state(q_start), self._state(q_goal))
        ss.solve(budget)
        if not ss.haveExactSolutionPath():  # solve() is truthy for approximate solutions too
            return None, f"RRT-Connect found no collision-free path in {budget:.1f} s"
        solution = ss.getSolutionPath()
        raw = self._states(solution, q_start, q_goal)
        # A simplifier of this query (its generator seeded as the search's), run for a fixed number of rounds:
        # OMPL's time-bounded simplifySolution finishes its current pass past the bound (seconds over a 0.2 s
        # budget on 2 busy cores) and shortens a path by as much as the machine's load lets it.
        simplifier = self._og.PathSimplifier(ss.getSpaceInformation())
        shortened = self._og.PathGeometric(solution)
        for _ in range(self._simplify_steps):
            simplifier.reduceVertices(shortened)
            simplifier.partialShortcutPath(shortened)
        # OMPL and the final dense check sample a motion at different points, so a path that grazes an obstacle
        # can pass one and fail the other; the simplifier's shortcuts are the usual culprits. The raw RRT-Connect
        # path is then the fallback before a new search.
        for path in (self._states(shortened, q_start, q_goal), raw):
            if self.world.path_valid(path):
                return path, ""
        return None, "both the simplified and the raw RRT-Connect path failed the final collision check"

    def _states(self, solution, q_start: np.ndarray, q_goal: np.ndarray) -> np.ndarray:
        states = solution.getStates()
        path = np.array([[s[i] for i in range(self._dof)] for s in states], dtype=np.float64)
        path[0], path[-1] = q_start, q_goal
        return path


@functools.cache
def _swept_motion_validator_type():
    """An OMPL motion validator that gives the answers of OMPL's own ``DiscreteMotionValidator`` (the same
    configurations: the motion's end, and the ones between at the space's segment count, each checked as the state
    validity checker checks it) through :meth:`CollisionWorld.motion_valid`, which skips the scene test where a stretch
    of the motion is certified clear of every obstacle."""
    from ompl import base as ob

    class SweptMotionValidator(ob.MotionValidator):
        def __init__(self, si, space, world: CollisionWorld):
            super().__init__(si)
            self._space, self._world, self._dof = space, world, world.arm.arm_joints

        def checkMotion(self, s1, s2) -> bool:
            q0 = np.array([s1[i] for i in range(self._dof)], dtype=np.float64)
            q1 = np.array([s2[i] for i in range(self._dof)], dtype=np.float64)
            return self._world.motion_valid(q0, q1, self._space.validSegmentCount(s1, s2))

    return SweptMotionValidator


def query_seed(seed: int, q_start: np.ndarray, q_goal: np.ndarray, scene: str, attempt: int = 0) -> int:
    """The seed of one planning query: a hash of the planner's ``seed``, the start and goal (to 1e-6 rad), the
    scene's fingerprint and the attempt number, in 1..2**31-1 (OMPL rejects 0)."""
    h = hashlib.sha256()
    h.update(np.int64(seed).tobytes())
    for q in (q_start, q_goal):
        h.update(np.round(np.asarray(q, dtype=np.float64), 6).tobytes())
    h.update(scene.encode())
    h.update(np.int64(attempt).tobytes())
    return 1 + int.from_bytes(h.digest()[:8], "little") % (2**31 - 2)


def _reseed_ompl(ou, seed: int) -> None:
    """Reseed OMPL's process-wide seed generator, from which every new OMPL generator (a planner's sampler, a path
    simplifier) takes its seed. OMPL logs an error when generators were made before ("changing seed now will not
    lead to deterministic sampling"): true of the generators that already exist, which the planner no longer uses,
    so the message is silenced."""
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed))
    finally:
        ou.setLogLevel(level)
