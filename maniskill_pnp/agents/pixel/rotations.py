"""Rotation indices of the pixel Q networks, shared by both kinds of network.

Both :class:`~maniskill_pnp.agents.pixel.fcn.PixelQNetwork` and
:class:`~maniskill_pnp.agents.pixel.equivariant.EquivariantPixelQNetwork` give ``R`` Q maps per heightmap, rotation
``r`` being the jaw direction ``yaw = r * 2*pi / R`` of :class:`~maniskill_pnp.cell.workspace.WorkspaceSpec`; this
module checks the rotation indices of their ``rotation_maps`` queries. It imports neither network, so that both can
import it (:mod:`~maniskill_pnp.agents.pixel.fcn` imports :mod:`~maniskill_pnp.agents.pixel.equivariant`, never the
reverse).
"""

from __future__ import annotations

import torch


def rotation_query(heightmaps: torch.Tensor, rotation: torch.Tensor, num_rotations: int) -> torch.Tensor:
    """The rotation indices of a ``rotation_maps`` query as a flat int64 tensor, one per heightmap.

    Raises:
        ValueError: heightmaps are not ``(N, 4, H, W)`` with ``N`` rotations, or an index is outside ``0..R-1``.
    """
    rotation = rotation.reshape(-1).long()
    if rotation.shape[0] != heightmaps.shape[0] or heightmaps.ndim != 4:
        raise ValueError(f"need heightmaps (N, 4, H, W) and N rotations, got {tuple(heightmaps.shape)}, {tuple(rotation.shape)}")
    if rotation.numel() and (int(rotation.min()) < 0 or int(rotation.max()) >= num_rotations):
        raise ValueError(f"rotation index out of range 0..{num_rotations - 1}")
    return rotation


__all__ = ["rotation_query"]
