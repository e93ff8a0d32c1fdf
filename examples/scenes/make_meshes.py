"""Write the mesh files of the example scene ``mesh_parts.yaml`` into ``meshes/`` (next to this script).

Three small machined-looking parts, each watertight and non-convex (so the package decomposes each into convex
collision parts with CoACD), each within the gripper's limits (``maniskill_pnp.scenes.objects``: at least 2 cm high,
at most 7 cm across at the footprint's narrowest, no side over 12 cm):

* ``channel_bracket.stl``: a U channel (a base plate and two flanges) lying open side up, in **millimetres**, as CAD
  tools export STL (the scene loads it with ``scale: 0.001``): 60 x 40 mm footprint, 34 mm high;
* ``ring.obj``: a ring (torus) lying flat, in metres: 66 mm across, 24 mm high, an 18 mm hole;
* ``flanged_bushing.ply``: a bushing with a flange at its foot and a through bore, in metres: 60 mm flange, 32 mm
  body, 15 mm bore, 36 mm high.

Regenerate them with ``.venv/bin/python examples/scenes/make_meshes.py`` (``--out DIR`` to write elsewhere).
``tests/test_scene_file.py`` checks that this script reproduces the shipped files and that the scene loads.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
#: The mesh files the scene uses (described in the module docstring).
MESH_FILES = ("channel_bracket.stl", "ring.obj", "flanged_bushing.ply")


def _ear_clip(outline: np.ndarray) -> np.ndarray:
    """Triangles (index triples) of a simple counter-clockwise polygon, by ear clipping."""
    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    left, triangles = list(range(len(outline))), []
    while len(left) > 3:
        for k in range(len(left)):
            i, j, m = left[k - 1], left[k], left[(k + 1) % len(left)]
            a, b, c = outline[i], outline[j], outline[m]
            if cross(a, b, c) <= 0:  # reflex or flat corner: not an ear
                continue
            others = [outline[q] for q in left if q not in (i, j, m)]
            if any(cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0 for p in others):
                continue
            triangles.append((i, j, m))
            left.pop(k)
            break
        else:
            raise ValueError("outline is not a simple counter-clockwise polygon")
    triangles.append(tuple(left))
    return np.array(triangles)


def channel_bracket() -> trimesh.Trimesh:
    """U channel in millimetres: the profile (x across, z up) extruded 40 mm along y, centred on the origin."""
    width, height, wall, base, length = 60.0, 34.0, 7.0, 7.0, 40.0
    profile = np.array([[0, 0], [width, 0], [width, height], [width - wall, height], [width - wall, base],
                        [wall, base], [wall, height], [0, height]])
    mesh = trimesh.creation.extrude_triangulation(profile, _ear_clip(profile), length)
    # the extrusion runs along z: turn it (90 degrees about x) so the profile stands in x-z and the channel runs along y
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh


def ring() -> trimesh.Trimesh:
    """Torus lying flat (axis z) in metres: tube radius 12 mm around a 21 mm radius circle."""
    return trimesh.creation.torus(major_radius=0.021, minor_radius=0.012, major_sections=36, minor_sections=16)


def flanged_bushing() -> trimesh.Trimesh:
    """Bushing in metres: its half cross-section (radius, height) revolved about z, flange at the bottom."""
    bore, body, flange, foot, height = 0.0075, 0.016, 0.03, 0.008, 0.036
    section = np.array([[bore, 0], [flange, 0], [flange, foot], [body, foot], [body, height], [bore, height], [bore, 0]])
    return trimesh.creation.revolve(section, sections=40)


#: File name of each mesh -> the function that builds it.
BUILDERS = dict(zip(MESH_FILES, (channel_bracket, ring, flanged_bushing)))


def make_meshes(out: Path = HERE / "meshes") -> list[Path]:
    """Build every mesh and write it into ``out`` (created); returns the files written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, build in BUILDERS.items():
        mesh = build()
        if not mesh.is_watertight or mesh.volume <= 0:
            raise RuntimeError(f"{name}: the generated mesh is not a closed, outward-facing solid")
        mesh.export(out / name)
        written.append(out / name)
    return written


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=HERE / "meshes", help="folder to write into (default: %(default)s)")
    for path in make_meshes(parser.parse_args().out):
        print(f"{path} ({path.stat().st_size} bytes)")
