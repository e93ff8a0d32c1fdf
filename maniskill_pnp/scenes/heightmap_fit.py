"""Whether a top-down Panda grasp fits where a heightmap shows it: the camera's view of
:mod:`~maniskill_pnp.scenes.grasp_feasibility`, which reads the objects' collision shapes.

A grasp at a pixel and rotation *fits* when

1. the open gripper (its fingers' collision boxes and its hand's hull, from the robot's URDF), lowered straight down
   to the grasp's fingertip height (:meth:`~maniskill_pnp.cell.workspace.WorkspaceSpec.grasp_tcp_height` of the height
   at the pixel), stays above every height of the map under it, within ``fit_tolerance``: a grasp whose fingers would
   strike a neighbour or land on the object itself (wider than the open jaws) does not fit; and
2. closing would bear on material: along each pad's two edges and middle, closing from its inner face meets
   material that reaches into the pads' height band, and where it is met differs across the pad's width by at most
   the friction slope of :mod:`~maniskill_pnp.scenes.grasp_feasibility` plus a pixel (a corner pinched obliquely is
   no grasp).

No object state enters it, only what the camera shows, so a real cell computes it the same way. The agents' action
mask offers only the grasps that fit (:class:`~maniskill_pnp.agents.pixel.mask.HeightmapActionMask`), and the
``fit_gain`` slide reward of ClutterGraspSlide-v1 pays a slide by the graspable regions it adds
(:func:`graspable_regions`).

Example:
    >>> fit = HeightmapGraspFit.for_workspace(WorkspaceSpec(heightmap_size=64))
    >>> occupied = height > 0.01
    >>> fits = fit(height, occupied)                          # (N, R, H, W) booleans
    >>> graspable_regions(fits[0].any(dim=0), occupied[0])    # regions of material that some grasp fits
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage

from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.grasp_feasibility import FRICTION, MIN_GRIP, lowest_per_offset, panda_gripper

#: Default tolerance (m) of the fit test: a finger may come this close above a height of the map (its noise).
FIT_TOLERANCE = 0.003


@dataclass(frozen=True)
class HeightmapGraspFit:
    """The grasp-fit test of heightmaps of ``pixel_size`` pixels, at ``num_rotations`` jaw rotations.

    Args:
        num_rotations: Rotations; rotation ``r`` closes the jaws along ``r * 360° / num_rotations`` from the column
            axis (world x).
        pixel_size: Side of a heightmap pixel (m).
        grasp_depth: How far below the height at the pixel the fingertip TCP goes (m).
        min_tip_height: The fingertip TCP never goes below this height above the table (m).
        fit_tolerance: A gripper point may be this far (m) below a height of the map and still count as clear.
    """

    num_rotations: int
    pixel_size: float = 0.002
    grasp_depth: float = 0.02
    min_tip_height: float = 0.012
    fit_tolerance: float = FIT_TOLERANCE

    def __post_init__(self):
        if not isinstance(self.num_rotations, int) or self.num_rotations < 1:
            raise ValueError(f"num_rotations must be a positive int, got {self.num_rotations!r}")
        if not self.pixel_size > 0 or self.min_tip_height < 0 or self.fit_tolerance < 0:
            raise ValueError(
                f"pixel_size must be > 0, min_tip_height and fit_tolerance >= 0 (m), got {self.pixel_size!r}, "
                f"{self.min_tip_height!r}, {self.fit_tolerance!r}"
            )

    @classmethod
    def for_workspace(cls, workspace: WorkspaceSpec, fit_tolerance: float = FIT_TOLERANCE) -> "HeightmapGraspFit":
        """The test of a workspace's heightmaps and grasps."""
        return cls(workspace.num_rotations, workspace.pixel_size, workspace.finger_length - workspace.grasp_z_offset,
                   workspace.min_tip_height, fit_tolerance)

    def __call__(self, height: torch.Tensor, where: torch.Tensor, fit: torch.Tensor | None = None) -> torch.Tensor:
        """``bool (N, R, H, W)``: at the pixels of ``where`` ``(N, H, W)``, whether a grasp at each rotation fits the
        heightmap ``height`` ``(N, H, W)`` (m above the table; extended by bare table beyond its edges); False
        elsewhere.

        With a fit heightmap ``fit`` ``(N, k·H, k·W)`` (the same square on a ``k`` times finer grid) the two tests
        read it instead, around each grasp pixel's centre; the fingertip height still follows ``height`` at the pixel,
        as the task's grasp does.
        """
        n, h, w = height.shape
        scale, fine = 1, height
        if fit is not None:
            scale = fit.shape[-1] // w
            if fit.shape != (n, scale * h, scale * w) or scale < 1:
                raise ValueError(f"the fit heightmap must be (N, k*H, k*W) for a whole k >= 1 with the heightmap "
                                 f"{tuple(height.shape)}, got {tuple(fit.shape)}")
            fine = fit.to(height.dtype)
        reach, descent, closing, model = gripper_cells(self.pixel_size, self.num_rotations, scale)
        k, dev = 2 * reach + 1, height.device
        windows = F.pad(fine, (reach, reach, reach, reach)).unfold(1, k, 1).unfold(2, k, 1)  # (N, kH, kW, K, K) view
        at = where.nonzero(as_tuple=True)
        around = windows[at[0], at[1] * scale + scale // 2, at[2] * scale + scale // 2].reshape(-1, k * k)
        tcp = torch.clamp(height[at] - self.grasp_depth, min=self.min_tip_height)
        band = (tcp + model.pad_band[0] + MIN_GRIP)[:, None, None, None]
        step = self.pixel_size / scale
        spread = FRICTION * 2 * model.pad_half_width + step
        closing = closing.to(dev)
        fits = torch.zeros(n, self.num_rotations, h, w, dtype=torch.bool, device=dev)
        if not len(tcp):
            return fits
        # a gripper cell this high above the fingertips clears the map's highest point (bare table beyond its edges)
        # at the lowest fingertip height of the batch: it cannot decide a test, so it is left out
        clears_all = float(fine.max().clamp(min=0.0) - tcp.min()) - self.fit_tolerance
        for rot, (index, lowest) in enumerate(descent):
            risky = lowest < clears_all
            index, lowest = index[risky].to(dev), lowest[risky].to(dev)
            clear = (around[:, index] - lowest).amax(dim=-1) <= tcp + self.fit_tolerance if len(index) else \
                torch.ones_like(tcp, dtype=torch.bool)
            material = around[:, closing[rot]] > band  # (M, 2 pads, 3 lines, S)
            met = material.any(dim=-1)
            first = material.to(torch.uint8).argmax(dim=-1).float() * (step / 2)  # travel to first contact
            flat = (first.amax(dim=-1) - first.amin(dim=-1) <= spread).all(dim=-1)
            fits[at[0], rot, at[1], at[2]] = clear & met.all(dim=-1).all(dim=-1) & flat
        return fits


def graspable_regions(graspable: np.ndarray | torch.Tensor, occupied: np.ndarray | torch.Tensor) -> int:
    """How many connected regions of material (``occupied`` ``(H, W)``, 8-neighbourhood) hold a pixel of
    ``graspable`` ``(H, W)`` (where some grasp fits): about the objects, as the camera separates them, that a grasp can
    take. Objects pressed together are one region, graspable when a grasp fits one of them; the pixels where grasps
    fit a single object need not be connected (a neighbour can block some rotations), so they are not counted
    themselves."""
    graspable, occupied = (np.asarray(m.cpu() if isinstance(m, torch.Tensor) else m, dtype=bool)
                           for m in (graspable, occupied))
    if graspable.ndim != 2 or graspable.shape != occupied.shape:
        raise ValueError(f"graspable and occupied must be (H, W) maps of one shape, got {graspable.shape} and "
                         f"{occupied.shape}")
    labels, _ = ndimage.label(occupied, structure=np.ones((3, 3), dtype=bool))
    return int(np.count_nonzero(np.unique(labels[graspable & occupied])))


@functools.cache
def pusher_half_width() -> float:
    """Half the width (m) of the closed Panda fingers across a slide's push: the extent along the jaws of the gripper's
    points within 2 cm of the fingertips."""
    points = panda_gripper(opening=0.0).points
    return float(np.abs(points[points[:, 2] < 0.02, 1]).max())


@functools.cache
def gripper_cells(pixel_size: float, num_rotations: int, scale: int):
    """The open gripper over a map ``scale`` times finer than heightmap pixels of ``pixel_size``: ``(reach, descent,
    closing, model)``, indices into the flattened ``(2 * reach + 1)²`` neighbourhood of the fine pixel at a grasp
    pixel's centre (the one whose lower corner it is, for an even ``scale``).

    ``descent[r]`` is ``(index, lowest)``: the neighbourhood cells under the gripper at rotation ``r`` and its
    lowest height above the fingertip TCP over each (m). ``closing[r]`` ``(2, 3, S)``: for each pad (+y, -y), three
    lines across its width (its two edges and middle) from its inner face towards the other pad, ``S`` cells half a
    fine pixel apart. ``reach`` is the largest offset (fine pixels), ``model`` the
    :class:`~maniskill_pnp.scenes.grasp_feasibility.GripperModel`. Rotation ``r`` closes the jaws along
    ``r * 360° / num_rotations`` from the column axis."""
    model = panda_gripper()
    points = model.points  # x along the pads' width, y the closing direction, lowest height above the TCP
    cell = pixel_size / scale
    travel = np.arange(0.0, 2 * model.pad_inner + cell / 4, cell / 2)
    lines = np.array([[[(x, sign * (model.pad_inner - t)) for t in travel]
                       for x in (-model.pad_half_width, 0.0, model.pad_half_width)] for sign in (1.0, -1.0)])

    def cells(xy: np.ndarray, yaw: float) -> np.ndarray:  # grasp-frame (x, y) -> fine-pixel offsets (row, col)
        dx = xy[..., 1] * np.cos(yaw) - xy[..., 0] * np.sin(yaw)
        dy = xy[..., 1] * np.sin(yaw) + xy[..., 0] * np.cos(yaw)
        offsets = np.stack([dy, dx], axis=-1) / cell
        # an odd scale puts a fine pixel's centre on the grasp pixel's, an even one a fine pixel's corner
        return (np.round(offsets) if scale % 2 else np.floor(offsets)).astype(np.int64)

    under, closing = [], []
    for rot in range(num_rotations):
        yaw = rot * 2 * np.pi / num_rotations
        under.append(lowest_per_offset(cells(points[:, :2], yaw), points[:, 2]))
        closing.append(cells(lines, yaw))
    closing = np.stack(closing)
    reach = int(max(max(np.abs(keys).max() for keys, _ in under), np.abs(closing).max()))
    k = 2 * reach + 1

    def flat(offsets: np.ndarray) -> torch.Tensor:
        return torch.from_numpy((offsets[..., 0] + reach) * k + offsets[..., 1] + reach)

    descent = [(flat(keys), torch.from_numpy(lowest).float()) for keys, lowest in under]
    return reach, descent, flat(closing), model


__all__ = ["FIT_TOLERANCE", "HeightmapGraspFit", "graspable_regions", "gripper_cells", "pusher_half_width"]
