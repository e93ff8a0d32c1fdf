"""Scene files: the YAML / JSON layout format, its errors, export and replay of a scene, ``layout_file=`` on the clutter
tasks, the shipped locking layouts, and ``eval-clutter`` / ``record-clutter`` on scene files.

Heightmap agreement (export -> replay) is measured with a 1-pixel tolerance: a pixel of the original heightmap agrees
when some pixel of the replayed one within one pixel of it (3x3 neighbourhood) has its height to 5 mm; at most 0.5 %
of the pixels (20 of 64x64) may disagree (a thin edge of a tilted object can appear or vanish at a pixel boundary
when the replay's settle moves it by a fraction of a millimetre), and at most 1 % may differ by more than 5 mm
pixel for pixel. The replayed objects also rest within 2 mm of the exported positions.
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.scenes.clutter import as_pose, random_specs
from maniskill_pnp.scenes.complicated_layouts import (COMPLICATED_LAYOUT_NAMES, COMPLICATED_SCENES_DIR,
                                                     complicated_layout_files, complicated_layouts)
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.scenes.scene_file import (SceneFileError, euler_to_quat, load_scene, parse_scene, quat_to_euler_xyz,
                                            quat_to_matrix, read_scene, save_scene)
from maniskill_pnp.cell.workspace import WorkspaceSpec

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=4)
#: The 8 locking layouts as the Python definitions that preceded the shipped files gave them (names; per object the
#: kind, size values and pose [x y z qw qx qy qz] at WS's centre; NaN / "" pad to 7 objects): plain numbers computed
#: from the definitions' source, so the same on every machine.
REFERENCE = Path(__file__).parent / "data" / "complicated_layouts_definitions.npz"
#: How far a locking layout's object may settle from its designed pose in the env (m, degrees): the designs leave
#: GAP = 1 mm between neighbours, so an object that moved or turned a gap's width (1° turns a 9 cm bar's end by 0.8 mm)
#: would be another arrangement. Measured (2026-12-06, a 2-core x86-64 machine with AVX-512): < 0.001 mm and 0.03°.
SETTLE_TOL_M, SETTLE_TOL_DEG = 0.001, 1.0
#: The example scenes that ship in the repository (mesh_parts.yaml, its meshes and their generator).
EXAMPLE_SCENES = Path(__file__).parent.parent / "examples" / "scenes"

#: A valid scene: a cube and a bar in the workspace frame, the bar turned 90° about z.
VALID = dict(
    format=1, frame="workspace", name="two", objects=[
        dict(kind="cuboid", size=[0.02, 0.02, 0.02], color=[0.9, 0.1, 0.1], position=[-0.08, 0.0, 0.02],
             quaternion=[1.0, 0.0, 0.0, 0.0]),
        dict(kind="cuboid", size=[0.02, 0.045, 0.02], position=[0.08, 0.05, 0.02],
             euler=dict(convention="xyz", angles=[0, 0, 90], degrees=True)),
    ])


def _write(path: Path, data) -> Path:
    path.write_text(json.dumps(data) if path.suffix == ".json" else yaml.safe_dump(data, sort_keys=False))
    return path


def _same_rotation(q1, q2, tol=1e-9) -> bool:
    return min(np.abs(np.asarray(q1) - q2).max(), np.abs(np.asarray(q1) + q2).max()) < tol


def within_one_pixel(a: np.ndarray, b: np.ndarray, tol: float = 0.005) -> np.ndarray:
    """Per pixel of ``a``: whether some pixel of ``b`` within one pixel (3x3) has the same height to ``tol`` m."""
    pad = np.pad(b, 1, mode="edge")
    h, w = a.shape
    shifted = np.stack([pad[1 + i: h + 1 + i, 1 + j: w + 1 + j] for i in (-1, 0, 1) for j in (-1, 0, 1)])
    return np.abs(shifted - a).min(axis=0) <= tol


# ----------------------------------------------------------------------------- the format, no simulation
def test_quaternion_and_euler_forms_give_the_same_pose():
    yaw90 = [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]
    forms = [dict(quaternion=yaw90), dict(euler=dict(convention="xyz", angles=[0, 0, 90], degrees=True)),
             dict(euler=dict(convention="xyz", angles=[0.0, 0.0, np.pi / 2])),
             dict(euler=dict(convention="ZYX", angles=[90, 0, 0], degrees=True))]
    quats = []
    for form in forms:
        entry = dict(kind="cuboid", size=[0.02, 0.02, 0.02], position=[0.0, 0.0, 0.02], **form)
        (obj,) = parse_scene(dict(format=1, frame="workspace", objects=[entry])).objects
        quats.append(obj.quaternion)
    assert all(_same_rotation(q, yaw90) for q in quats), quats

    # "xyz" is extrinsic roll-pitch-yaw, R = Rz(yaw) Ry(pitch) Rx(roll); intrinsic "ZYX" takes the angles reversed
    roll, pitch, yaw = 0.3, -0.7, 2.1
    c, s = np.cos, np.sin
    rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    q = euler_to_quat([roll, pitch, yaw], "xyz")
    np.testing.assert_allclose(quat_to_matrix(q), rz @ ry @ rx, atol=1e-12)
    assert _same_rotation(euler_to_quat([yaw, pitch, roll], "ZYX"), q)
    np.testing.assert_allclose(quat_to_euler_xyz(q), [roll, pitch, yaw], atol=1e-12)
    rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    rng = np.random.default_rng(0)
    for convention in ("xyz", "zyx", "XYZ", "ZYX", "zxz", "YXY"):
        angles = rng.uniform(-3, 3, 3)
        x, y, z, w = rotation.from_euler(convention, angles).as_quat()
        assert _same_rotation(euler_to_quat(angles, convention), [w, x, y, z]), convention


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
@pytest.mark.parametrize("frame", ["workspace", "world"])
@pytest.mark.parametrize("orientation", ["quaternion", "euler"])
def test_save_and_load_round_trip(tmp_path, suffix, frame, orientation):
    """Specs exactly, poses to the written precision; a hull keeps its seed; tilted objects keep their rotation."""
    cx, cy = WS.center
    tilt = euler_to_quat([20, -35, 110], "xyz", degrees=True)
    layout = complicated_layouts(WS)[1] + [
        (ObjectSpec("hull", (0.05, 0.04, 0.03), (0.2, 0.6, 0.25), seed=7), (cx + 0.12, cy + 0.12, 0.05, *tilt)),
        (ObjectSpec("arch", (0.07, 0.03, 0.015, 0.04)), (cx - 0.12, cy - 0.12, 0.05, *euler_to_quat([0, 90, 0], "xyz", True)))]
    path = save_scene(tmp_path / f"scene{suffix}", layout, WS, frame=frame, name="mixed", orientation=orientation)
    scene = read_scene(path)
    assert scene.frame == frame and scene.name == "mixed"
    loaded = load_scene(path, WS)
    assert [s for s, _ in loaded] == [s for s, _ in layout]
    for (_, a), (_, b) in zip(loaded, layout):
        b = as_pose(b)
        assert np.abs(np.asarray(a.p) - b.p).max() < 1e-6
        assert _same_rotation(a.q, b.q, 1e-6)
    if suffix == ".yaml":
        text = path.read_text()
        assert text.startswith("# maniskill_pnp scene file") and ("euler: {convention: xyz" in text) == (orientation == "euler")


def test_workspace_frame_follows_the_workspace(tmp_path):
    path = _write(tmp_path / "two.yaml", VALID)
    moved = WorkspaceSpec(center=(0.0, 0.05), table_z=0.05, heightmap_size=64, pixel_size=0.448 / 64)  # in reach
    a, b = load_scene(path, WS), load_scene(path, moved)
    np.testing.assert_allclose(np.asarray(b[0][1].p) - a[0][1].p, [0.0 + 0.06, 0.05 + 0.1, 0.05], atol=1e-9)
    world = dict(VALID, frame="world")
    with pytest.raises(SceneFileError, match="not wholly over the workspace"):  # the same numbers as world coordinates
        load_scene(_write(tmp_path / "world.yaml", dict(world, objects=[dict(VALID["objects"][1], position=[0.3, 0.3, 0.02])])), WS)


def _mutate(change):
    data = json.loads(json.dumps(VALID))
    change(data)
    return data


def _obj(key, value=None, drop=False):
    def change(data):
        if drop:
            data["objects"][1].pop(key)
        else:
            data["objects"][1][key] = value
    return change


#: (change of VALID, message after "<file>: ").
BAD = [
    (_obj("kind", "blob"), r"objects\[1\]\.kind: unknown kind 'blob'; valid kinds"),
    (_obj("kind", "mesh"), r"objects\[1\]\.size: mesh objects take file and scale"),
    (_obj("file", "bar.obj"), r"objects\[1\]\.file: only mesh objects take file \(cuboid objects take size\)"),
    (_obj("kind", None, drop=True), r"objects\[1\]\.kind: missing"),
    (_obj("size", [0.02, 0.02]), r"objects\[1\]\.size: cuboid takes 3 values \['hx', 'hy', 'hz'\] \(metres\), got 2 values"),
    (_obj("size", [0.02, "a", 0.02]), r"objects\[1\]\.size: must be"),
    (_obj("size", [0.2, 0.2, 0.02]), r"objects\[1\] \(cuboid\): .*does not fit the gripper"),
    (_obj("position", None, drop=True), r"objects\[1\]\.position: missing"),
    (_obj("position", [0.0, 0.0]), r"objects\[1\]\.position: must be \[x, y, z\]"),
    (_obj("quaternion", [1, 0, 0, 0]), r"objects\[1\]: give exactly one orientation, 'quaternion' or 'euler' \(got both\)"),
    (_obj("euler", None, drop=True), r"objects\[1\]: give exactly one orientation.*\(got neither\)"),
    (_obj("euler", dict(convention="xyy", angles=[0, 0, 0])), r"objects\[1\]\.euler\.convention: unknown convention 'xyy'"),
    (_obj("euler", dict(angles=[0, 0, 0])), r"objects\[1\]\.euler\.convention: missing"),
    (_obj("euler", dict(convention="xyz", angles=[0, 0, 90], degrees="yes please")), r"objects\[1\]\.euler\.degrees"),
    (_obj("euler", dict(convention="xyz", angles=[0, 0, 0], order=1)), r"objects\[1\]\.euler: unknown key\(s\) \['order'\]"),
    (_obj("colour", [1, 0, 0]), r"objects\[1\]: unknown key\(s\) \['colour'\]; valid keys"),
    (_obj("color", [1.5, 0, 0]), r"objects\[1\]\.color: must be RGB in 0\.\.1"),
    (_obj("seed", -1), r"objects\[1\]\.seed: must be an int >= 0"),
    (lambda d: d["objects"][0].update(quaternion=[2, 0, 0, 0]), r"objects\[0\]\.quaternion: must be a unit quaternion"),
    (lambda d: d.update(format=2), r"format: unsupported version 2; this version reads format 1"),
    (lambda d: d.pop("format"), r"format: missing"),
    (lambda d: d.update(frame="table"), r"frame: unknown frame 'table'; valid frames"),
    (lambda d: d.update(scale=2), r"unknown key\(s\) \['scale'\]"),
    (lambda d: d.update(objects=[]), r"objects: must be a non-empty list"),
    (lambda d: d["objects"][1].update(position=[-0.07, 0.0, 0.02]),
     r"objects\[0\] \(cuboid\) and objects\[1\] \(cuboid\) overlap: their shapes interpenetrate by 40\.0 mm"),
    (lambda d: d["objects"][1].update(position=[0.3, 0.0, 0.02]), r"objects\[1\] \(cuboid\) reaches x .*not wholly over the workspace"),
]


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
@pytest.mark.parametrize("change, message", BAD)
def test_errors_name_the_file_the_object_and_the_field(tmp_path, suffix, change, message):
    path = _write(tmp_path / f"bad_scene{suffix}", _mutate(change))
    with pytest.raises(SceneFileError, match=rf"bad_scene\{suffix}: {message}"):
        load_scene(path, WS)


def test_file_level_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.yaml"):
        read_scene(tmp_path / "nowhere.yaml")
    with pytest.raises(SceneFileError, match=r"scene.txt: a scene file ends in \.yaml, \.yml, \.json"):
        read_scene(_write(tmp_path / "scene.txt", VALID))
    (tmp_path / "broken.yaml").write_text("format: 1\nobjects: [\n")
    with pytest.raises(SceneFileError, match="broken.yaml: not valid YAML"):
        read_scene(tmp_path / "broken.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(SceneFileError, match="list.yaml: a scene file holds a mapping"):
        read_scene(tmp_path / "list.yaml")
    # YAML exponents without a dot are numbers
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(VALID, sort_keys=False).replace("0.02, 0.02, 0.02]", "2e-2, 2.0e-2, 20E-3]", 1))
    assert read_scene(tmp_path / "exp.yaml").objects[0].spec.size == (0.02, 0.02, 0.02)
    with pytest.raises(ValueError, match="overlap"):  # save_scene refuses a layout that would not load
        save_scene(tmp_path / "x.yaml", [(ObjectSpec("cuboid", (0.02, 0.02, 0.02)), (*WS.center, 0.02))] * 2, WS)
    assert not (tmp_path / "x.yaml").exists()


def test_the_documented_example_loads():
    import maniskill_pnp.scenes.scene_file as module

    block = module.__doc__.split("schema::")[1].split("Frames.")[0]
    data = yaml.safe_load("\n".join(line[4:] for line in block.splitlines()))
    layout = parse_scene(data, "docstring").layout(WorkspaceSpec())
    assert [spec.kind for spec, _ in layout] == ["cuboid", "hull"] and layout[1][0].seed == 7


def test_layouts_are_checked_by_their_shapes_and_settled_is_ignored(tmp_path):
    """Objects whose bounding boxes cross but whose shapes do not (a cylinder in an arch's tunnel) load; files of
    earlier versions marked ``settled: true`` load as any other (the key is ignored: shapes are checked)."""
    arch = dict(kind="arch", size=[0.09, 0.035, 0.015, 0.045], position=[0.0, 0.0, 0.0225], quaternion=[1, 0, 0, 0])
    inside = dict(kind="cylinder", size=[0.012, 0.01], position=[0.0, 0.0, 0.01], quaternion=[1, 0, 0, 0])
    tunnel = dict(format=1, frame="workspace", objects=[arch, inside])
    assert [s.kind for s, _ in load_scene(_write(tmp_path / "tunnel.yaml", tunnel), WS)] == ["arch", "cylinder"]
    assert len(load_scene(_write(tmp_path / "old.yaml", dict(VALID, settled=True)), WS)) == 2
    leaning = _mutate(lambda d: d.update(settled=True) or d["objects"][1].update(position=[-0.05, 0.0, 0.03]))
    with pytest.raises(SceneFileError, match=r"leaning.yaml: objects\[0\] \(cuboid\) and objects\[1\] \(cuboid\) overlap: "
                                             r"their shapes interpenetrate by \d+\.\d mm"):
        load_scene(_write(tmp_path / "leaning.yaml", leaning), WS)
    # a bar resting on two cubes (a bridge) loads after a short settle; half of it over one cube does not
    cube = dict(kind="cuboid", size=[0.015, 0.015, 0.015], quaternion=[1, 0, 0, 0])
    bar = dict(kind="cuboid", size=[0.05, 0.012, 0.01], quaternion=[1, 0, 0, 0])
    bridge = dict(format=1, frame="workspace", objects=[dict(cube, position=[-0.035, 0, 0.015]),
                                                        dict(cube, position=[0.035, 0, 0.015]), dict(bar, position=[0, 0, 0.04])])
    assert len(load_scene(_write(tmp_path / "bridge.yaml", bridge), WS)) == 3
    bridge["objects"] = bridge["objects"][:1] + [dict(bar, position=[0.03, 0, 0.04])]
    with pytest.raises(SceneFileError, match=r"overhang.yaml: objects\[1\] \(cuboid\) does not rest where it is placed: "
                                             r"it moves \d+\.\d mm in a 0\.30 s physics settle .* objects\[0\] \(cuboid\) "):
        load_scene(_write(tmp_path / "overhang.yaml", bridge), WS)


def _u_layout(u_mesh, **fields):
    """The U mesh with a small cube in its gap (their bounding boxes cross), at the workspace centre."""
    u = ObjectSpec("mesh", file=u_mesh, color=(0.2, 0.6, 0.25), **fields)
    cx, cy = WS.center
    return [(u, (cx, cy, 0.015, 1.0, 0.0, 0.0, 0.0)), (ObjectSpec("cuboid", (0.01, 0.01, 0.01)), (cx, cy + 0.006, 0.01))]


def test_mesh_objects_round_trip(tmp_path, u_mesh):
    """Mesh paths relative to the scene file's folder when the mesh is in it, absolute otherwise; every mesh field kept."""
    folder = tmp_path / "scenes"
    (folder / "parts").mkdir(parents=True)
    local = folder / "parts" / "u.obj"
    local.write_bytes(u_mesh.read_bytes())
    for mesh, fields, written in [(local, {}, "parts/u.obj"), (u_mesh, dict(scale=(1.0, 1.25, 1.0), texture=True,
                                                                          density=250.0), str(u_mesh.resolve()))]:
        layout = _u_layout(mesh, **fields)
        for suffix in (".yaml", ".json"):
            path = save_scene(folder / f"mesh{suffix}", layout, WS)
            data = yaml.safe_load(path.read_text())
            assert data["objects"][0]["file"] == written and "size" not in data["objects"][0]
            loaded = load_scene(path, WS)
            assert [s for s, _ in loaded] == [s for s, _ in layout]
            assert np.abs(np.asarray(loaded[0][1].p) - as_pose(layout[0][1]).p).max() < 1e-6
    data["objects"][0].update(collision="parts/u.obj", scale=[1, 1, 1])
    scene = read_scene(_write(folder / "with_parts.json", data))
    assert scene.objects[0].spec.collision == str(local.resolve()) and scene.objects[0].spec.scale == (1.0, 1.0, 1.0)


def test_mesh_entry_errors(tmp_path, u_mesh):
    base = dict(kind="mesh", file=str(u_mesh), position=[0, 0, 0.015], quaternion=[1, 0, 0, 0])
    cases = [
        (dict(file=3), r"objects\[0\]\.file: must be a path"),
        (dict(file="nowhere.obj"), r"objects\[0\]\.file: mesh file .*nowhere\.obj does not exist"),
        (dict(collision="nowhere.ply"), r"objects\[0\]\.collision: mesh file .*nowhere\.ply does not exist"),
        (dict(scale=[1, 1]), r"objects\[0\]\.scale: must be one factor or \[sx, sy, sz\]"),
        (dict(scale=0), r"objects\[0\]\.scale: must be positive"),
        (dict(texture="yes"), r"objects\[0\]\.texture: must be true or false"),
        (dict(density=-1), r"objects\[0\]\.density: must be a positive number"),
        (dict(seed=3), r"objects\[0\]\.seed: mesh objects take file and scale"),
        (dict(scale=3), r"objects\[0\] \(mesh\): mesh .*u_shape\.obj \(scale \[3\.0, 3\.0, 3\.0\]\) does not fit the gripper"),
    ]
    for change, match in cases:
        entry = {k: v for k, v in dict(base, **change).items() if v is not None}
        with pytest.raises(SceneFileError, match=rf"bad_mesh\.yaml: {match}"):
            read_scene(_write(tmp_path / "bad_mesh.yaml", dict(format=1, frame="workspace", objects=[entry])))
    entry = {k: v for k, v in base.items() if k != "file"}
    with pytest.raises(SceneFileError, match=r"objects\[0\]\.file: missing"):
        read_scene(_write(tmp_path / "bad_mesh.yaml", dict(format=1, frame="workspace", objects=[entry])))


def _assert_definition(k: int, layout, reference, pos_tol: float, angle_tol_deg: float) -> None:
    """``layout`` (a list of ``(ObjectSpec, pose)``) is locking layout ``k`` of ``reference``: the same kinds and sizes
    in the same order, each position within ``pos_tol`` m and each orientation within ``angle_tol_deg``."""
    name = COMPLICATED_LAYOUT_NAMES[k]
    n = int(np.count_nonzero(reference["kinds"][k]))
    assert [s.kind for s, _ in layout] == list(reference["kinds"][k][:n]), name
    for i, (spec, pose) in enumerate(layout):
        want_size = reference["sizes"][k, i]
        assert np.array_equal(np.asarray(spec.size, dtype=float), want_size[~np.isnan(want_size)]), (name, i)
        want = reference["poses"][k, i]
        assert np.abs(np.asarray(pose.p) - want[:3]).max() <= pos_tol, (name, i)
        # normalized (a file's quaternion is rounded to its decimals) and by atan2, which resolves small angles that
        # planning.kinematics.quat_angle's arccos of the dot product cannot
        q, w = (np.asarray(v, dtype=float) / np.linalg.norm(v) for v in (pose.q, want[3:]))
        w = w if np.dot(q, w) >= 0 else -w
        turn = np.degrees(4 * np.arctan2(np.linalg.norm(q - w), np.linalg.norm(q + w)))  # the angle between the two
        assert turn <= angle_tol_deg, (name, i, turn)


def test_shipped_locking_layout_files():
    files = complicated_layout_files()
    assert [p.stem for p in files] == list(COMPLICATED_LAYOUT_NAMES) and len(files) == 8
    assert sorted(p.name for p in COMPLICATED_SCENES_DIR.iterdir()) == sorted(p.name for p in files)
    reference = np.load(REFERENCE)
    assert list(reference["names"]) == list(COMPLICATED_LAYOUT_NAMES)
    for k, (path, layout) in enumerate(zip(files, complicated_layouts(WS))):
        scene = read_scene(path)
        assert scene.frame == "workspace" and scene.name == COMPLICATED_LAYOUT_NAMES[k]
        _assert_definition(k, layout, reference, pos_tol=1e-6, angle_tol_deg=1e-4)  # YAML's decimals, nothing more


def test_shipped_mesh_example_scene(tmp_path):
    """``examples/scenes/mesh_parts.yaml`` loads and validates, its meshes are small and ``make_meshes.py`` still makes
    them: regenerated into ``tmp_path``, each has the shipped file's vertices (to 1e-6 of its size), faces and volume."""
    import importlib.util

    import trimesh
    from scipy.spatial import cKDTree

    from maniskill_pnp.scenes.layout_check import check_layout

    spec = importlib.util.spec_from_file_location("example_make_meshes", EXAMPLE_SCENES / "make_meshes.py")
    make_meshes = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_meshes)
    shipped_dir = EXAMPLE_SCENES / "meshes"
    assert sorted(p.name for p in shipped_dir.iterdir()) == sorted(make_meshes.MESH_FILES)
    for new in make_meshes.make_meshes(tmp_path / "meshes"):
        shipped = shipped_dir / new.name
        assert shipped.stat().st_size < 100_000, shipped.name
        a, b = (trimesh.load(str(p), force="mesh") for p in (shipped, new))
        tol = 1e-6 * float(np.max(a.extents))
        assert len(a.vertices) == len(b.vertices) and len(a.faces) == len(b.faces), new.name
        assert cKDTree(a.vertices).query(b.vertices)[0].max() <= tol, new.name
        assert cKDTree(b.vertices).query(a.vertices)[0].max() <= tol, new.name
        assert a.is_watertight and abs(a.volume - b.volume) <= 1e-6 * a.volume, new.name

    scene = read_scene(EXAMPLE_SCENES / "mesh_parts.yaml")
    assert scene.name == "mesh_parts" and scene.description and scene.frame == "workspace"
    ws = WorkspaceSpec()
    layout = load_scene(EXAMPLE_SCENES / "mesh_parts.yaml", ws)  # every object fits the gripper; the layout validates
    assert [s.label for s, _ in layout] == ["mesh channel_bracket.stl", "cuboid", "mesh ring.obj", "cylinder", "arch",
                                            "cylinder", "mesh flanged_bushing.ply"]
    assert all(Path(s.file).parent == shipped_dir.resolve() for s, _ in layout if s.kind == "mesh")
    assert layout[0][0].scale == (0.001,) * 3 and np.allclose(layout[0][0].extents, [0.06, 0.04, 0.034])
    check = check_layout(layout, ws)
    assert [(i, j) for i, j, _ in check.contacts] == [(0, 1)]  # the block rests on the channel's base plate
    assert np.nanmax(check.displacement) < 1e-3


# ----------------------------------------------------------------------------- envs
@pytest.fixture(scope="module")
def exported(tmp_path_factory, u_mesh):
    """A clutter of 4 objects (3 random procedural ones and the U mesh) dropped at random orientations (they may tilt
    and pile up) after its settle: its scene file and its depth heightmap."""
    objects = random_specs(np.random.default_rng(5), 3) + [ObjectSpec("mesh", file=u_mesh, color=(0.2, 0.6, 0.25))]
    env = gym.make("ClutterGrasp-v1", workspace=WS, num_objects=4, loosely_packed=False, objects=objects, **CPU)
    try:
        obs, info = env.reset(seed=3)
        assert int(info["num_objects"]) == 4
        path = env.unwrapped.export_scene(tmp_path_factory.mktemp("scenes") / "random_four.yaml", name="random_four")
        assert len(read_scene(path).objects) == int(info["objects_remaining"])
        with pytest.raises(ValueError, match="env index must be in 0..0"):
            env.unwrapped.export_scene(path.with_name("other.yaml"), env_idx=1)
        with pytest.raises(SceneFileError, match="ends in"):
            env.unwrapped.export_scene(path.with_name("other.txt"))
        return path, obs["depth_heightmap"][0].cpu().numpy()
    finally:
        env.close()


@pytest.fixture(scope="module")
def files_env(exported):
    """ClutterGrasp-v1 on two scene files: the exported random clutter and the shipped row_of_three."""
    rows = complicated_layout_files()[COMPLICATED_LAYOUT_NAMES.index("row_of_three")]
    env = gym.make("ClutterGrasp-v1", workspace=WS, layout_file=[exported[0], rows], **CPU)
    yield env
    env.close()


def test_exported_scene_replays_with_the_same_heightmap(exported, files_env):
    path, depth = exported
    scene = read_scene(path)
    assert scene.name == "random_four" and scene.frame == "workspace"
    assert "mesh" in [o.spec.kind for o in scene.objects]  # the U is among the replayed objects
    obs, info = files_env.reset(seed=0, options={"layout_index": 0})
    replayed = obs["depth_heightmap"][0].cpu().numpy()
    assert int(info["layout_index"]) == 0 and int(info["lost_objects"]) == 0
    assert int(info["objects_remaining"]) == len(scene.objects)
    assert depth.max() > 0.01  # the objects are seen
    assert np.count_nonzero(~within_one_pixel(depth, replayed)) <= 0.005 * depth.size
    assert np.count_nonzero(np.abs(depth - replayed) > 0.005) <= 0.01 * depth.size
    rest = np.stack([a.pose.p[0].cpu().numpy() for a in files_env.unwrapped.clutter.active_actors[0]])
    want = np.array([pose.p for _, pose in scene.layout(WS)])
    assert np.abs(rest - want).max() < 0.002


def test_several_layout_files_and_layout_index(exported, files_env):
    u = files_env.unwrapped
    assert u.layout_files == (exported[0], complicated_layout_files()[0]) and len(u.layouts) == 2
    obs, info = files_env.reset(seed=0, options={"layout_index": 1})
    assert int(info["layout_index"]) == 1 and int(info["num_objects"]) == 3  # the three bars
    rows = read_scene(complicated_layout_files()[COMPLICATED_LAYOUT_NAMES.index("row_of_three")]).layout(WS)
    rest = files_env.unwrapped.clutter.workspace_layout(0)  # the file's bars, where it puts them
    assert [s for s, _ in rest] == [s for s, _ in rows]
    assert max(np.abs(np.asarray(a.p) - b.p).max() for (_, a), (_, b) in zip(rest, rows)) <= SETTLE_TOL_M
    drawn = {int(files_env.reset(seed=s)[1]["layout_index"]) for s in range(8)}
    assert drawn == {0, 1}  # a seeded draw among the files
    with pytest.raises(ValueError, match="layout_index"):
        files_env.reset(seed=0, options={"layout_index": 2})


def test_locking_layouts_unchanged_since_the_python_definitions():
    """layout="complicated" (now read from the shipped files) builds the objects of the former Python definitions, and
    they rest where those put them (within :data:`SETTLE_TOL_M` / :data:`SETTLE_TOL_DEG`: a machine-independent
    claim, where rendered heights differ between CPUs by up to a millimetre at object edges)."""
    reference = np.load(REFERENCE)
    env = gym.make("ClutterGraspSlide-v1", workspace=WS, layout="complicated", **CPU)
    try:
        for k in range(len(COMPLICATED_LAYOUT_NAMES)):
            obs, info = env.reset(seed=0, options={"layout_index": k})
            assert int(info["layout_index"]) == k and int(info["lost_objects"]) == 0
            _assert_definition(k, env.unwrapped.clutter.workspace_layout(0), reference, SETTLE_TOL_M, SETTLE_TOL_DEG)
            assert obs["depth_heightmap"][0].max() > 0.01  # and the camera sees them
    finally:
        env.close()


@pytest.mark.parametrize(
    "env_id, kwargs, error, match",
    [
        ("ClutterGrasp-v1", dict(layout="X"), ValueError, "mutually exclusive"),
        ("ClutterGraspSlide-v1", dict(layout="complicated"), ValueError, "mutually exclusive"),
        ("ClutterGraspSlide-v1", dict(complicated_index=0), ValueError, "no other layout"),
        ("ClutterGraspSlide-v1", dict(num_objects="complicated"), ValueError, "no other layout"),
        ("ClutterGrasp-v1", dict(layout_file=[]), ValueError, "non-empty list"),
        ("ClutterGrasp-v1", dict(layout_file=3), ValueError, "non-empty list"),
        ("ClutterGrasp-v1", dict(layout_file="nowhere.yaml"), FileNotFoundError, "nowhere.yaml"),
    ],
)
def test_bad_layout_file_options(env_id, kwargs, error, match):
    kwargs.setdefault("layout_file", complicated_layout_files()[0])
    with pytest.raises(error, match=match):
        gym.make(env_id, workspace=WS, **kwargs, **CPU)


def test_a_scene_that_does_not_fit_the_workspace_names_the_file(tmp_path):
    small = WorkspaceSpec(heightmap_size=16, pixel_size=0.001, num_rotations=4, spawn_margin=0.001)  # a 1.6 cm square
    path = complicated_layout_files()[0]
    with pytest.raises(SceneFileError, match=r"row_of_three.yaml: objects\[0\] \(cuboid\) reaches x .* not wholly over the workspace"):
        gym.make("ClutterGrasp-v1", workspace=small, layout_file=path, **CPU)


# ----------------------------------------------------------------------------- evaluation and video
def _two_cubes(path: Path) -> Path:
    return _write(path, VALID)


def test_eval_config_layout_files(tmp_path):
    from maniskill_pnp.agents.pixel.evaluate import ClutterEvalConfig

    scene = _two_cubes(tmp_path / "two.yaml")
    assert ClutterEvalConfig(checkpoint=tmp_path).scenarios == ("train",)
    cfg = ClutterEvalConfig(checkpoint=tmp_path, layout_file=(scene,))
    assert cfg.scenarios == () and cfg.layout_scenario == "two" and cfg.to_json()["layout_file"] == [str(scene)]
    both = ClutterEvalConfig(checkpoint=tmp_path, scenarios=("min",), layout_file=(scene, COMPLICATED_SCENES_DIR / "sandwich.yaml"))
    assert both.layout_scenario == "two+sandwich"
    with pytest.raises(ValueError, match="episodes"):
        ClutterEvalConfig(checkpoint=tmp_path, episodes=1, layout_file=(scene, scene))
    with pytest.raises(FileNotFoundError, match="nowhere.yaml"):
        ClutterEvalConfig(checkpoint=tmp_path, layout_file=(tmp_path / "nowhere.yaml",))
    with pytest.raises(SceneFileError, match=r"bad.yaml: objects\[1\]\.kind"):
        ClutterEvalConfig(checkpoint=tmp_path, layout_file=(_write(tmp_path / "bad.yaml", _mutate(_obj("kind", "blob"))),))
    with pytest.raises(ValueError, match="name of a scenario"):
        ClutterEvalConfig(checkpoint=tmp_path, scenarios=("min",), layout_file=(_two_cubes(tmp_path / "min.yaml"),))


def test_eval_clutter_layout_file_writes_its_row(tiny_clutter_run, tmp_path):
    from maniskill_pnp.agents.pixel.evaluate import EPISODE_COLUMNS, METRICS
    from maniskill_pnp.cli import main as cli

    scene = _two_cubes(tmp_path / "two_cubes.yaml")
    out = tmp_path / "eval"
    cli(["eval-clutter", str(tiny_clutter_run), "--layout-file", str(scene), "--episodes", "1", "--max-steps", "1",
         "--out", str(out)])
    summary = json.loads((out / "eval_summary.json").read_text())
    assert list(summary["metrics"]) == ["two_cubes"] and set(METRICS) <= set(summary["metrics"]["two_cubes"])
    (episode,) = summary["episodes"]
    assert episode["scenario"] == "two_cubes" and episode["layout"] == "two_cubes" and episode["objects"] == 2
    rows = (out / "eval_table.md").read_text().splitlines()
    assert len(rows) == 3 and rows[2].startswith("| two_cubes | 1 |")
    lines = (out / "eval_episodes.csv").read_text().splitlines()
    assert lines[0] == ",".join(EPISODE_COLUMNS) and lines[1].startswith("two_cubes,1000,2,") and lines[1].endswith(",two_cubes")


def test_record_clutter_layout_file(tiny_clutter_run, tmp_path):
    from maniskill_pnp.agents.pixel.video import ClutterVideoConfig, run as record

    scene = _two_cubes(tmp_path / "two_cubes.json")
    with pytest.raises(ValueError, match="not both"):
        ClutterVideoConfig(checkpoint=tiny_clutter_run, scenario="min", layout_file=scene)
    summary = record(ClutterVideoConfig(checkpoint=tiny_clutter_run, layout_file=scene, max_steps=1, frame_every=20,
                                        out=tmp_path / "video"))
    assert summary["scenario"] == "two_cubes" and summary["objects"] == 2 and len(summary["decisions"]) == 1
    assert (tmp_path / "video" / "episode.mp4").stat().st_size > 0
