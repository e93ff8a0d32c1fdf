"""Shape-exact layout validation (:mod:`maniskill_pnp.scenes.layout_check`): collision shapes instead of bounding boxes
for overlaps, the workspace and the table; touching objects checked by a short physics settle. No env is made."""

from __future__ import annotations

import numpy as np
import pytest
import sapien

from maniskill_pnp.scenes.clutter import _obb, _obb_overlap, validate_layout
from maniskill_pnp.scenes.layout_check import check_layout
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.cell.workspace import WorkspaceSpec

WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=4)
CX, CY = WS.center
CUBE = ObjectSpec("cuboid", (0.02, 0.02, 0.02))


def _yaw(deg: float) -> list[float]:
    a = np.radians(deg) / 2
    return [np.cos(a), 0.0, 0.0, np.sin(a)]


def _boxes_overlap(layout) -> bool:
    """What the former bounding-box check said."""
    (a, pa), (b, pb) = [(s, sapien.Pose(p=p[:3], q=p[3:]) if len(p) == 7 else sapien.Pose(p=p)) for s, p in layout]
    return _obb_overlap(_obb(a, pa), _obb(b, pb))


def test_a_cylinder_in_an_arch_tunnel_is_valid():
    arch = ObjectSpec("arch", (0.09, 0.035, 0.015, 0.045))  # a 6 cm wide, 2.5 cm high tunnel
    cylinder = ObjectSpec("cylinder", (0.012, 0.01))
    layout = [(arch, (CX, CY, 0.0225)), (cylinder, (CX + 0.01, CY, 0.01))]
    assert _boxes_overlap(layout)  # rejected by bounding boxes
    report = check_layout([(s, sapien.Pose(p=p)) for s, p in layout], WS)
    assert report.contacts == [] and report.settled == ()  # apart: no settle needed
    assert len(validate_layout(layout, WS)) == 2


def test_two_overlapping_boxes_name_both_and_the_depth():
    with pytest.raises(ValueError, match=r"layout objects 0 \(cuboid\) and 1 \(cuboid\) overlap: their shapes interpenetrate "
                                         r"by 10\.0 mm \(at most 1\.0 mm allowed\)"):
        validate_layout([(CUBE, (CX, CY, 0.02)), (CUBE, (CX + 0.03, CY, 0.02))], WS)
    bar = ObjectSpec("cuboid", (0.01, 0.045, 0.02))
    with pytest.raises(ValueError, match=r"layout objects 1 \(cuboid\) and 2 \(cuboid\) overlap: .* by 5\.0 mm"):
        validate_layout([(CUBE, (CX - 0.1, CY, 0.02)), (CUBE, (CX, CY, 0.02)), (bar, (CX + 0.025, CY, 0.02, *_yaw(0)))], WS)


def test_touching_and_slightly_penetrating_objects_are_settled():
    """Within 1 mm of penetration two cubes are touching: the settle runs, moves them little, and is reported."""
    report = check_layout([(CUBE, sapien.Pose([CX, CY, 0.02])), (CUBE, sapien.Pose([CX + 0.0395, CY, 0.02]))], WS)
    ((i, j, d),) = report.contacts
    assert (i, j) == (0, 1) and d == pytest.approx(-0.0005, abs=1e-6)
    assert report.settled == (0, 1) and report.displacement.shape == (2,) and report.displacement.max() < 0.002


def test_a_stack_is_valid_and_an_overhang_is_not():
    stack = [(CUBE, sapien.Pose([CX, CY, 0.02])), (CUBE, sapien.Pose([CX + 0.005, CY, 0.06], _yaw(20)))]
    report = check_layout(stack, WS)
    assert report.settled == (0, 1) and report.displacement.max() < 0.001
    with pytest.raises(ValueError, match=r"layout object 1 \(cuboid\) does not rest where it is placed: it moves \d+\.\d mm "
                                         r"in a 0\.30 s physics settle \(at most 3\.0 mm allowed\); the touching objects moved: "
                                         r"object 0 \(cuboid\) \d+\.\d mm, object 1 \(cuboid\) \d+\.\d mm"):
        check_layout([(CUBE, sapien.Pose([CX, CY, 0.02])), (CUBE, sapien.Pose([CX + 0.035, CY, 0.06]))], WS)
    # objects that touch nothing are not settled, whatever their pose: above the table they are dropped
    prism = ObjectSpec("wedge", (0.05, 0.03, 0.04))
    assert check_layout([(prism, sapien.Pose([CX, CY, 0.1], [0.9, 0.3, 0.2, 0.1]))], WS).settled == ()


def test_a_cylinder_lying_in_a_cradle_is_valid():
    """A lying cylinder (r = 1.5 cm) resting on the inner top edges of two bars 2 cm apart, off the table."""
    cylinder = ObjectSpec("cylinder", (0.015, 0.025))
    bar = ObjectSpec("cuboid", (0.03, 0.01, 0.01))
    z = 0.02 + np.sqrt(0.015 ** 2 - 0.01 ** 2)  # the axis above the edges (y = +-1 cm, z = 2 cm) by the radius
    lying = sapien.Pose([CX, CY, z], [np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])
    layout = [(bar, sapien.Pose([CX, CY - 0.02, 0.01])), (bar, sapien.Pose([CX, CY + 0.02, 0.01])), (cylinder, lying)]
    report = check_layout(layout, WS)
    assert sorted((i, j) for i, j, _ in report.contacts) == [(0, 2), (1, 2)] and report.settled == (0, 1, 2)
    assert report.displacement.max() < 0.002


def test_workspace_and_table_by_shape():
    """An object starts a scene wholly over the heightmap (its shapes, within 1 mm of the edge), where the arm reaches
    some grasp, and not below the table."""
    cylinder = ObjectSpec("cylinder", (0.02, 0.015))
    x_max, y_min = WS.bounds[0, 1], WS.bounds[1, 0]
    assert len(validate_layout([(cylinder, (x_max - 0.0205, CY, 0.015))], WS)) == 1  # 0.5 mm inside the edge
    with pytest.raises(ValueError, match=r"layout object 0 \(cylinder\) reaches x 0\.\d+\.\.0\.\d+, y .*: not wholly over "
                                         r"the workspace"):
        validate_layout([(cylinder, (x_max - 0.005, CY, 0.015))], WS)  # its centre over the square, its side over the edge
    small = ObjectSpec("cuboid", (0.01, 0.01, 0.01))
    with pytest.raises(ValueError, match=r"layout object 0 \(cuboid\) has its centre at x 0\.\d+, y -0\.\d+, where the "
                                         r"arm reaches no top-down grasp"):
        validate_layout([(small, (x_max - 0.012, y_min + 0.012, 0.01))], WS)  # the far corner, beyond the Panda's reach
    sphere = ObjectSpec("sphere", (0.02,))
    with pytest.raises(ValueError, match=r"layout object 0 \(sphere\) reaches z -0\.0030, below the table at 0\.0 "
                                         r"\(by 3\.0 mm; 1\.0 mm allowed\)"):
        validate_layout([(sphere, (CX, CY, 0.017))], WS)
    assert len(validate_layout([(sphere, (CX, CY, 0.0195))], WS)) == 1  # 0.5 mm into the table: a resting contact
    tilted = sapien.Pose([CX, CY, 0.02 * np.sqrt(2) - 0.0015], [np.cos(np.pi / 8), np.sin(np.pi / 8), 0, 0])  # on an edge
    with pytest.raises(ValueError, match="below the table"):
        validate_layout([(CUBE, tilted)], WS)


def test_a_mesh_object_is_checked_by_its_parts(u_mesh):
    """A cube in the U's gap is valid (their boxes cross); a cube across an arm is not."""
    u = ObjectSpec("mesh", file=u_mesh)
    small = ObjectSpec("cuboid", (0.01, 0.01, 0.01))
    layout = [(u, (CX, CY, 0.015)), (small, (CX, CY + 0.006, 0.01))]
    assert _boxes_overlap(layout) and len(validate_layout(layout, WS)) == 2
    with pytest.raises(ValueError, match=r"layout objects 0 \(mesh u_shape\.obj\) and 1 \(cuboid\) overlap"):
        validate_layout([(u, (CX, CY, 0.015)), (small, (CX + 0.02, CY + 0.006, 0.01))], WS)
