"""The flat pixelwise action index over (primitive, rotation, row, col), encoded and decoded in one place.

Index layout (row-major): ``index = ((primitive * R + rotation) * H + row) * W + col``. A grasp-only task has
one primitive, so its index is ``(rotation * H + row) * W + col``: the flat index of a Q-value tensor of shape
(primitives, rotations, H, W), which is what a pixelwise agent's ``argmax`` returns.

Example:
    >>> layout = PixelActionLayout(num_primitives=1, num_rotations=16, height=224, width=224)
    >>> layout.decode(layout.encode(0, 3, 10, 20))
    (0, 3, 10, 20)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


def _is_integral(x) -> bool:
    if isinstance(x, torch.Tensor):
        return not x.dtype.is_floating_point and not x.dtype.is_complex and x.dtype != torch.bool
    if isinstance(x, (bool, np.bool_)):
        return False
    if isinstance(x, (int, np.integer)):
        return True
    if isinstance(x, np.ndarray):
        return np.issubdtype(x.dtype, np.integer)
    return False


@dataclass(frozen=True)
class PixelActionLayout:
    """Sizes of the (primitive, rotation, row, col) action grid.

    Attributes:
        num_primitives: Number of primitives (1 for grasp only; 3 for grasp, left slide, right slide).
        num_rotations: Number of rotations.
        height: Heightmap rows.
        width: Heightmap columns.
    """

    num_primitives: int
    num_rotations: int
    height: int
    width: int

    def __post_init__(self):
        for name in ("num_primitives", "num_rotations", "height", "width"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v <= 0:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(primitives, rotations, rows, cols)."""
        return (self.num_primitives, self.num_rotations, self.height, self.width)

    @property
    def size(self) -> int:
        """Number of flat indices."""
        return self.num_primitives * self.num_rotations * self.height * self.width

    def encode(self, primitive, rotation, row, col):
        """Flat index of ``(primitive, rotation, row, col)``: ints, integer numpy arrays or integer tensors (broadcast).

        Raises:
            ValueError: A component is not integral or is out of its range.
        """
        parts = (primitive, rotation, row, col)
        names = ("primitive", "rotation", "row", "col")
        for name, v, n in zip(names, parts, self.shape):
            if not _is_integral(v):
                raise ValueError(f"{name} must be an integer (or integer array/tensor), got {v!r}")
            lo, hi = (int(v.min()), int(v.max())) if not isinstance(v, (int, np.integer)) and np.size(v) else (int(v), int(v))
            if lo < 0 or hi >= n:
                raise ValueError(f"{name} out of range: valid values are 0..{n - 1}, got {lo if lo < 0 else hi}")
        p, r, i, j = parts
        _, R, H, W = self.shape
        if any(isinstance(v, torch.Tensor) for v in parts):
            dev = next(v.device for v in parts if isinstance(v, torch.Tensor))
            p, r, i, j = (torch.as_tensor(v, dtype=torch.int64, device=dev) for v in parts)
        elif any(isinstance(v, np.ndarray) for v in parts):
            p, r, i, j = (np.asarray(v, dtype=np.int64) for v in parts)
        else:
            p, r, i, j = (int(v) for v in parts)
        return ((p * R + r) * H + i) * W + j

    def decode(self, index):
        """``(primitive, rotation, row, col)`` of flat index/indices ``index`` (int, integer array or tensor).

        Raises:
            ValueError: ``index`` is not integral (floats, NaN, bools) or is outside ``0..size-1``.
        """
        if not _is_integral(index):
            raise ValueError(f"a pixel action index must be an integer in 0..{self.size - 1}, got {index!r}")
        if isinstance(index, torch.Tensor):
            idx = index.to(torch.int64)
        elif isinstance(index, np.ndarray):
            idx = index.astype(np.int64)
        else:
            idx = int(index)
        lo = int(idx.min()) if not isinstance(idx, int) and np.size(idx) else (idx if isinstance(idx, int) else 0)
        hi = int(idx.max()) if not isinstance(idx, int) and np.size(idx) else (idx if isinstance(idx, int) else 0)
        if lo < 0 or hi >= self.size:
            raise ValueError(f"pixel action index out of range: valid indices are 0..{self.size - 1}, got {lo if lo < 0 else hi}")
        _, R, H, W = self.shape
        col = idx % W
        row = (idx // W) % H
        rot = (idx // (W * H)) % R
        prim = idx // (W * H * R)
        return prim, rot, row, col
