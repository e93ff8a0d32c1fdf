"""Determinism: the same seed gives the same clutter, observations and scripted episode (one process per run, as
OMPL seeds its random generator once per process)."""

from __future__ import annotations

import json
import subprocess
import sys

SCRIPT = r"""
import json, gymnasium as gym, numpy as np
import maniskill_pnp
from maniskill_pnp.tasks.clutter_oracle import HeightmapGraspOracle
from maniskill_pnp.tasks.workspace import WorkspaceSpec
ws = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=4)
env = gym.make("ClutterGrasp-v1", num_objects=4, workspace=ws, planner_seed=3, sim_backend="physx_cpu", render_backend="cpu")
obs, info = env.reset(seed=11)
oracle = HeightmapGraspOracle(env.unwrapped.workspace)
record = dict(height=float(obs["depth_heightmap"].sum()), actions=[], rewards=[])
for _ in range(3):
    action = oracle(obs["depth_heightmap"][0])
    obs, reward, terminated, truncated, info = env.step(action)
    record["actions"].append(int(action))
    record["rewards"].append(float(reward))
record["positions"] = np.round([a.pose.p[0].numpy() for a in env.unwrapped.clutter.active_actors[0]], 4).tolist()
print("RECORD" + json.dumps(record))
"""


def _episode() -> dict:
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = next(x for x in proc.stdout.splitlines() if x.startswith("RECORD"))
    return json.loads(line[len("RECORD"):])


def test_same_seed_same_scripted_episode():
    first, second = _episode(), _episode()
    assert first["height"] > 0 and len(first["actions"]) == 3
    assert first == second
