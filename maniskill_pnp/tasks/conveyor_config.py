"""Geometry and discrete MDP of the conveyor task (thesis chapter 4): one source of truth for env and agents.

The belt runs along +y in front of the Panda (robot base at x = -0.615). An object rides it toward the
workspace end; two ray gates across the belt time its leading edge (speed class), a row of downward rays
under the second gate sees where it lies across the belt (alignment). The agent then chooses a pre-pick
coordinate above the belt and a grasp coordinate on a line along the belt below that pre-pick coordinate.

"Left" and "right" are seen looking along the belt's motion (+y): left is -x, the lane nearer the robot.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from maniskill_pnp.cell.bin import BinSpec

PHASES = ("initial", "pre_pick", "grasp", "done")
#: What the task's ``info`` says for a speed or alignment not sensed yet (ManiSkill's numpy wrappers cannot carry
#: None; ``encode_state`` takes it as None).
UNKNOWN = "unknown"
ALIGNMENTS = ("left", "center", "right")
SPEEDS = ("slow", "medium", "fast")
OBJECT_KINDS = ("cuboid", "cylinder", "sphere")
REWARD_SCHEMES = ("normal", "negative", "bonus", "negative_bonus")


#: Hand-marked optimal choices per speed class: (pre-pick row, grasp index), the row taken in the sensed lane.
#: Found by a sweep of every (row, grasp) pair over seeded arrivals in every lane: each is the middle of the span
#: of grasp points that caught every object; slow objects are met upstream, fast ones downstream.
_BEST_ROW_GRASP = {"slow": (0, 1), "medium": (1, 1), "fast": (1, 3)}


@dataclass(frozen=True)
class ConveyorSpec:
    """Conveyor geometry, sensors, belt speeds and the hand-made coordinate sets (world frame, m, s).

    Attributes:
        belt_x: x of the belt's centre line.
        belt_y: (start, end) of the belt along y; objects move toward ``end`` and fall off past it.
        belt_width: Width of the belt across its motion (x).
        belt_top: Height of the belt surface above the table.
        belt_grip: Friction coefficient of the belt drive: the drive force is capped at ``belt_grip * m * g``.
        belt_response: Time constant of the belt drive pulling an object to belt speed.
        lane_offsets: x offsets of the left, center and right lanes from ``belt_x``.
        lane_jitter: Half range of the uniform x jitter of an object around its lane.
        spawn_y: y of an object's centre when it is put on the belt.
        speeds: Belt speeds (m/s) of the slow, medium and fast classes.
        gate_y: y of the two speed gates (horizontal rays across the belt); the second one signals arrival.
        gate_height: Height of the gate rays above the belt surface.
        align_ray_x: x offsets (from ``belt_x``) of the downward alignment rays at the second gate.
        align_ray_height: Height above the belt from which the alignment rays look down.
        wait_timeout: Seconds the initial phase waits for an arrival before it gives up.
        prepick_y: y of the pre-pick coordinates (one row per lane: pre-pick set = lanes × these).
        prepick_height: Height of the pre-pick coordinates above the belt.
        grasp_offsets: Grasp coordinates as y offsets from the chosen pre-pick coordinate (a line along the belt).
        grasp_height: Height of the grasp TCP above the belt.
        grasp_yaw: Closing direction of the jaws (rad from x): along the belt, so the downstream finger stops
            the object while the jaws close.
        best_row_grasp: Hand-marked optimal (pre-pick row, grasp index) per speed class, in the sensed lane; see
            :meth:`best`. The "bonus" reward and the scripted oracle use it.
        bin: The place bin.
        arm_velocity: Joint velocity limit (rad/s) of the arm's motions: the pre-pick and grasp coordinates and the
            hand-marked optimal pairs are timed against the belt at these limits.
        arm_acceleration: Joint acceleration limit (rad/s^2) of the arm's motions.
    """

    belt_x: float = -0.10
    belt_y: tuple[float, float] = (-0.55, 0.15)
    belt_width: float = 0.24
    belt_top: float = 0.04
    belt_grip: float = 0.5
    belt_response: float = 0.02
    lane_offsets: tuple[float, float, float] = (-0.065, 0.0, 0.065)
    lane_jitter: float = 0.008
    spawn_y: float = -0.37
    speeds: tuple[float, float, float] = (0.02, 0.04, 0.06)
    gate_y: tuple[float, float] = (-0.30, -0.25)
    gate_height: float = 0.012
    align_ray_x: tuple[float, ...] = tuple(np.round(np.linspace(-0.1, 0.1, 9), 4))
    align_ray_height: float = 0.2
    wait_timeout: float = 15.0
    prepick_y: tuple[float, ...] = (-0.24, -0.20, -0.16)
    prepick_height: float = 0.10
    grasp_offsets: tuple[float, ...] = (-0.04, -0.02, 0.0, 0.02, 0.04, 0.06)
    grasp_height: float = 0.018
    grasp_yaw: float = np.pi / 2
    best_row_grasp: dict[str, tuple[int, int]] = field(default_factory=lambda: dict(_BEST_ROW_GRASP))
    bin: BinSpec = BinSpec(center=(-0.25, 0.36, 0.0))
    arm_velocity: float = 1.5
    arm_acceleration: float = 2.0

    @property
    def prepick_coords(self) -> np.ndarray:
        """(lanes × rows)×3 pre-pick coordinates; index = lane * len(prepick_y) + row."""
        return np.array(
            [
                (self.belt_x + dx, y, self.belt_top + self.prepick_height)
                for dx in self.lane_offsets
                for y in self.prepick_y
            ]
        )

    def grasp_coord(self, prepick_index: int, grasp_index: int) -> np.ndarray:
        """The grasp TCP position for grasp coordinate ``grasp_index`` below pre-pick ``prepick_index``."""
        x, y, _ = self.prepick_coords[prepick_index]
        return np.array([x, y + self.grasp_offsets[grasp_index], self.belt_top + self.grasp_height])

    def best(self, alignment: str, speed: str) -> tuple[int, int]:
        """The hand-marked optimal (pre-pick index, grasp index) for an alignment and speed class."""
        row, grasp = self.best_row_grasp[speed]
        return ALIGNMENTS.index(alignment) * len(self.prepick_y) + row, grasp

    def oracle_action(self, phase: str, alignment: str | None, speed: str | None) -> int:
        """The scripted oracle's action in ``phase`` for the sensed alignment and speed (see :meth:`best`)."""
        if phase == "initial":
            return 0
        prepick, grasp = self.best(alignment, speed)
        return {"pre_pick": prepick, "grasp": grasp}[phase]

    @property
    def num_actions(self) -> dict[str, int]:
        """Valid action count per phase ("initial" has one: wait)."""
        return {"initial": 1, "pre_pick": len(self.prepick_coords), "grasp": len(self.grasp_offsets), "done": 0}

    @property
    def action_n(self) -> int:
        """Size of the Discrete action space: the largest phase's action count."""
        return max(self.num_actions.values())

    @property
    def num_states(self) -> int:
        """Number of discrete state ids (see :func:`encode_state`)."""
        return len(PHASES) * (len(SPEEDS) + 1) * (len(ALIGNMENTS) + 1) * (self.action_n + 1)

    def encode_state(self, phase: str, speed: str | None, alignment: str | None, last: int | None) -> int:
        """One state id from (phase, sensed speed, sensed alignment, last chosen coordinate); None (or the task
        info's :data:`UNKNOWN`, and -1 for ``last``) = not known yet."""
        p = PHASES.index(phase)
        s = 0 if speed in (None, UNKNOWN) else SPEEDS.index(speed) + 1
        a = 0 if alignment in (None, UNKNOWN) else ALIGNMENTS.index(alignment) + 1
        c = 0 if last is None or int(last) < 0 else int(last) + 1
        return ((p * (len(SPEEDS) + 1) + s) * (len(ALIGNMENTS) + 1) + a) * (self.action_n + 1) + c

    def decode_state(self, state: int) -> dict:
        """Inverse of :meth:`encode_state`."""
        rest, c = divmod(int(state), self.action_n + 1)
        rest, a = divmod(rest, len(ALIGNMENTS) + 1)
        p, s = divmod(rest, len(SPEEDS) + 1)
        return dict(
            phase=PHASES[p],
            speed=None if s == 0 else SPEEDS[s - 1],
            alignment=None if a == 0 else ALIGNMENTS[a - 1],
            last=None if c == 0 else c - 1,
        )
