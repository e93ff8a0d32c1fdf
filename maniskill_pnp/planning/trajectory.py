"""Time parameterization of joint paths (TOPP-RA, the toppra library) sampled at the controller's rate."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import toppra
from toppra import algorithm as toppra_algorithm
from toppra import constraint as toppra_constraint
from toppra.algorithm.reachabilitybased.reachability_algorithm import MAX_TRIES, SMALL, TINY
from toppra.parametrizer import ParametrizeConstAccel


def densify(path: np.ndarray, max_step: float = 0.05) -> np.ndarray:
    """Insert waypoints so no joint moves more than ``max_step`` rad between consecutive ones.

    A spline through sparse RRT waypoints could bulge away from the checked straight segments; dense waypoints
    keep the timed trajectory on the path that was collision-checked.
    """
    path = np.asarray(path, dtype=np.float64)
    if path.ndim != 2 or len(path) < 1:
        raise ValueError(f"a path is an (N, dof) array with N >= 1, got shape {path.shape}")
    out = [path[0]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.max(np.abs(b - a)) / max_step - 1e-9)))  # a step of exactly max_step is one step
        out.extend(a + (b - a) * t for t in np.linspace(0.0, 1.0, n + 1)[1:])
    return np.stack(out)


def time_parameterize(path: np.ndarray, dt: float, max_velocity: float, max_acceleration: float) -> np.ndarray:
    """Joint positions along ``path`` at every ``dt`` seconds, time-optimal under velocity/acceleration limits.

    Args:
        path: Waypoints (N×dof).
        dt: Sample period (the controller period, ``1 / control_freq``).
        max_velocity: Joint speed limit (rad/s), the same for every joint.
        max_acceleration: Joint acceleration limit (rad/s²).

    Returns:
        Positions (M×dof); the last row is exactly the path's end. Where TOPP-RA fails on a path, the
        :func:`constant_speed` samples of it (the same checked path, without the acceleration limit). A path of one
        straight joint-space segment (every free-space motion whose straight segment is collision-free) takes its
        time-optimal profile in closed form (:func:`straight_segment`) instead of TOPP-RA's numerical one.
    """
    path = np.asarray(path, dtype=np.float64)
    if path.ndim == 2 and len(path) == 2:
        return straight_segment(path[0], path[1], dt, max_velocity, max_acceleration)
    path = densify(path)
    if len(path) < 2 or np.allclose(path[0], path[-1], atol=1e-6):
        return path[-1:].copy()
    dof = path.shape[1]
    # TOPP-RA's spline needs distinct, strictly increasing path parameters: drop repeated waypoints.
    keep = np.concatenate([[True], np.any(np.abs(np.diff(path, axis=0)) > 1e-9, axis=1)])
    path = path[keep]
    if len(path) == 2:
        path = densify(path, max_step=float(np.max(np.abs(path[1] - path[0]))) / 2 + 1e-9)
    try:
        qs = toppra_samples(path, dt, max_velocity, max_acceleration)
    except RuntimeError:  # TOPP-RA finds no feasible parameterization of some paths ("Fail to parameterize path")
        return constant_speed(path, dt, max_velocity)
    if len(qs) == 0 or not np.allclose(qs[-1], path[-1], atol=1e-4):
        qs = np.concatenate([qs.reshape(-1, dof), path[-1:]])
    return qs


def toppra_samples(path: np.ndarray, dt: float, max_velocity: float, max_acceleration: float) -> np.ndarray:
    """Positions every ``dt`` seconds of TOPP-RA's time-optimal trajectory through the waypoints ``path`` (N×dof, N
    >= 2, distinct), under the same velocity and acceleration limit for every joint; RuntimeError where TOPP-RA finds
    no parameterization.

    The computation of mplib's ``Planner.TOPP`` (a cubic spline over uniform path parameters, joint velocity and
    acceleration constraints, ``ParametrizeConstAccel``, ``int(duration / dt)`` samples), so the samples are the
    same to the bit (tested), without its velocity and acceleration samples and with the constraints built once per
    limits. TOPP-RA's two passes run in :func:`path_velocities`.
    """
    path = np.asarray(path, dtype=np.float64)
    spline = toppra.SplineInterpolator(np.linspace(0, 1, len(path)), path)
    constraints = list(_constraints(path.shape[1], float(max_velocity), float(max_acceleration)))
    grid = gridpoints(spline)
    solver = toppra_algorithm.TOPPRA(constraints, spline, gridpoints=grid).solver_wrapper
    sd = path_velocities(solver)
    if sd is None:
        raise RuntimeError("Fail to parameterize path")
    trajectory = ParametrizeConstAccel(spline, grid, sd)
    return np.asarray(trajectory(np.linspace(0, trajectory.duration, int(trajectory.duration / dt))), dtype=np.float64)


def path_velocities(solver) -> np.ndarray | None:
    """The path velocities at the gridpoints of TOPP-RA's time-optimal parameterization from rest to rest, or None
    where it has none: the backward pass (the squared velocities from which the end is still reachable, stage by
    stage) and the greedy forward pass, through ``solver`` (toppra's stage-wise LP solver of the constraints), with
    toppra's own guards against numerical error. The same calls in the same order as toppra's
    ``compute_parameterization``, so the same velocities to the bit (tested), without its per-stage bookkeeping.
    """
    n = solver.get_no_stages()
    if solver.get_no_vars() != 2:  # only the joint velocity and acceleration constraints: no auxiliary variables
        raise ValueError(f"path_velocities takes canonical linear constraints only, got {solver.get_no_vars()} variables")
    up, down = np.array([1e-9, -1.0]), np.array([-1e-9, 1.0])
    reach = np.zeros((n + 1, 2))  # squared velocities; the end at rest
    solver.setup_solver()
    for i in range(n - 1, -1, -1):
        lo, hi = reach[i + 1]
        x_lo = solver.solve_stagewise_optim(i, None, down, np.nan, np.nan, lo, hi)[1]
        x_hi = solver.solve_stagewise_optim(i, None, up, np.nan, np.nan, lo, hi)[1]
        if np.isnan(x_lo) or np.isnan(x_hi):
            return None
        reach[i] = (max(x_lo, 0.0), x_hi)
    solver.close_solver()
    if SMALL < reach[0, 0] or reach[0, 1] + SMALL < 0.0:  # the start, at rest, cannot reach the end
        return None
    deltas = solver.get_deltas()
    xs = np.zeros(n + 1)
    tries, i = 0, 0
    solver.setup_solver()
    while i < n:
        u = solver.solve_stagewise_optim(i, None, np.array([-2 * deltas[i], -1.0]), xs[i], xs[i], reach[i + 1, 0],
                                         reach[i + 1, 1])[0]
        if np.isnan(u):  # just infeasible by numerical error: retry from a slightly lower velocity
            if tries == MAX_TRIES:
                return None
            xs[i] = max(xs[i] - TINY, 0.999 * xs[i])
            tries += 1
            continue
        tries = 0
        x_next = xs[i] + 2 * deltas[i] * u
        x_next = max(x_next - TINY, 0.9999 * x_next)
        xs[i + 1] = min(reach[i + 1, 1], max(reach[i + 1, 0], x_next))
        i += 1
    solver.close_solver()
    return np.sqrt(xs)


def gridpoints(spline, max_err: float = 1e-3, max_segment: float = 0.05, min_points: int = 100,
               max_iteration: int = 100) -> np.ndarray:
    """The gridpoints toppra's ``propose_gridpoints`` gives a path (with the defaults TOPP-RA calls it with), the same
    to the bit (tested), each pass's segments checked together: halve every segment longer than ``max_segment`` or
    whose estimated interpolation error ``0.5 |q''(mid)| length^2`` exceeds ``max_err``, until none is; then halve all
    until there are ``min_points``."""
    grid = np.asarray(spline.path_interval, dtype=np.float64)
    for iteration in range(max_iteration):
        mid, length = 0.5 * (grid[:-1] + grid[1:]), grid[1:] - grid[:-1]
        split = length > max_segment
        short = ~split
        if short.any():
            error = np.max(np.abs(0.5 * spline(mid[short], 2) * length[short, None] ** 2), axis=1)
            split[short] = error > max_err
        grid = np.sort(np.concatenate([grid, mid[split]]))
        if not split.any():
            break
    while len(grid) < min_points:
        grid = np.sort(np.concatenate([grid, 0.5 * (grid[:-1] + grid[1:])]))
    if iteration == max_iteration - 1:
        raise ValueError("Unable to find a good gridpoint for this path.")
    return grid


@lru_cache(maxsize=8)
def _constraints(dof: int, max_velocity: float, max_acceleration: float) -> tuple:
    """toppra's joint velocity and acceleration constraints (they hold the limits only, not the path)."""
    return (toppra_constraint.JointVelocityConstraint(np.full(dof, max_velocity)),
            toppra_constraint.JointAccelerationConstraint(np.full(dof, max_acceleration)))


def constant_speed(path: np.ndarray, dt: float, max_velocity: float) -> np.ndarray:
    """Joint positions along ``path`` at every ``dt`` seconds with the fastest joint at ``max_velocity`` throughout
    (no acceleration limit): the fallback of :func:`time_parameterize`. The last row is exactly the path's end."""
    if not dt > 0 or not max_velocity > 0:
        raise ValueError(f"dt and max_velocity must be > 0, got {dt}, {max_velocity}")
    qs = densify(path, max_step=max_velocity * dt)
    return qs[1:] if len(qs) > 1 else qs.copy()


def straight_segment(q0: np.ndarray, q1: np.ndarray, dt: float, max_velocity, max_acceleration) -> np.ndarray:
    """Joint positions every ``dt`` seconds along the straight joint-space segment ``q0`` → ``q1``, time-optimal
    under per-joint velocity and acceleration limits (scalars or one per joint), sampled as :func:`time_parameterize`
    samples TOPP-RA's trajectories.

    On a straight segment every joint moves in proportion, so the limits bound the path speed and acceleration, and
    the time-optimal profile is a trapezoid (or a triangle when the top speed is never reached): the closed form of
    what TOPP-RA finds numerically. Measured against mplib's TOPP-RA on the free-space motions of a clutter task:
    the same number of samples, positions within 2e-5 rad, about 0.1 ms instead of 8 ms.

    Returns:
        Positions (M×dof), as many as TOPP-RA's trajectory gives (``int(duration / dt)``, evenly spaced from start to
        end); the last row is exactly ``q1``.
    """
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    if not dt > 0 or not np.all(np.asarray(max_velocity) > 0) or not np.all(np.asarray(max_acceleration) > 0):
        raise ValueError(f"dt and the limits must be > 0, got {dt}, {max_velocity}, {max_acceleration}")
    if np.allclose(q0, q1, atol=1e-6):  # as time_parameterize: no motion, one step at the end
        return q1[None].copy()
    delta = np.abs(q1 - q0)
    moving = delta > 1e-12
    # Limits of the path parameter s in [0, 1] (q = q0 + s (q1 - q0)): the tightest joint's.
    v = float(np.min((np.broadcast_to(max_velocity, delta.shape) / np.where(moving, delta, 1.0))[moving]))
    a = float(np.min((np.broadcast_to(max_acceleration, delta.shape) / np.where(moving, delta, 1.0))[moving]))
    if v * v / a >= 1.0:  # a triangle: accelerate to the middle, decelerate to the end
        t_acc, t_cruise = float(np.sqrt(1.0 / a)), 0.0
        v = a * t_acc
    else:
        t_acc, t_cruise = v / a, (1.0 - v * v / a) / v
    duration = 2 * t_acc + t_cruise
    t = np.linspace(0.0, duration, int(duration / dt))
    s = np.where(t < t_acc, 0.5 * a * t**2,
                 np.where(t < t_acc + t_cruise, 0.5 * a * t_acc**2 + v * (t - t_acc), 1.0 - 0.5 * a * (duration - t) ** 2))
    qs = q0 + s[:, None] * (q1 - q0)
    if len(qs) == 0 or not np.allclose(qs[-1], q1, atol=1e-4):
        qs = np.concatenate([qs.reshape(-1, len(q0)), q1[None]])
    qs[-1] = q1
    return qs
