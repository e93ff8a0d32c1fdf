"""Inverse kinematics and straight Cartesian segments for the arm (pinocchio through mplib).

IK solutions are filtered by the collision world (joint limits, self- and scene collisions) and the one
nearest the current configuration wins, so consecutive motions don't swing the elbow around.
Straight segments (approach, lift, slide) are followed by chained IK seeded from the previous waypoint and
rejected when a joint would jump, when a limit is hit, or when a waypoint collides.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien

from maniskill_pnp.planning.collision import CollisionWorld


@dataclass(frozen=True)
class IKResult:
    """Outcome of an IK query: ``q`` (arm joints) when ``ok``, else ``reason`` says why not."""

    q: np.ndarray | None
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.q is not None


@dataclass(frozen=True)
class SegmentResult:
    """Outcome of a straight Cartesian segment: joint waypoints (N×dof) when ``ok``, else ``reason``."""

    path: np.ndarray | None
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.path is not None


class Kinematics:
    """IK, FK and Cartesian segments for the arm of a :class:`CollisionWorld`.

    Args:
        world: The collision world (owns the robot model and the obstacles used to filter solutions).
        seed: Seed of the random restarts of IK.
    """

    def __init__(self, world: CollisionWorld, seed: int = 0):
        self.world = world
        self.arm = world.arm
        planner = world.mplib_planner
        self._model = planner.pinocchio_model
        self._tcp = planner.link_name_2_idx[self.arm.tcp_link]
        n_fingers = len(planner.user_joint_names) - self.arm.arm_joints
        self._fingers = np.full(n_fingers, self.arm.gripper_open)
        limits = np.concatenate(self._model.get_joint_limits()).reshape(-1, 2)
        self._qmin, self._qmax = limits[:, 0].copy(), limits[:, 1].copy()
        self._rng = np.random.default_rng(seed)

    def fk(self, q: np.ndarray) -> sapien.Pose:
        """World pose of the TCP at arm configuration ``q``."""
        self._model.compute_forward_kinematics(self._full(q))
        raw = np.asarray(self._model.get_link_pose(self._tcp), dtype=np.float64)
        return self.world.base_to_world(raw)

    #: A valid solution that moves no joint farther than this (rad) from ``q_near`` ends the search. The first attempt,
    #: seeded at ``q_near``, finds one for nearly every grasp and release of the clutter tasks; a random restart then
    #: saves at most about 0.1 rad of travel (about 50 ms of a free-space motion at the Panda's rated speed), at 20-50 ms
    #: of IK per restart round. Restarts still run where the first solution swings the arm farther (another branch).
    NEAR = 1.25

    def ik(self, pose: sapien.Pose, q_near: np.ndarray, *, restarts: int = 12, tol: float = 2e-3) -> IKResult:
        """A valid arm configuration reaching the world TCP ``pose``, near ``q_near``.

        The first attempt starts at ``q_near``; further ones from random configurations, until a solution within
        :attr:`NEAR` rad (max joint distance) of ``q_near`` is found; the nearest found wins.
        """
        return self.ik_any([pose], q_near, restarts=restarts, tol=tol)

    def ik_any(self, poses: list[sapien.Pose], q_near: np.ndarray, *, restarts: int = 12, tol: float = 2e-3) -> IKResult:
        """Like :meth:`ik`, for several equivalent goal poses (e.g. a parallel-jaw grasp and its 180° twin); every pose
        is tried in each attempt."""
        best, best_d, reasons = None, np.inf, set()
        targets = [self._base_pose7(p) for p in poses]
        for attempt in range(restarts + 1):
            seed = q_near if attempt == 0 else self._random_q()
            for target in targets:
                q, err = self._solve(target, seed)
                if err > tol:
                    reasons.add("no IK solution reaches the pose")
                    continue
                if not self.arm.within_limits(q):
                    reasons.add("IK solution outside the joint limits")
                    continue
                d = float(np.max(np.abs(q - q_near)))
                if d >= best_d:  # no nearer than a valid one found: its collision check could not change the answer
                    continue
                if not self.world.is_valid(q):
                    reasons.add("every IK solution collides")
                    continue
                best, best_d = q, d
            if best is not None and best_d < self.NEAR:
                break
        if best is None:
            return IKResult(None, "; ".join(sorted(reasons)) or "no IK solution")
        return IKResult(best)

    def straight_line(self, q_start: np.ndarray, goal: sapien.Pose, *, step: float = 0.005, max_joint_step: float = 0.15) -> SegmentResult:
        """Joint waypoints that move the TCP on a straight line from its pose at ``q_start`` to ``goal``.

        Position is interpolated linearly and orientation by slerp, one waypoint every ``step`` metres; each
        waypoint is solved by IK seeded from the previous one. Fails (with a reason) on a joint jump larger than
        ``max_joint_step`` rad between waypoints, a joint limit, or a collision.
        """
        start = self.fk(q_start)
        dist = float(np.linalg.norm(goal.p - start.p))
        angle = quat_angle(start.q, goal.q)
        n = max(2, int(np.ceil(max(dist / step, angle / 0.05))) + 1)
        path = [np.asarray(q_start, dtype=np.float64)]
        for t in np.linspace(0.0, 1.0, n)[1:]:
            pose = sapien.Pose(p=start.p + t * (goal.p - start.p), q=_slerp(start.q, goal.q, t))
            q, err = self._solve(self._base_pose7(pose), path[-1])
            if err > 2e-3:
                return SegmentResult(None, f"straight line leaves the arm's reach at {t:.0%}")
            if not self.arm.within_limits(q):
                return SegmentResult(None, f"straight line hits a joint limit at {t:.0%}")
            if np.max(np.abs(q - path[-1])) > max_joint_step:
                return SegmentResult(None, f"straight line passes a singularity (joint jump) at {t:.0%}")
            if not self.world.is_valid(q):
                pairs = sorted({f"{a}/{b}" for a, b in self.world.collisions(q)})
                return SegmentResult(None, f"straight line collides at {t:.0%}: {', '.join(pairs[:3])}")
            path.append(q)
        return SegmentResult(np.stack(path))

    # ------------------------------------------------------------------ internals
    def _full(self, q: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(q, dtype=np.float64), self._fingers])

    def _base_pose7(self, pose: sapien.Pose) -> np.ndarray:
        b = self.world.world_to_base(pose)
        return np.concatenate([b.p, b.q]).astype(np.float64)

    def _solve(self, target7: np.ndarray, seed: np.ndarray) -> tuple[np.ndarray, float]:
        q, _, err = self._model.compute_IK_CLIK_JL(
            self._tcp, target7, self._full(seed), self._qmin, self._qmax, max_iter=300
        )
        return np.asarray(q[: self.arm.arm_joints], dtype=np.float64), float(np.linalg.norm(err))

    def _random_q(self) -> np.ndarray:
        return self._rng.uniform(self.arm.lower, self.arm.upper)


def quat_angle(q0: np.ndarray, q1: np.ndarray) -> float:
    d = abs(float(np.dot(q0, q1)))
    return 2.0 * float(np.arccos(min(1.0, d)))


def _slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    d = float(np.dot(q0, q1))
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(d)
    return (np.sin((1 - t) * theta) * q0 + np.sin(t * theta) * q1) / np.sin(theta)
