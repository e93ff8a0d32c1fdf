"""World bounding boxes of a sub-scene's render bodies, from local boxes found once.

SAPIEN's ``RenderBodyComponent.get_global_aabb_fast`` moves each render shape's local box to the body's pose; under
cProfile its first call after a pose change took about half a millisecond for a Panda link's visual mesh (tens of
thousands of vertices). :class:`RenderBoxes` finds each shape's local box once and moves its eight corners with the
body's pose on every call: the same boxes (to float rounding; tested against SAPIEN's). Side by side, the render part
of a clutter decision measured no faster than with SAPIEN's call (the work seems to move into the render).

Example:
    >>> boxes = RenderBoxes(bodies)   # RenderBodyComponents of one sub-scene
    >>> lo, hi = boxes.world()        # (N, 3) each: the boxes at the bodies' current poses
"""

from __future__ import annotations

import numpy as np
import sapien

from maniskill_pnp.cell.view_volume import box_corners

#: (mesh file, scale) -> its box: the robot's links are rebuilt from the same files at every reconfiguration.
_FILE_BOXES: dict[tuple[str, tuple[float, ...]], tuple[np.ndarray, np.ndarray]] = {}


def _mesh_box(shape) -> tuple[np.ndarray, np.ndarray]:
    v = np.concatenate([np.asarray(p.vertices, dtype=np.float64) for p in shape.parts]) * np.asarray(shape.scale)
    return v.min(axis=0), v.max(axis=0)


def shape_box(shape) -> tuple[np.ndarray, np.ndarray] | None:
    """``(lo, hi)`` of render shape ``shape`` in its own frame, or None for a kind of shape not handled here."""
    render = sapien.render
    if isinstance(shape, render.RenderShapeTriangleMesh):
        if not shape.filename:
            return _mesh_box(shape)
        key = (shape.filename, tuple(float(v) for v in shape.scale))
        if key not in _FILE_BOXES:
            _FILE_BOXES[key] = _mesh_box(shape)
        return _FILE_BOXES[key]
    if isinstance(shape, render.RenderShapeBox):
        hi = np.asarray(shape.half_size, dtype=np.float64)
    elif isinstance(shape, render.RenderShapeSphere):
        hi = np.full(3, float(shape.radius))
    elif isinstance(shape, render.RenderShapeCylinder):  # SAPIEN's cylinders and capsules lie along x
        hi = np.array([shape.half_length, shape.radius, shape.radius], dtype=np.float64)
    elif isinstance(shape, render.RenderShapeCapsule):
        hi = np.array([shape.half_length + shape.radius, shape.radius, shape.radius], dtype=np.float64)
    else:
        return None
    return -hi, hi


def _moved(points: np.ndarray, pose: sapien.Pose) -> np.ndarray:
    t = pose.to_transformation_matrix()
    return points @ t[:3, :3].T + t[:3, 3]


class RenderBoxes:
    """The world axis-aligned boxes of ``bodies`` (SAPIEN ``RenderBodyComponent``), each the box of its shapes' local
    boxes moved to the body's pose, as ``get_global_aabb_fast`` gives them. A body with a kind of shape not handled
    by :func:`shape_box` is asked SAPIEN on every call."""

    def __init__(self, bodies):
        self.bodies = list(bodies)
        self._corners: list[np.ndarray | None] = []  # per body: its shapes' box corners in the body's frame
        for body in self.bodies:
            boxes = [shape_box(s) for s in body.render_shapes]
            if not boxes or any(b is None for b in boxes):
                self._corners.append(None)
                continue
            self._corners.append(np.concatenate([
                _moved(box_corners(lo, hi), s.local_pose) for s, (lo, hi) in zip(body.render_shapes, boxes)
            ]))

    def world(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)``, each ``(N, 3)``: the bodies' boxes at their current poses (world frame)."""
        lo, hi = np.empty((len(self.bodies), 3)), np.empty((len(self.bodies), 3))
        for i, (body, corners) in enumerate(zip(self.bodies, self._corners)):
            if corners is None:
                lo[i], hi[i] = np.asarray(body.get_global_aabb_fast(), dtype=np.float64)
                continue
            points = _moved(corners, body.entity_pose)
            lo[i], hi[i] = points.min(axis=0), points.max(axis=0)
        return lo, hi
