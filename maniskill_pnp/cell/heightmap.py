"""RGB-D images → world point clouds → orthographic heightmaps over the workspace grid (batched torch).

Pipeline (VPG's, on tensors with a leading batch dimension, CPU or GPU):

1. :func:`depth_to_world_points`: back-project each camera's depth image (ManiSkill's ``sensor_data`` depth:
   int16 millimetres along the optical axis, 0 where nothing was hit) through its OpenCV intrinsics and the
   camera-to-world transform (inverse of ``extrinsic_cv``) into world points.
2. :func:`project_heightmap`: drop the points of all cameras straight down (along gravity) onto the
   workspace grid of a :class:`~maniskill_pnp.cell.workspace.WorkspaceSpec` and keep, per pixel, the highest
   point (``scatter_reduce`` with ``amax``) and its colour.
3. :func:`fill_holes`: pixels no point fell into take the mean of their filled neighbours, a few passes.

:func:`heightmaps_from_sensors` runs the three on ManiSkill's ``sensor_data`` / ``sensor_param`` dicts.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping

import torch
import torch.nn.functional as F

from maniskill_pnp.cell.workspace import WorkspaceSpec

#: Depth units of ManiSkill's int16 depth textures (metres per unit).
DEPTH_UNIT = 1e-3


def depth_to_world_points(depth: torch.Tensor, intrinsic_cv: torch.Tensor, extrinsic_cv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World points of a batch of depth images.

    Args:
        depth: (B, H, W) or (B, H, W, 1) depth along the optical axis, metres (float) or millimetres (int16).
        intrinsic_cv: (B, 3, 3) OpenCV intrinsics.
        extrinsic_cv: (B, 3, 4) or (B, 4, 4) world-to-camera transform (OpenCV camera axes).

    Returns:
        points (B, H*W, 3) in world metres and valid (B, H*W) — False where the depth is 0 (no hit).
    """
    if depth.dim() == 4:
        depth = depth[..., 0]
    z = depth.to(torch.float32) * (DEPTH_UNIT if not depth.dtype.is_floating_point else 1.0)
    b, h, w = z.shape
    dev = z.device
    k = intrinsic_cv.to(dev, torch.float32)
    # SAPIEN's intrinsics put pixel (u, v)'s centre at (u + 0.5, v + 0.5).
    v, u = torch.meshgrid(torch.arange(h, device=dev, dtype=torch.float32) + 0.5, torch.arange(w, device=dev, dtype=torch.float32) + 0.5, indexing="ij")
    fx, fy, cx, cy = k[:, 0, 0, None, None], k[:, 1, 1, None, None], k[:, 0, 2, None, None], k[:, 1, 2, None, None]
    cam = torch.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], dim=-1).reshape(b, -1, 3)
    ext = extrinsic_cv.to(dev, torch.float32)
    rot, trans = ext[:, :3, :3], ext[:, :3, 3]
    # World = R^T (p_cam - t); in row-vector form p_cam @ R - t @ R.
    world = torch.baddbmm(-(trans[:, None, :] @ rot), cam, rot)
    return world, (z > 0).reshape(b, -1)


def project_heightmap(
    points: torch.Tensor, colors: torch.Tensor, valid: torch.Tensor, spec: WorkspaceSpec
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Orthographic top-down projection of world points onto the workspace grid, highest point per pixel.

    Args:
        points: (B, N, 3) world points (m).
        colors: (B, N, 3) colours (any numeric dtype; returned as float).
        valid: (B, N) points to use.
        spec: The workspace grid.

    Returns:
        height (B, S, S) float32 metres above the table, color (B, S, S, 3) float32, filled (B, S, S) bool — False
        where no point fell into the pixel (height 0 and colour 0 there).
    """
    b, n, _ = points.shape
    s = spec.heightmap_size
    dev = points.device
    bounds = torch.as_tensor(spec.bounds, dtype=torch.float32, device=dev)
    col = torch.floor((points[..., 0] - bounds[0, 0]) / spec.pixel_size)
    row = torch.floor((points[..., 1] - bounds[1, 0]) / spec.pixel_size)
    hgt = points[..., 2] - spec.table_z
    keep = valid & (col >= 0) & (col < s) & (row >= 0) & (row < s) & (hgt > -0.01) & (hgt < spec.max_height)
    # One flat index over (batch, pixel) per point; the points not kept go to one extra pixel, cut off at the end
    # (elementwise and scatter work over every point is cheaper than picking the kept ones out). row * s + col is a
    # whole number below s * s where kept, exact in float32.
    offset = torch.arange(b, device=dev)[:, None] * (s * s)
    flat = torch.where(keep, torch.where(keep, row * s + col, 0.0).long() + offset, b * s * s).reshape(-1)
    hk = torch.where(keep, hgt.clamp(min=0.0), -1.0).reshape(-1)
    best = torch.full((b * s * s + 1,), -1.0, device=dev).scatter_reduce(0, flat, hk, reduce="amax", include_self=True)
    # Colour of the highest point: of the points that reach their pixel's maximum, the last one (in point order).
    top = keep.reshape(-1) & (hk >= best[flat])
    order = torch.where(top, torch.arange(b * n, device=dev), -1)
    last = torch.full((b * s * s + 1,), -1, dtype=order.dtype, device=dev).scatter_reduce(0, flat, order, reduce="amax")
    best, last = best[:-1], last[:-1]
    filled = best >= 0
    color = torch.zeros((b * s * s, 3), device=dev)
    color[filled] = colors.reshape(b * n, -1)[last[filled]].to(torch.float32)
    return best.clamp(min=0.0).reshape(b, s, s), color.reshape(b, s, s, 3), filled.reshape(b, s, s)


def fill_holes(height: torch.Tensor, color: torch.Tensor, filled: torch.Tensor, passes: int = 3) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Fill unseen pixels with the mean of their seen 3×3 neighbours, ``passes`` times (a hole grows in by one pixel a pass).

    Args/returns as :func:`project_heightmap`'s outputs; ``filled`` comes back updated.
    """
    b, s = height.shape[0], height.shape[-1]
    x = torch.cat([height[:, None], color.permute(0, 3, 1, 2)], dim=1).reshape(b * 4, 1, s, s)
    m = filled[:, None].to(x.dtype).repeat(1, 4, 1, 1).reshape(b * 4, 1, s, s)
    ones = torch.ones((1, 1, 3, 3), dtype=x.dtype, device=x.device)
    for _ in range(passes):
        if bool(m.all()):
            break
        num = F.conv2d(x * m, ones, padding=1)
        den = F.conv2d(m, ones, padding=1)
        new = (m == 0) & (den > 0)
        x = torch.where(new, num / den.clamp(min=1e-9), x)
        m = torch.where(new, torch.ones_like(m), m)
    x, m = x.reshape(b, 4, s, s), m.reshape(b, 4, s, s)
    return x[:, 0], x[:, 1:].permute(0, 2, 3, 1), m[:, 0] > 0


@contextlib.contextmanager
def _single_thread_on_cpu(device: torch.device):
    """One intra-op thread on CPU: these tensors are too small to gain from more, and on a busy 2-core machine
    torch's thread pool made a heightmap ~20x slower (0.8 s instead of 0.04 s)."""
    if device.type != "cpu":
        yield
        return
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def heightmaps_from_sensors(
    sensor_data: Mapping[str, Mapping[str, torch.Tensor]],
    sensor_param: Mapping[str, Mapping[str, torch.Tensor]],
    spec: WorkspaceSpec,
    cameras: tuple[str, ...] | None = None,
    fill_passes: int = 3,
    fit: bool = False,
) -> tuple[torch.Tensor, ...]:
    """Colour and height heightmaps fused from ManiSkill cameras.

    Args:
        sensor_data: ``{camera: {"rgb": (B,H,W,3) uint8, "depth": (B,H,W,1) int16 mm}}``.
        sensor_param: ``{camera: {"intrinsic_cv": (B,3,3), "extrinsic_cv": (B,3,4)}}``.
        spec: The workspace grid.
        cameras: Cameras to fuse (default: every camera of ``spec``).
        fill_passes: Hole-filling passes (0: none).
        fit: Also the fit heightmap: the same points' heights on ``spec.fit_grid`` (its holes filled as well).

    Returns:
        color (B, S, S, 3) uint8 and height (B, S, S) float32 metres above the table (0 where nothing was seen); with
        ``fit`` a third, the fit heightmap (B, k·S, k·S) float32 (k = ``spec.fit_scale``).
    """
    names = cameras or tuple(c.name for c in spec.cameras)
    with _single_thread_on_cpu(sensor_data[names[0]]["depth"].device):
        points = _world_points(sensor_data, sensor_param, names)
        color, height = _project(*points, spec, fill_passes)
        if not fit:
            return color, height
        return color, height, _project(*points, spec.fit_grid, fill_passes)[1]


def _world_points(sensor_data, sensor_param, names):
    pts, cols, val = [], [], []
    for name in names:
        data, param = sensor_data[name], sensor_param[name]
        p, v = depth_to_world_points(data["depth"], param["intrinsic_cv"], param["extrinsic_cv"])
        pts.append(p)
        val.append(v)
        cols.append(data["rgb"].reshape(p.shape[0], -1, 3).to(p.device))
    return torch.cat(pts, 1), torch.cat(cols, 1), torch.cat(val, 1)


def _project(points, colors, valid, spec, fill_passes):
    height, color, filled = project_heightmap(points, colors, valid, spec)
    if fill_passes:
        height, color, filled = fill_holes(height, color, filled, fill_passes)
    return color.round().clamp(0, 255).to(torch.uint8), height.to(torch.float32)
