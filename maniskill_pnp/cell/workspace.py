"""Workspace geometry of the vision tasks: one frozen dataclass shared by the env and the agents.

:class:`WorkspaceSpec` is the single source of truth for the heightmap grid (bounds, pixel size, size), the
rotations of the pixelwise action, the cameras that see the workspace, the table height, the bin and the
grasp height rule. The env builds its cameras and heightmaps from it and an agent maps pixels to world
points with the same object, so the two can never disagree about a constant.

Grid convention (as in VPG): ``heightmap[row, col]``; ``col`` grows with world x and ``row`` with world y, the
pixel centre of ``(row, col)`` is ``(x_min + (col + 0.5) * pixel_size, y_min + (row + 0.5) * pixel_size)``.
Rotation index ``r`` means a grasp whose jaws close along ``yaw = r * 2π / num_rotations`` from world x.
A slide with rotation ``r`` pushes perpendicular to that jaw line: "left" is the jaw direction turned by +90°
(counter-clockwise seen from above, world z up), ``(-sin yaw, cos yaw)``; "right" is the opposite,
``(sin yaw, -cos yaw)``. In the heightmap rotated so that the jaws close along its column axis, left is
towards growing rows. Rotation 0: jaws along +x, left = +y, right = -y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from maniskill_pnp.cell.bin import BinSpec

#: The rotation step must be a whole number of 1/ROTATION_STEP_DIVISOR degrees.
ROTATION_STEP_DIVISOR = 1000


#: Where the clutter cell's Panda stands (world, m): its base, beside the table's near edge.
DEFAULT_ROBOT_BASE = (-0.615, 0.0, 0.0)

@dataclass(frozen=True)
class CameraSpec:
    """A pinhole RGB-D camera looking at the workspace.

    Attributes:
        name: Sensor name (key of the sensor data).
        eye: Camera position (world, m).
        target: Point the optical axis goes through (world, m).
        up: Up hint of the image (world vector); must not be parallel to the viewing direction.
        width: Image width (px).
        height: Image height (px).
        fov: Vertical field of view (rad).
        near: Near clip plane (m).
        far: Far clip plane (m).
    """

    name: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    width: int = 320
    height: int = 320
    fov: float = 1.0
    near: float = 0.05
    far: float = 3.0


def default_cameras(c: tuple[float, float]) -> tuple[CameraSpec, ...]:
    """The two cameras of the thesis' set-up for a workspace centred at ``c`` (x, y)."""
    # Top: 1.6 m above the table with a narrow field of view: nearly orthographic, ~1.8 mm per pixel on the table.
    top = CameraSpec("top_camera", eye=(c[0], c[1], 1.6), target=(c[0], c[1], 0.0), up=(1.0, 0.0, 0.0), fov=0.35)
    # Perspective: in front of the workspace (the robot stands behind it), looking down at about 45 degrees.
    side = CameraSpec("perspective_camera", eye=(c[0] + 0.55, c[1] - 0.25, 0.6), target=(c[0], c[1], 0.0), fov=0.9)
    return (top, side)


@dataclass(frozen=True)
class WorkspaceSpec:
    """Geometry of a pixelwise-action workspace (world frame, metres).

    Attributes:
        center: Centre (x, y) of the heightmap square on the table.
        heightmap_size: Pixels per side of the square heightmap.
        pixel_size: Side of one heightmap pixel (m).
        num_rotations: Grasp yaws, evenly spaced over 360 degrees; the step ``360 / num_rotations`` must be exact
            to 1/1000 degree (16 gives the thesis' 22.5 degrees; 7 is rejected).
        table_z: Height of the table top (heights are measured from it).
        max_height: Heights above this (m above the table) are ignored when building heightmaps.
        spawn_margin: Clutter is spawned at least this far (m) inside the heightmap's edges.
        grasp_z_offset: The thesis' "+3 cm": the jaw reference point goes this far above the surface seen at p.
        finger_length: Distance from that jaw reference (the base of the finger pads) down to the fingertip TCP;
            the TCP therefore goes to ``surface + grasp_z_offset - finger_length``.
        min_tip_height: The fingertip TCP never goes below this height above the table.
        slide_length: Length of a slide (push) primitive (m); the thesis' 8 cm.
        slide_clearance: Half side (m) of the square around a slide's start pixel whose highest point sets the
            closed fingertips' height (VPG's "safe z": the tip comes down beside objects, never onto them).
        cameras: The RGB-D cameras fused into the heightmap; None: :func:`default_cameras` of ``center`` (a
            top-down narrow-FOV one and a perspective one).
        bin: The place bin, beside the workspace.
        fit_scale: Fine pixels per heightmap pixel side of the *fit heightmap*, the same cameras' heights on a finer
            grid (:attr:`fit_grid`) that the grasp-fit test of the pixel agents reads (their networks keep the
            heightmap); 1: none.
    """

    center: tuple[float, float] = (-0.06, -0.1)
    heightmap_size: int = 224
    pixel_size: float = 0.002
    num_rotations: int = 16
    table_z: float = 0.0
    max_height: float = 0.3
    spawn_margin: float = 0.06
    grasp_z_offset: float = 0.03
    finger_length: float = 0.05
    min_tip_height: float = 0.012
    slide_length: float = 0.08
    slide_clearance: float = 0.01
    cameras: tuple[CameraSpec, ...] | None = None
    bin: BinSpec = field(default_factory=BinSpec)
    fit_scale: int = 1

    def __post_init__(self):
        k = self.fit_scale
        if not isinstance(k, (int, np.integer)) or isinstance(k, bool) or k < 1:
            raise ValueError(f"fit_scale must be a positive integer (1: no fit heightmap), got {k!r}")
        if not isinstance(self.heightmap_size, (int, np.integer)) or self.heightmap_size <= 0:
            raise ValueError(f"heightmap_size must be a positive integer, got {self.heightmap_size!r}")
        if not self.pixel_size > 0:
            raise ValueError(f"pixel_size must be > 0 (m), got {self.pixel_size!r}")
        r = self.num_rotations
        if not isinstance(r, (int, np.integer)) or isinstance(r, bool) or r <= 0 or (360 * ROTATION_STEP_DIVISOR) % r:
            raise ValueError(
                f"num_rotations must divide 360 degrees evenly (a step that is a whole number of 1/{ROTATION_STEP_DIVISOR} "
                f"degrees, e.g. 4, 8, 16 = 22.5 degrees), got {r!r}"
            )
        if not self.slide_length > 0 or not self.slide_clearance >= 0:
            raise ValueError(f"slide_length must be > 0 and slide_clearance >= 0, got {self.slide_length!r}, {self.slide_clearance!r}")
        if not self.max_height > 0:
            raise ValueError(f"max_height must be > 0, got {self.max_height!r}")
        if not 0 <= self.spawn_margin < self.side / 2:
            raise ValueError(f"spawn_margin must be in [0, {self.side / 2}), got {self.spawn_margin!r}")
        if self.cameras is None:
            object.__setattr__(self, "cameras", default_cameras(self.center))
        if not self.cameras:
            raise ValueError("at least one camera is needed to build heightmaps")
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must be unique, got {names}")

    # ------------------------------------------------------------------ bounds
    @property
    def side(self) -> float:
        """Side of the heightmap square (m)."""
        return self.heightmap_size * self.pixel_size

    @property
    def fit_grid(self) -> WorkspaceSpec:
        """The workspace on the fit heightmap's grid: ``fit_scale`` times the pixels per side over the same square."""
        k = int(self.fit_scale)
        return replace(self, heightmap_size=self.heightmap_size * k, pixel_size=self.pixel_size / k, fit_scale=1)

    @property
    def bounds(self) -> np.ndarray:
        """``[[x_min, x_max], [y_min, y_max], [z_min, z_max]]`` of the heightmap volume (world, m)."""
        h = self.side / 2
        cx, cy = self.center
        return np.array([[cx - h, cx + h], [cy - h, cy + h], [self.table_z, self.table_z + self.max_height]])

    @property
    def spawn_bounds(self) -> np.ndarray:
        """``[[x_min, x_max], [y_min, y_max]]`` where clutter is spawned (the bounds shrunk by ``spawn_margin``)."""
        b = self.bounds[:2].copy()
        b[:, 0] += self.spawn_margin
        b[:, 1] -= self.spawn_margin
        return b

    def contains_xy(self, xy) -> np.ndarray:
        """True where the world point(s) ``xy`` (..., 2) lie over the heightmap square."""
        xy = np.asarray(xy, dtype=np.float64)
        b = self.bounds
        return (xy[..., 0] >= b[0, 0]) & (xy[..., 0] <= b[0, 1]) & (xy[..., 1] >= b[1, 0]) & (xy[..., 1] <= b[1, 1])

    # ------------------------------------------------------------------ pixel <-> world
    def pixel_to_world(self, row, col, height):
        """World point(s) of pixel centre ``(row, col)`` at ``height`` m above the table.

        Works on Python numbers, numpy arrays and torch tensors (broadcast); returns (..., 3) of the same kind.
        """
        b = self.bounds
        if isinstance(row, torch.Tensor) or isinstance(col, torch.Tensor) or isinstance(height, torch.Tensor):
            ref = next(t for t in (row, col, height) if isinstance(t, torch.Tensor))
            row, col, height = (torch.as_tensor(v, dtype=torch.float64, device=ref.device) for v in (row, col, height))
            x = b[0, 0] + (col + 0.5) * self.pixel_size
            y = b[1, 0] + (row + 0.5) * self.pixel_size
            return torch.stack(torch.broadcast_tensors(x, y, height + self.table_z), dim=-1)
        row, col, height = (np.asarray(v, dtype=np.float64) for v in (row, col, height))
        x = b[0, 0] + (col + 0.5) * self.pixel_size
        y = b[1, 0] + (row + 0.5) * self.pixel_size
        return np.stack(np.broadcast_arrays(x, y, height + self.table_z), axis=-1)

    def world_to_pixel(self, xyz):
        """``(row, col)`` integer pixel(s) containing world point(s) ``xyz`` (..., 2 or 3); -1 where outside the grid."""
        if isinstance(xyz, torch.Tensor):
            b = torch.as_tensor(self.bounds, dtype=xyz.dtype, device=xyz.device)
            col = torch.floor((xyz[..., 0] - b[0, 0]) / self.pixel_size).long()
            row = torch.floor((xyz[..., 1] - b[1, 0]) / self.pixel_size).long()
            bad = (col < 0) | (col >= self.heightmap_size) | (row < 0) | (row >= self.heightmap_size)
            return torch.where(bad, -1, row), torch.where(bad, -1, col)
        xyz = np.asarray(xyz, dtype=np.float64)
        b = self.bounds
        col = np.floor((xyz[..., 0] - b[0, 0]) / self.pixel_size).astype(np.int64)
        row = np.floor((xyz[..., 1] - b[1, 0]) / self.pixel_size).astype(np.int64)
        bad = (col < 0) | (col >= self.heightmap_size) | (row < 0) | (row >= self.heightmap_size)
        return np.where(bad, -1, row), np.where(bad, -1, col)

    def rotation_to_yaw(self, rotation):
        """Jaw closing direction (rad from world x) of rotation index ``rotation``."""
        return rotation * (2 * math.pi / self.num_rotations)

    def grasp_tcp_height(self, surface_height: float) -> float:
        """World z of the fingertip TCP for a grasp at a pixel whose surface is ``surface_height`` m above the table.

        The thesis adds 3 cm to the z of the pixel's 3-D point for its gripper's reference point. The Panda's TCP is
        at the fingertips, ``finger_length`` below the base of its finger pads, so the fingertips go
        ``finger_length - grasp_z_offset`` (2 cm by default) below the surface: the pads close on the top part of
        the object. They never go lower than ``min_tip_height`` above the table.
        """
        tip = surface_height + self.grasp_z_offset - self.finger_length
        return self.table_z + max(tip, self.min_tip_height)

    def slide_direction(self, rotation, side: str) -> np.ndarray:
        """Unit push direction (x, y) of a slide with rotation index ``rotation``; ``side`` is "left" or "right".

        Left is the jaw direction turned by +90° about world z (see the module docstring), right the opposite.
        """
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        yaw = self.rotation_to_yaw(rotation)
        sign = 1.0 if side == "left" else -1.0
        return sign * np.array([-math.sin(yaw), math.cos(yaw)])

    def slide_tip_height(self, height: np.ndarray, row: int, col: int) -> float:
        """World z of the closed fingertips during a slide that starts at pixel ``(row, col)`` of ``height``.

        The highest point of ``height`` (m above the table) within ``slide_clearance`` of the pixel, so the tip comes
        down on nothing; never lower than ``min_tip_height``.
        """
        k = int(round(self.slide_clearance / self.pixel_size))
        patch = np.asarray(height)[max(row - k, 0): row + k + 1, max(col - k, 0): col + k + 1]
        return self.table_z + max(float(patch.max()), self.min_tip_height)
