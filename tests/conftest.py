"""Shared fixtures: expensive ManiSkill envs are made once per session and reset per test."""

from __future__ import annotations

import os

import gymnasium as gym
import pytest
import torch

import maniskill_pnp  # noqa: F401  (registers the tasks)

CPU = dict(sim_backend="physx_cpu", render_backend="cpu")

if os.environ.get("PYTEST_XDIST_WORKER"):
    # pytest-xdist runs one test process per core: one torch thread each (their subprocesses inherit it through
    # OMP_NUM_THREADS), so that two processes do not each spin two threads on two cores.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)


def pytest_collection_modifyitems(config, items):
    import importlib.util

    skips = {}
    if not torch.cuda.is_available():
        skips["gpu"] = pytest.mark.skip(reason="needs an NVIDIA GPU")
    if importlib.util.find_spec("ray") is None:
        skips["ray"] = pytest.mark.skip(reason="needs the ray extra (pip install 'maniskill_pnp[ray]')")
    for item in items:
        for marker, skip in skips.items():
            if marker in item.keywords:
                item.add_marker(skip)


@pytest.fixture(scope="session")
def cube_env():
    """CubeToBin-v1 in pd_joint_pos mode on the CPU (state observations)."""
    env = gym.make("CubeToBin-v1", obs_mode="state", control_mode="pd_joint_pos", **CPU)
    yield env
    env.close()


WALL = ((0.15, 0.0, 0.12), (0.1, 0.015, 0.12))


@pytest.fixture(scope="session")
def wall_env():
    """CubeToBin-v1 with a wall in front of the robot that parts y<0 from y>0."""
    env = gym.make("CubeToBin-v1", obs_mode="state", control_mode="pd_joint_pos", obstacles=(WALL,), **CPU)
    yield env
    env.close()


@pytest.fixture(scope="session")
def tiny_clutter_run(tmp_path_factory):
    """A run folder trained for two grasps: 32 px heightmaps, 2 rotations, 2 objects, the small backbone, collected
    in this process (the tests that use it read the folder; worker-process collection is tested in test_collection)."""
    from maniskill_pnp.agents.pixel.config import ClutterConfig
    from maniskill_pnp.agents.pixel.recipe import main as train

    out = tmp_path_factory.mktemp("clutter_runs")
    cfg = ClutterConfig.from_preset("cpu-small", heightmap_size=32, num_rotations=2, num_objects=2, steps=2,
                                    checkpoint_interval=2, log_interval=1, collector="direct", out=out)
    summary = train(cfg)
    assert summary["steps"] == 2
    return cfg.run_dir


def u_prism(length=0.05, width=0.04, thickness=0.012, height=0.03):
    """A watertight U-shaped prism (trimesh): a base bar along x and two arms along y, ``height`` high, its corner at
    the origin (not centred: mesh objects centre themselves)."""
    import numpy as np
    import trimesh

    l, w, t = length, width, thickness
    outline = np.array([[0, 0], [l, 0], [l, w], [l - t, w], [l - t, t], [t, t], [t, w], [0, w]], dtype=float)
    triangles = np.array([[0, 1, 4], [1, 2, 3], [1, 3, 4], [0, 4, 5], [0, 5, 6], [0, 6, 7]])
    return trimesh.creation.extrude_triangulation(outline, triangles, height)


@pytest.fixture(scope="session")
def u_mesh(tmp_path_factory):
    """An OBJ file of :func:`u_prism` (5 x 4 cm, arms 1.2 cm thick, 3 cm high), in a folder of its own."""
    path = tmp_path_factory.mktemp("meshes") / "u_shape.obj"
    u_prism().export(path)
    return path
