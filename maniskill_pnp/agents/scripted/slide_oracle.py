"""Scripted oracles that see the objects' shapes and poses: grasps where a grasp fits, and slides that free one.

They measure what a primitive *can* win on a scene, not what a learned agent does. Both read the env's objects in
the workspace (:meth:`~maniskill_pnp.scenes.clutter_pool.ClutterPool.workspace_objects`) and act through the env's
own pixel actions, so the physics decides the outcome.

* :class:`FeasibleGraspOracle` (``slides=False``, the *grasp-only* oracle): where some object has a feasible
  top-down grasp (:func:`~maniskill_pnp.scenes.grasp_feasibility.grasp_feasibility`, on the agent's jaw lines), it
  grasps the highest such object at the feasible position nearest the middle of its top. Where every object is
  locked it falls back to the heightmap oracle's grasp
  (:class:`~maniskill_pnp.agents.scripted.clutter_oracle.HeightmapGraspOracle`), which then fails or pushes.
* With ``slides=True`` (the *slide-then-grasp* oracle) it slides instead where every object is locked: per locked
  object, per slide direction (the task's 2 × R/2 directions) and per offset of the pusher along its width, it sweeps
  the closed fingers' collision geometry along the push on the objects' height columns; a slide qualifies when the
  pusher comes down on nothing and meets that object alone. The object is moved by the push that is left after the
  contact, its path checked free of the others (and inside the workspace), and the grasp check is run on the
  layout so predicted. A slide that the agents' mask would not offer because it carries material off the heightmap
  (:meth:`~maniskill_pnp.agents.pixel.mask.HeightmapActionMask.slides_keep_in`) is not taken either. The oracle takes the slide predicted to unlock the most objects (then the one best lined up
  with a face of the object); if no slide qualifies it grasps as the grasp-only oracle does.

Example:
    >>> oracle = FeasibleGraspOracle(env.unwrapped, slides=True)
    >>> action = oracle(obs)
    >>> oracle.last  # what it chose and why
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from maniskill_pnp.agents.pixel.mask import HeightmapActionMask
from maniskill_pnp.agents.scripted.clutter_oracle import HeightmapGraspOracle
from maniskill_pnp.scenes.grasp_feasibility import _maps, grasp_feasibility, panda_gripper

#: The grasp check's grid for the oracles (the agent's jaw lines every 180/8 degrees).
CHECK = dict(position_step=0.004, resolution=0.001)
#: Offsets (m) of the pusher along its width tried per direction, and the sweep step (m).
PUSHER_OFFSETS = (-0.015, 0.0, 0.015)
SWEEP_STEP = 0.004
#: The pusher starts this far (m) behind the object's face along the push.
APPROACH = 0.02


@dataclass
class OracleChoice:
    """What an oracle chose: ``kind`` ("grasp", "fallback_grasp" or "slide"), the flat action, the object (pool index,
    -1 for a fallback) and, for a slide, how many objects it was predicted to unlock."""

    kind: str
    action: int
    target: int
    predicted_unlocked: int = 0


class FeasibleGraspOracle:
    """The grasp-only (``slides=False``) or slide-then-grasp (``slides=True``) oracle of one env (env 0) of
    ClutterGrasp-v1 / ClutterGraspSlide-v1; see the module docstring."""

    def __init__(self, env, slides: bool = False):
        if slides and "left_slide" not in env.PRIMITIVES:
            raise ValueError(f"slides need ClutterGraspSlide-v1's primitives, this task has {env.PRIMITIVES}")
        self.env, self.slides = env, slides
        self.ws = env.workspace
        self.fallback = HeightmapGraspOracle(self.ws)
        closed = panda_gripper(opening=0.0)
        self.pusher = closed.points
        self.last: OracleChoice | None = None
        self.yaw_step = 360.0 / self.ws.num_rotations  # the action's jaw lines (r and r + R/2 are one line)
        self.mask = HeightmapActionMask.for_workspace(env.PRIMITIVES, self.ws, keep_in=True) if slides else None

    def __call__(self, obs) -> int:
        height = np.asarray(obs["depth_heightmap"][0], dtype=np.float64).squeeze()
        objects = self.env.clutter.workspace_objects(0)
        if not objects:
            return self._fallback(height)
        keys = list(objects)
        layout = [objects[i] for i in keys]
        grasps = grasp_feasibility(layout, self.ws, yaw_step_deg=self.yaw_step, first_only=True, **CHECK)
        free = [g for g in grasps if not g.locked]
        if free:
            g = max(free, key=lambda g: layout[g.index][1].p[2] + layout[g.index][0].extents[2] / 2)
            x, y, _, yaw = g.example
            row, col = self.ws.world_to_pixel(np.array([x, y, 0.0]))
            rot = int(round(yaw / (2 * math.pi / self.ws.num_rotations))) % self.ws.num_rotations
            action = int(self.env.action_layout.encode(0, rot, int(row), int(col)))
            self.last = OracleChoice("grasp", action, keys[g.index])
            return action
        if self.slides:
            best = self._best_slide(layout, height)
            if best is not None:
                action, k, unlocked = best
                self.last = OracleChoice("slide", action, keys[k], unlocked)
                return action
        return self._fallback(height)

    def _fallback(self, height) -> int:
        action = int(self.fallback(height))
        self.last = OracleChoice("fallback_grasp", action, -1)
        return action

    # ------------------------------------------------------------------ slides
    def _best_slide(self, layout, height: np.ndarray) -> tuple[int, int, int] | None:
        ws = self.ws
        occupied = torch.as_tensor(height, dtype=torch.float32)[None, None] > self.mask.min_height
        everywhere = torch.ones(1, ws.num_rotations, *height.shape, dtype=torch.bool)
        keeps_in = {side: self.mask.slides_keep_in(occupied, side, everywhere)[0].numpy() for side in ("left", "right")}
        maps = _maps(layout, ws.table_z, CHECK["resolution"])
        tip_z = ws.table_z + ws.min_tip_height
        low = self.pusher[self.pusher[:, 2] + tip_z < float(maps.top.max())]  # the pusher parts objects can meet
        (x0, x1), (y0, y1) = ws.bounds[:2]
        best, best_key = None, None
        for k, (spec, pose) in enumerate(layout):
            present = ~np.isnan(maps.hi[k])
            others = np.any(~np.isnan(np.delete(maps.hi, k, axis=0)), axis=0)  # cells any other object covers
            cells = maps.origin + maps.step * np.argwhere(present)
            centre = cells.mean(axis=0)
            yaw_obj = math.atan2(*pose.to_transformation_matrix()[1::-1, 0])
            for rot in range(ws.num_rotations // 2):
                for side in ("left", "right"):
                    d = ws.slide_direction(rot, side)
                    jaw = np.array([d[1], -d[0]])
                    reach = float(np.max((cells - centre) @ d))
                    for offset in PUSHER_OFFSETS:
                        start = centre - d * (reach + APPROACH) + jaw * offset
                        contact = self._sweep(maps, low, start, d, tip_z, k)
                        if contact is None:
                            continue
                        shift = d * (ws.slide_length - contact)
                        moved = cells + shift
                        if not (x0 <= moved[:, 0].min() and moved[:, 0].max() <= x1 and y0 <= moved[:, 1].min()
                                and moved[:, 1].max() <= y1) or self._path_blocked(maps, present, others, shift):
                            continue
                        row, col = ws.world_to_pixel(np.array([*start, 0.0]))
                        if not (0 <= row < height.shape[0] and 0 <= col < height.shape[1]
                                and keeps_in[side][rot, row, col]):
                            continue  # the heightmap's view of the push carries material off it
                        predicted = list(layout)
                        p = np.array(pose.p, dtype=np.float64)
                        p[:2] += shift
                        predicted[k] = (spec, type(pose)(p=p, q=pose.q))
                        unlocked = sum(not g.locked for g in grasp_feasibility(
                            predicted, ws, yaw_step_deg=self.yaw_step, first_only=True, **CHECK))
                        face = abs(math.remainder(math.atan2(d[1], d[0]) - yaw_obj, math.pi / 2))
                        key = (unlocked, -face, -abs(offset))
                        if best_key is None or key > best_key:
                            action = int(self.env.action_layout.encode(1 if side == "left" else 2, rot, int(row), int(col)))
                            best, best_key = (action, k, unlocked), key
        if best is None or best[2] == 0:
            return None
        return best

    def _sweep(self, maps, pusher, start, d, tip_z, target) -> float | None:
        """Push distance at which the pusher, lowered at ``start`` and swept along ``d``, first meets object
        ``target``; None if it comes down on something, or meets another object first or at all."""
        jaw = np.array([d[1], -d[0]])
        # pusher points: x along the pads' width (the push), y along the closed jaws
        xy = pusher[:, :1] * d + pusher[:, 1:2] * jaw
        z = tip_z + pusher[:, 2]
        contact = None
        for t in np.arange(0.0, self.ws.slide_length + 1e-9, SWEEP_STEP):
            i, j, inside = maps.cells(start + xy + t * d)
            hit = inside[:, None] & (np.nan_to_num(maps.hi[:, i, j].T, nan=-np.inf) > z[:, None])  # (points, objects)
            touched = np.flatnonzero(hit.any(axis=0))
            if t == 0.0 and len(touched):
                return None
            if any(o != target for o in touched):
                return None
            if len(touched) and contact is None:
                contact = float(t)
        return contact

    def _path_blocked(self, maps, present, others, shift) -> bool:
        """Whether an object's footprint (cells ``present``), moved along ``shift`` in steps, meets the cells
        ``others`` of the other objects."""
        cells = np.argwhere(present)
        n = max(1, int(np.linalg.norm(shift) / SWEEP_STEP))
        for s in range(1, n + 1):
            ij = np.rint(cells + shift * s / n / maps.step).astype(np.int64)
            ok = (ij[:, 0] >= 0) & (ij[:, 0] < others.shape[0]) & (ij[:, 1] >= 0) & (ij[:, 1] < others.shape[1])
            if others[ij[ok, 0], ij[ok, 1]].any():
                return True
        return False
