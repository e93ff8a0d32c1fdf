"""Rolling resistance of spheres on the table, which PhysX leaves out.

PhysX models sliding friction but no rolling resistance: a sphere set rolling on the table keeps rolling, slowed only
by SAPIEN's angular damping (0.05 /s). Measured in the clutter tasks' physics (100 Hz, the package's materials), a
2 cm sphere set rolling at 0.1 m/s is 48 cm away after 5 s and still at 0.09 m/s; at 0.2 m/s, 96 cm. A nudge from a
grasp then carries it off the table. (Cylinders lying down collide as 32-sided prisms, see
:mod:`~maniskill_pnp.scenes.objects`, and stop within 3-14 cm of such nudges by themselves.)

The model is Coulomb's law of rolling friction: a rolling body meets a torque ``f * N`` against its rolling, ``f`` the
*lever arm* of rolling friction (a length, a property of the two materials), ``N`` the normal force (here the body's
weight, ``m g``, while it rests on the table). For a solid sphere of radius ``r`` rolling without slipping the
deceleration is ``5/7 g f / r``, so from speed ``v`` it rolls ``7 v^2 r / (10 g f)`` before it stops.

The lever arm: published engineering tables give 1.2 mm for wood on steel (the Lust CDA3000 engineering guide,
Table 7.22 "Lever arm of rolling friction"; NORD's drive-selection tables: 0.05 in = 1.27 mm), 1.5 mm for wood on
wood (0.06 in, eMachineShop's table of rolling-friction coefficients) and 2.0 mm for plastic on steel (Lust; NORD:
0.08 in). The clutter objects stand for wooden or plastic parts on a wooden table; :data:`LEVER_ARM` takes the
smallest of these, 1.2 mm, so that the model errs towards rolling too far rather than too short. With it a 2 cm
sphere set rolling at 0.1 / 0.2 / 0.3 m/s stops after 1.2 / 4.8 / 10.7 cm (the law; measured in the tasks' physics
within 5% of it).

The torque is applied every physics step, capped so that it stops a rolling sphere but never turns it back, and only
to spheres that roll (:meth:`RollingResistance.apply`): awake, turning fast enough to roll at :data:`MIN_ROLLING_SPEED`
or more, and resting on the table. A sphere at rest still turns a little in PhysX's contact solver (about 1e-6 m/s at
its rim); a torque against that would change nothing, but every torque PhysX is given wakes its body, so it kept
the sphere, and every object touching it, awake and simulated on every step (with the Python work of the torque, a
clutter task's physics step took 2.5 times as long, issue 51). Left alone, such a sphere falls asleep as any other
resting body does.
The GPU-batched simulation does not apply it yet (only the CPU simulation, where every step's torques are set per
body).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Lever arm of rolling friction (m): wood on steel, the smallest published value for wood or plastic on a hard
#: surface (see the module docstring).
LEVER_ARM = 1.2e-3
#: A sphere whose lowest point is within this (m) of the table top rests on it.
CONTACT_BAND = 1e-3
#: A sphere whose horizontal spin would roll it slower than this (m/s) is not rolling (:meth:`RollingResistance.apply`
#: gives it no torque): 100 times what a sphere at rest turns at in the contact solver, and a speed at which the
#: torque would stop it within a step, after rolling a micrometre.
MIN_ROLLING_SPEED = 1e-4


@dataclass(frozen=True)
class RollingResistance:
    """Coulomb rolling friction of spheres resting on a horizontal table at height ``table_z``.

    Attributes:
        table_z: Height (m) of the table top.
        lever_arm: Lever arm of rolling friction (m); 0 turns the model off.
        gravity: Magnitude of gravity (m/s²).
    """

    table_z: float
    lever_arm: float = LEVER_ARM
    gravity: float = 9.81

    def __post_init__(self):
        if not (np.isfinite(self.lever_arm) and self.lever_arm >= 0):
            raise ValueError(f"rolling lever arm must be a finite length >= 0 (m), got {self.lever_arm!r}")

    def torque(self, position: np.ndarray, angular_velocity: np.ndarray, radius: float, mass: float, inertia: float,
               dt: float) -> np.ndarray:
        """The rolling-friction torque (N m, world frame) on a sphere of ``radius``, ``mass`` and moment of inertia
        ``inertia`` about its centre at ``position`` turning at ``angular_velocity``, for a physics step of ``dt``
        seconds: ``-lever_arm * m * g`` along its horizontal spin while it rests on the table, at most what stops that
        spin within the step; zero off the table."""
        spin = np.array([angular_velocity[0], angular_velocity[1], 0.0], dtype=np.float64)
        rate = float(np.linalg.norm(spin))
        if self.lever_arm == 0 or rate == 0.0 or position[2] - radius > self.table_z + CONTACT_BAND:
            return np.zeros(3)
        magnitude = min(self.lever_arm * mass * self.gravity, inertia * rate / dt)
        return -magnitude * spin / rate

    def apply(self, bodies, dt: float) -> None:
        """Add the torque of each ``(component, radius)`` in ``bodies`` (SAPIEN ``PhysxRigidDynamicComponent`` of a
        sphere) for the next physics step of ``dt`` seconds, to those that roll: not asleep, their horizontal spin at
        least :data:`MIN_ROLLING_SPEED` at the rim, resting on the table (:meth:`torque`). The others are left
        untouched, so that PhysX can put a sphere at rest to sleep; and the cheap tests (sleep, then spin) come
        first, since this runs for every sphere on every physics step."""
        if self.lever_arm == 0:
            return
        for body, radius in bodies:
            if body.is_sleeping:
                continue
            spin = body.angular_velocity.tolist()
            if math.hypot(spin[0], spin[1]) * radius < MIN_ROLLING_SPEED:
                continue
            position = body.entity_pose.p
            if position[2] - radius > self.table_z + CONTACT_BAND:
                continue
            tau = self.torque(position, spin, radius, body.mass, min(body.inertia.tolist()), dt)
            if tau.any():
                body.add_force_torque(np.zeros(3, dtype=np.float32), tau.astype(np.float32))


def stopping_distance(speed: float, radius: float, lever_arm: float = LEVER_ARM, gravity: float = 9.81) -> float:
    """How far (m) a solid sphere rolling without slipping at ``speed`` (m/s) rolls under Coulomb rolling friction:
    ``7 v^2 r / (10 g f)``."""
    return 7.0 * speed**2 * radius / (10.0 * gravity * lever_arm)
