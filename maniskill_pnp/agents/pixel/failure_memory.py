"""What a greedy pixel agent must not try again: the failed actions of an unchanged scene.

A greedy agent is a function of the heightmap. A failed attempt that leaves the scene as it was (a grasp that closed
on nothing, a guarded descent stopped on a neighbour, a plan the arm cannot reach, a slide that moved nothing) leaves
the heightmap and so the argmax where they were: without a memory the agent repeats the same failure until the
failure limit ends the episode. :class:`FailureMemory` keeps, after each failure, that action and its neighbours (the
same primitive, within ``radius_px`` pixels and ``rotation_steps`` rotations; for a grasp also the same jaw line
turned by 180°, the same grasp for parallel jaws) out of the agent's choice until the heightmap changes by VPG's
test (:func:`~maniskill_pnp.tasks.clutter_grasp_slide.heightmap_changed`): then every remembered failure may be
tried again.
"""

from __future__ import annotations

import numpy as np

from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.tasks.clutter_grasp_slide import heightmap_changed


class FailureMemory:
    """The failed actions of the current scene and the flat action indices they rule out.

    Args:
        layout: The action layout (primitives × rotations × rows × cols) of the agent's flat actions.
        primitives: The primitive names, in primitive-index order (a ``"grasp"`` is symmetric under 180°).
        radius_px: Pixels around a failed action's pixel (Chebyshev distance) that are ruled out with it.
        rotation_steps: Rotations either side of a failed action's rotation that are ruled out with it.
    """

    def __init__(self, layout: PixelActionLayout, primitives: tuple[str, ...], radius_px: int = 2,
                 rotation_steps: int = 1):
        if radius_px < 0 or rotation_steps < 0:
            raise ValueError(f"radius_px and rotation_steps must be >= 0, got {radius_px}, {rotation_steps}")
        if len(primitives) != layout.num_primitives:
            raise ValueError(f"{len(primitives)} primitive names for a layout of {layout.num_primitives} primitives")
        self.layout, self.primitives = layout, tuple(primitives)
        self.radius_px, self.rotation_steps = int(radius_px), int(rotation_steps)
        self.failures: list[int] = []
        self._scene: np.ndarray | None = None  # the heightmap the remembered failures were tried on

    def reset(self) -> None:
        """Forget every failure (a new episode)."""
        self.failures.clear()
        self._scene = None

    def observe(self, action: int, failed: bool, depth_after: np.ndarray) -> None:
        """Record the outcome of ``action`` and the heightmap after it: a changed scene clears the memory, then a
        failure is remembered."""
        depth_after = np.asarray(depth_after, np.float32)
        if self._scene is not None and heightmap_changed(self._scene, depth_after):
            self.failures.clear()
        if failed:
            self.failures.append(int(action))
        self._scene = depth_after if self.failures else None

    def excluded(self) -> np.ndarray:
        """Flat action indices the remembered failures rule out (sorted, without repeats)."""
        if not self.failures:
            return np.zeros(0, dtype=np.int64)
        L = self.layout
        ruled = np.zeros(L.shape, dtype=bool)
        for action in self.failures:
            p, r, row, col = (int(v) for v in L.decode(action))
            turns = [r] if self.primitives[p] != "grasp" or L.num_rotations % 2 else [r, r + L.num_rotations // 2]
            rotations = {(t + k) % L.num_rotations for t in turns for k in range(-self.rotation_steps, self.rotation_steps + 1)}
            rows = slice(max(0, row - self.radius_px), row + self.radius_px + 1)
            cols = slice(max(0, col - self.radius_px), col + self.radius_px + 1)
            for rot in rotations:
                ruled[p, rot, rows, cols] = True
        return np.flatnonzero(ruled.reshape(-1))


__all__ = ["FailureMemory"]
