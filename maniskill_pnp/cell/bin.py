"""The bin that placed objects go into: an open box of five static plates beside the workspace."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien

from maniskill_pnp.planning.primitives import PlaceRegion


@dataclass(frozen=True)
class BinSpec:
    """Geometry of the place bin (world frame, metres).

    Attributes:
        center: Centre of the bin's floor on the table (x, y, z).
        inner_half_size: Half extents (x, y) of the inside of the bin.
        wall_height: Height of the walls above the table.
        wall_thickness: Thickness of the walls and floor.
        color: RGBA colour.
    """

    center: tuple[float, float, float] = (0.0, 0.32, 0.0)
    inner_half_size: tuple[float, float] = (0.09, 0.09)
    wall_height: float = 0.06
    wall_thickness: float = 0.01
    color: tuple[float, float, float, float] = (0.35, 0.35, 0.4, 1.0)

    def region(self) -> PlaceRegion:
        """The region where a placed object must come to rest: the bin's inside and, once objects pile up in it, the
        pile above its footprint up to 5 cm over the release height (an object resting on the pile is in the bin)."""
        hx, hy = self.inner_half_size
        drop = self.wall_height + 0.12
        return PlaceRegion(center=self.center, half_size=(hx, hy, (drop + 0.05) / 2), drop_height=drop)


def build_bin(scene, spec: BinSpec, name: str = "bin"):
    """Build the bin as one static actor (floor plate and four walls) in a ManiSkill scene."""
    hx, hy = spec.inner_half_size
    t, h = spec.wall_thickness, spec.wall_height
    material = sapien.render.RenderMaterial(base_color=list(spec.color))
    plates = [
        ((0.0, 0.0, t / 2), (hx + t, hy + t, t / 2)),  # floor
        ((hx + t / 2, 0.0, h / 2), (t / 2, hy + t, h / 2)),
        ((-hx - t / 2, 0.0, h / 2), (t / 2, hy + t, h / 2)),
        ((0.0, hy + t / 2, h / 2), (hx, t / 2, h / 2)),
        ((0.0, -hy - t / 2, h / 2), (hx, t / 2, h / 2)),
    ]
    builder = scene.create_actor_builder()
    for center, half in plates:
        pose = sapien.Pose(p=np.asarray(center, dtype=np.float64))
        builder.add_box_collision(pose=pose, half_size=half)
        builder.add_box_visual(pose=pose, half_size=half, material=material)
    builder.initial_pose = sapien.Pose(p=np.asarray(spec.center, dtype=np.float64))
    return builder.build_static(name=name)
