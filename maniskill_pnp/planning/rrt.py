"""Joint-space motion planning with OMPL's RRT-Connect, path simplification and a scene-aware plan cache.

The thesis planned the arm's motions with OMPL inside V-REP; here the same planner (RRT-Connect, through
OMPL's official 2.x Python bindings) runs against the FCL collision world built from the ManiSkill scene.

Example:
    >>> planner = JointSpacePlanner(world)
    >>> result = planner.plan(q_now, q_goal)
    >>> result.ok, result.path.shape, result.reason
"""

from __future__ import annotations

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
        simplify_time: Seconds the OMPL path simplifier may spend shortening a solution.
        cache: Plan cache (a fresh one by default); pass ``None`` to disable caching.
        attempts: RRT-Connect runs per query before giving up (a new run after a failed final check).
        seed: Seed of OMPL's random number generator (for reproducible plans). OMPL's generator is global to
            the process and can be seeded only before its first use, so the first planner's seed holds.
    """

    def __init__(
        self,
        world: CollisionWorld,
        *,
        time_budget: float = 2.0,
        max_step: float = 0.3,
        resolution: float = 0.004,
        simplify_time: float = 0.2,
        cache: PlanCache | None | str = "default",
        attempts: int = 3,
        seed: int | None = 0,
    ):
        from ompl import base as ob
        from ompl import geometric as og
        from ompl import util as ou

        ou.setLogLevel(ou.LOG_WARN)
        _seed_ompl_once(ou, seed)
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
        self._setup.getSpaceInformation().setStateValidityCheckingResolution(resolution / self._space.getMaximumExtent())
        rrt = og.RRTConnect(self._setup.getSpaceInformation())
        rrt.setRange(max_step)
        self._setup.setPlanner(rrt)
        self._simplify_time = simplify_time
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
        for _ in range(self.attempts):
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
        ss.clear()
        ss.setStartAndGoalStates(self._state(q_start), self._state(q_goal))
        ss.solve(budget)
        if not ss.haveExactSolutionPath():  # solve() is truthy for approximate solutions too
            return None, f"RRT-Connect found no collision-free path in {budget:.1f} s"
        raw = self._solution(q_start, q_goal)
        ss.simplifySolution(self._simplify_time)
        # OMPL and the final dense check sample a motion at different points, so a path that grazes an obstacle
        # can pass one and fail the other; the simplifier's shortcuts are the usual culprits. The raw RRT-Connect
        # path is then the fallback before a new search.
        for path in (self._solution(q_start, q_goal), raw):
            if self.world.path_valid(path):
                return path, ""
        return None, "both the simplified and the raw RRT-Connect path failed the final collision check"

    def _solution(self, q_start: np.ndarray, q_goal: np.ndarray) -> np.ndarray:
        states = self._setup.getSolutionPath().getStates()
        path = np.array([[s[i] for i in range(self._dof)] for s in states], dtype=np.float64)
        path[0], path[-1] = q_start, q_goal
        return path


_OMPL_SEEDED: list[int] = []  # OMPL's RNG is process-global: remember whether it was seeded


def _seed_ompl_once(ou, seed: int | None) -> None:
    if seed is None or _OMPL_SEEDED:
        return
    ou.RNG.setSeed(int(seed) + 1)  # OMPL rejects seed 0
    _OMPL_SEEDED.append(int(seed))
