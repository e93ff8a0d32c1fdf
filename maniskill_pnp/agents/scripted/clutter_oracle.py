"""A scripted grasping oracle for ClutterGrasp-v1 that sees only the heightmap (for tests and as a baseline).

Per object (a connected component of pixels above the table), the grasp pixel is the pixel of its top surface
(within ``top_band`` of its highest point) nearest that surface's centroid. For each of the rotations the
oracle measures, along the jaws' closing line through that pixel, the width of material the finger pads would
meet at the grasp height, and checks that both fingers land on free space; it takes the narrowest feasible
rotation (the jaws close across the object's shorter side). Objects are tried highest first.

Example:
    >>> oracle = HeightmapGraspOracle(env.unwrapped.workspace)
    >>> action = oracle(obs["depth_heightmap"][0])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage

from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.cell.workspace import WorkspaceSpec


@dataclass
class GraspChoice:
    """The oracle's pick: flat action index, its parts, the measured jaw width (m) and whether it looked feasible."""

    action: int
    rotation: int
    row: int
    col: int
    width: float
    feasible: bool


class HeightmapGraspOracle:
    """Heuristic grasps from a height-from-table heightmap.

    Args:
        workspace: The task's workspace (grid, rotations, grasp height rule).
        object_threshold: Pixels higher than this (m) belong to objects.
        top_band: Pixels within this (m) of an object's highest point form its top surface.
        max_width: Widest material (m) the jaws are asked to close on.
        finger_reach: Distance (m) from the grasp centre to each open finger's centre.
        finger_half: Half size (m) of the patch each finger lands on, checked free.
    """

    def __init__(self, workspace: WorkspaceSpec, object_threshold: float = 0.008, top_band: float = 0.005,
                 max_width: float = 0.065, finger_reach: float = 0.045, finger_half: float = 0.01):
        self.ws = workspace
        self.layout = PixelActionLayout(1, workspace.num_rotations, workspace.heightmap_size, workspace.heightmap_size)
        self.object_threshold = object_threshold
        self.top_band = top_band
        self.max_width = max_width
        self.finger_reach = finger_reach
        self.finger_half = finger_half

    def __call__(self, height) -> int:
        """Flat action index of the chosen grasp."""
        return self.choose(height).action

    def choose(self, height) -> GraspChoice:
        """The chosen grasp for heightmap ``height`` (H×W metres above the table; numpy or torch)."""
        h = height.detach().cpu().numpy() if isinstance(height, torch.Tensor) else np.asarray(height)
        h = h.reshape(h.shape[-2:]).astype(np.float64)
        labels, n = ndimage.label(h > self.object_threshold)
        if n == 0:
            r, c = np.unravel_index(int(np.argmax(h)), h.shape)
            return GraspChoice(self.layout.encode(0, 0, int(r), int(c)), 0, int(r), int(c), 0.0, False)
        peaks = ndimage.maximum(h, labels, index=np.arange(1, n + 1))
        fallback = None
        for k in np.argsort(-np.asarray(peaks)):
            mask = labels == k + 1
            if mask.sum() < 9:  # speckle
                continue
            top = mask & (h >= peaks[k] - self.top_band)
            rows, cols = np.nonzero(top)
            centre = np.array([rows.mean(), cols.mean()])
            i = int(np.argmin((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2))
            r, c = int(rows[i]), int(cols[i])
            rot, width, ok = self._best_rotation(h, r, c)
            choice = GraspChoice(self.layout.encode(0, rot, r, c), rot, r, c, width, ok)
            if ok:
                return choice
            fallback = fallback or choice
        return fallback

    def _best_rotation(self, h: np.ndarray, r: int, c: int) -> tuple[int, float, bool]:
        px = self.ws.pixel_size
        tip = self.ws.grasp_tcp_height(float(h[r, c])) - self.ws.table_z
        size = h.shape[0]
        steps = np.arange(-int(self.max_width / px), int(self.max_width / px) + 1)
        best = (0, np.inf, False)
        for rot in range(self.ws.num_rotations):
            yaw = self.ws.rotation_to_yaw(rot)
            d = np.array([np.sin(yaw), np.cos(yaw)])  # (row, col) step of the closing direction (row ~ y, col ~ x)
            rr = np.clip(np.round(r + steps * d[0]).astype(int), 0, size - 1)
            cc = np.clip(np.round(c + steps * d[1]).astype(int), 0, size - 1)
            solid = h[rr, cc] > tip + 0.003
            mid = len(steps) // 2
            lo = mid
            while lo > 0 and solid[lo - 1]:
                lo -= 1
            hi = mid
            while hi < len(steps) - 1 and solid[hi + 1]:
                hi += 1
            width = (hi - lo + 1) * px
            free = all(self._patch_free(h, r + s * self.finger_reach / px * d[0], c + s * self.finger_reach / px * d[1], tip) for s in (-1, 1))
            ok = width <= self.max_width and free
            if (ok, -width) > (best[2], -best[1]):
                best = (rot, width, ok)
        return best

    def _patch_free(self, h: np.ndarray, r: float, c: float, tip: float) -> bool:
        k = max(1, int(round(self.finger_half / self.ws.pixel_size)))
        r, c = int(round(r)), int(round(c))
        size = h.shape[0]
        patch = h[max(r - k, 0): min(r + k + 1, size), max(c - k, 0): min(c + k + 1, size)]
        return patch.size == 0 or float(patch.max()) < tip + 0.01
