"""Mesh objects (``kind="mesh"``): loading, convex parts and their cache, mass, the errors that name the file, a grasp
by the scripted oracle, and ManiSkill's YCB models as an object source (a fake asset folder; nothing is downloaded)."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import sapien
import trimesh

import maniskill_pnp  # noqa: F401  (registers the tasks)
from maniskill_pnp.scenes import meshes
from maniskill_pnp.tasks.clutter_grasp import resolve_objects
from maniskill_pnp.agents.scripted.clutter_oracle import HeightmapGraspOracle
from maniskill_pnp.scenes.objects import ObjectSpec, add_collisions
from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.ycb import DOWNLOAD_COMMAND, ycb_dir, ycb_model_ids, ycb_spec, ycb_specs

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")
WS = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=4)
INFO = "info_pick_v0.json"


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty cache folder (MANISKILL_PNP_CACHE) for this test."""
    monkeypatch.setenv("MANISKILL_PNP_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _count_coacd(monkeypatch) -> list:
    """Record every CoACD run (then run it)."""
    calls = []
    run = meshes._coacd_parts

    def counted(info):
        calls.append(info.path)
        return run(info)

    monkeypatch.setattr(meshes, "_coacd_parts", counted)
    return calls


def test_non_convex_mesh_is_decomposed_once_and_cached(u_mesh, fresh_cache, monkeypatch):
    calls = _count_coacd(monkeypatch)
    spec = ObjectSpec("mesh", file=str(u_mesh), color=(0.2, 0.6, 0.25))
    assert spec.file == str(u_mesh.resolve()) and spec.scale == (1.0, 1.0, 1.0) and spec.label == "mesh u_shape.obj"
    np.testing.assert_allclose(spec.extents, [0.05, 0.04, 0.03], atol=1e-9)
    assert spec.grasp_width == pytest.approx(0.04) and spec.footprint_radius == pytest.approx(np.hypot(0.05, 0.04) / 2)
    same = ObjectSpec("mesh", file=u_mesh, scale=1, color=(0.2, 0.6, 0.25))
    assert same == spec and hash(same) == hash(spec) and len({spec, same}) == 1
    with pytest.raises(AttributeError):
        spec.scale = (2.0, 2.0, 2.0)  # frozen
    assert calls == []  # a spec alone needs no decomposition

    parts = meshes.convex_parts(spec.file, spec.scale)
    assert len(parts) > 1 and calls == [u_mesh.resolve()]
    assert all(p.is_file() and p.parent.parent == fresh_cache / "meshes" for p in parts)
    verts = np.concatenate([meshes.part_arrays(p)[0] for p in parts])
    np.testing.assert_allclose(verts.min(0), -spec.extents / 2, atol=2e-3)  # the parts cover the centred U
    np.testing.assert_allclose(verts.max(0), spec.extents / 2, atol=2e-3)

    meshes._load.cache_clear()  # a new process: the parts come from the cache files
    assert meshes.convex_parts(str(u_mesh), (1.0, 1.0, 1.0)) == parts and len(calls) == 1
    meshes.convex_parts(str(u_mesh), (1.0, 1.0, 1.2))  # another scale, another decomposition
    assert len(calls) == 2


def test_convex_mesh_is_one_hull_and_its_mass_follows_the_density(tmp_path, fresh_cache, monkeypatch):
    calls = _count_coacd(monkeypatch)
    path = tmp_path / "block.stl"
    trimesh.creation.box((0.03, 0.05, 0.04)).apply_translation([1.0, 2.0, 3.0]).export(path)
    spec = ObjectSpec("mesh", file=path, scale=(1.0, 1.2, 0.6), density=500)  # per-axis scale, off-centre file
    np.testing.assert_allclose(spec.extents, [0.03, 0.06, 0.024], atol=1e-6)  # STL: float32
    assert spec.grasp_width == pytest.approx(0.03)
    (part,) = meshes.convex_parts(spec.file, spec.scale)
    assert calls == []
    np.testing.assert_allclose(meshes.part_arrays(part)[0].min(0), [-0.015, -0.03, -0.012], atol=1e-6)
    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
    builder = scene.create_actor_builder()
    add_collisions(builder, spec)
    body = builder.build(name="block").find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
    assert body.mass == pytest.approx(500 * 0.03 * 0.06 * 0.024, rel=1e-3)


def test_mesh_errors_name_the_file(tmp_path, u_mesh, fresh_cache):
    (tmp_path / "model.fbx").write_text("x")
    (tmp_path / "garbage.ply").write_bytes(b"not a mesh")
    (tmp_path / "text.obj").write_text("hello\n")
    flat = trimesh.Trimesh([[0, 0, 0], [0.03, 0, 0], [0.03, 0.03, 0], [0, 0.03, 0]], [[0, 1, 2], [0, 2, 3]])
    flat.export(tmp_path / "flat.ply")
    opened = trimesh.creation.box((0.03, 0.03, 0.03))
    opened.update_faces(np.arange(len(opened.faces)) >= 2)  # a box without its bottom: not watertight
    opened.export(tmp_path / "open.obj")
    cases = [
        (dict(file=tmp_path / "nowhere.obj"), r"mesh file .*nowhere\.obj does not exist"),
        (dict(file=tmp_path / "model.fbx"), r"mesh file .*model\.fbx: unsupported type '\.fbx'"),
        (dict(file=tmp_path / "garbage.ply"), r"cannot read mesh file .*garbage\.ply"),
        (dict(file=tmp_path / "text.obj"), r"mesh file .*text\.obj holds no triangles"),
        (dict(file=tmp_path / "flat.ply"), r"mesh file .*flat\.ply \(scale .*\) is degenerate"),
        (dict(file=u_mesh, scale=2.0), r"mesh .*u_shape\.obj \(scale \[2\.0, 2\.0, 2\.0\]\) does not fit the gripper"),
        (dict(file=u_mesh, scale=(1, 1, 0.5)), r"mesh .*u_shape\.obj .* is 0\.015 m high"),
        (dict(file=u_mesh, scale=-1), r"mesh .*u_shape\.obj: scale must be"),
        (dict(file=u_mesh, density=0), r"mesh .*u_shape\.obj: density must be"),
        (dict(), r"a mesh object needs file="),
        (dict(file=u_mesh, size=(0.01,)), r"mesh objects take no size"),
    ]
    for kwargs, match in cases:
        with pytest.raises(ValueError, match=match):
            ObjectSpec("mesh", **kwargs)
    with pytest.raises(ValueError, match=r"\['file'\] are fields of mesh objects, not of kind 'cuboid'"):
        ObjectSpec("cuboid", (0.02, 0.02, 0.02), file=str(u_mesh))
    spec = ObjectSpec("mesh", file=tmp_path / "open.obj")  # graspable; its parts need a closed surface
    with pytest.raises(ValueError, match=r"mesh file .*open\.obj is not watertight"):
        meshes.convex_parts(spec.file, spec.scale)


def test_oracle_grasps_a_mesh_object(u_mesh):
    """A one-object layout of the U (turned 17°): validated by its shape, seen in the heightmap, grasped and placed."""
    spec = ObjectSpec("mesh", file=u_mesh, color=(0.2, 0.6, 0.25))
    cx, cy = WS.center
    yaw = np.radians(17)
    env = gym.make("ClutterGrasp-v1", workspace=WS, layout=[(spec, (cx, cy, 0.015, np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)))],
                   **CPU)
    try:
        obs, info = env.reset(seed=0)
        assert env.unwrapped.clutter.names == ["obj_0_mesh"] and int(info["num_objects"]) == 1
        depth = obs["depth_heightmap"][0].numpy()
        assert depth.max() == pytest.approx(0.03, abs=0.003)
        # the U's shape, not its bounding box: pixels wholly in its gap see the table, pixels wholly in an arm its top
        rows, cols = np.indices(depth.shape)
        xy = WS.pixel_to_world(rows, cols, 0.0)[..., :2] - (cx, cy)
        x, y = (xy @ np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])).transpose(2, 0, 1)  # U frame
        m = WS.pixel_size / np.sqrt(2)  # a pixel's half diagonal
        gap = (np.abs(x) < 0.013 - m) & (y > -0.008 + m) & (y < 0.02 - m)
        solid = (np.abs(x) < 0.025 - m) & (np.abs(y) < 0.02 - m) & ~((np.abs(x) < 0.013 + m) & (y > -0.008 - m))
        assert gap.sum() >= 2 and solid.sum() >= 3
        assert depth[gap].max() < 0.005 and depth[solid].min() > 0.025
        obs, reward, terminated, truncated, info = env.step(HeightmapGraspOracle(WS)(obs["depth_heightmap"][0]))
        assert bool(info["grasp_success"]) and bool(info["place_success"]) and bool(terminated)
    finally:
        env.close()


# ----------------------------------------------------------------------------- YCB
def _fake_ycb(root, u_mesh) -> None:
    """A ManiSkill-style YCB folder: info_pick_v0.json and models/<id>/textured.obj (+ collision.ply for one)."""
    base = root / "assets" / "mani_skill2_ycb"
    box = trimesh.creation.box((0.04, 0.05, 0.06))
    info = {
        "900_block": dict(bbox=dict(min=[-0.02, -0.025, -0.03], max=[0.02, 0.025, 0.03]), scales=[1.0], density=400),
        "901_u_shape": dict(bbox=dict(min=[0.0, 0.0, 0.0], max=[0.05, 0.04, 0.03]), scales=[1.0]),
        "902_tray": dict(bbox=dict(min=[-0.1, -0.08, 0.0], max=[0.1, 0.08, 0.03]), scales=[1.0]),
    }
    for model_id in info:
        (base / "models" / model_id).mkdir(parents=True)
    box.export(base / "models" / "900_block" / "textured.obj")
    box.export(base / "models" / "900_block" / "collision.ply")
    (base / "models" / "901_u_shape" / "textured.obj").write_bytes(u_mesh.read_bytes())
    trimesh.creation.box((0.2, 0.16, 0.03)).export(base / "models" / "902_tray" / "textured.obj")
    (base / INFO).write_text(json.dumps(info))



@pytest.fixture
def asset_dir(tmp_path, monkeypatch):
    """ManiSkill's asset folder pointed at an empty ``tmp_path`` (its data source; MS_ASSET_DIR is read at import)."""
    from mani_skill.utils.assets import DATA_SOURCES

    monkeypatch.setattr(DATA_SOURCES["ycb"], "output_dir", tmp_path / "ms_data")
    return tmp_path / "ms_data"


def test_ycb_without_assets_names_the_download_command(asset_dir):
    assert DOWNLOAD_COMMAND == "python -m mani_skill.utils.download_asset ycb"
    assert ycb_dir() == asset_dir / "assets" / "mani_skill2_ycb"
    for call in (ycb_model_ids, ycb_specs, lambda: ycb_spec("005_tomato_soup_can"), lambda: resolve_objects("ycb")):
        with pytest.raises(FileNotFoundError, match=r"YCB assets are not in .*; download them with "
                                                    r"`python -m mani_skill\.utils\.download_asset ycb`"):
            call()
    with pytest.raises(FileNotFoundError, match="download_asset ycb"):
        gym.make("ClutterGrasp-v1", workspace=WS, objects="ycb", **CPU)


def test_ycb_models_from_the_asset_folder(asset_dir, u_mesh, fresh_cache):
    _fake_ycb(asset_dir, u_mesh)
    assert ycb_model_ids() == ["900_block", "901_u_shape", "902_tray"]
    specs, skipped = ycb_specs()
    assert [s.label for s in specs] == ["mesh textured.obj"] * 2 and list(skipped) == ["902_tray"]
    assert "does not fit the gripper" in skipped["902_tray"]
    block, ushape = specs
    assert block.texture and block.density == 400 and block.collision.endswith("900_block/collision.ply")
    assert ushape.collision is None and ushape.density == 1000
    np.testing.assert_allclose(block.extents, [0.04, 0.05, 0.06], atol=1e-9)
    assert len(meshes.convex_parts(block.file, block.scale, block.collision)) == 1  # its collision file's one part
    with pytest.raises(ValueError, match=r"YCB model 902_tray does not fit the gripper"):
        ycb_specs(["900_block", "902_tray"])
    with pytest.raises(ValueError, match=r"unknown YCB model '999_nothing'"):
        ycb_spec("999_nothing")
    assert resolve_objects(["900_block", ushape]) == (block, ushape)
    with pytest.raises(ValueError, match="not both"):
        gym.make("ClutterGrasp-v1", workspace=WS, objects="ycb", object_kinds=("cuboid",), **CPU)
    with pytest.raises(ValueError, match="not with layout"):
        gym.make("ClutterGrasp-v1", workspace=WS, objects="ycb", layout_file="x.yaml", **CPU)

    env = gym.make("ClutterGrasp-v1", workspace=WS, objects="ycb", num_objects=2, **CPU)
    try:
        pool = env.unwrapped.clutter
        assert sorted(pool.names) == ["obj_0_mesh", "obj_1_mesh"] and set(pool.specs) == {block, ushape}  # each once
        obs, info = env.reset(seed=1)
        assert int(info["objects_remaining"]) == 2 and obs["depth_heightmap"][0].max() > 0.02
    finally:
        env.close()
