"""CubeToBin-v1: one cube on the table, a bin beside it; the smallest pick-and-place scene.

It is the scene of the package's demo and of the motion-primitive tests: a plain ManiSkill task with
the Panda's low-level action space, which :class:`maniskill_pnp.planning.MotionPrimitives` drives.
"""

from __future__ import annotations

import numpy as np
import sapien
import torch

import mani_skill.envs.utils.randomization as randomization
from mani_skill.agents.robots import Panda
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.building import actors
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.pose import Pose

from maniskill_pnp.cell.bin import BinSpec, build_bin
from maniskill_pnp.tasks.registration import SeededNpRandom, register_task

ROBOT_BASE = (-0.615, 0.0, 0.0)


@register_task("CubeToBin-v1", max_episode_steps=400)
class CubeToBinEnv(SeededNpRandom, BaseEnv):
    """**Task Description:**
    Pick up a cube lying on the table and drop it into the bin beside the workspace, with ManiSkill's Panda.

    **Randomizations:**
    - the cube's xy position is uniform in a square of half size ``spawn_half_size`` around ``spawn_center``
    - the cube's yaw is uniform; it lies flat on the table

    **Success Conditions:**
    - the cube's centre is inside the bin (within the bin's inner footprint, below the top of its walls)
    """

    SUPPORTED_ROBOTS = ["panda"]
    agent: Panda
    cube_half_size = 0.02
    spawn_center = (0.0, -0.05)
    spawn_half_size = 0.1

    def __init__(
        self,
        *args,
        robot_uids="panda",
        bin_spec: BinSpec = BinSpec(),
        obstacles: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (),
        robot_init_qpos_noise=0.0,
        **kwargs,
    ):
        """Args beyond ManiSkill's: ``bin_spec`` (bin geometry) and ``obstacles``, static boxes given as
        ``(center xyz, half size xyz)`` pairs (named ``obstacle_0``, ``obstacle_1``...)."""
        for i, (center, half) in enumerate(obstacles):
            if len(center) != 3 or len(half) != 3 or min(half) <= 0:
                raise ValueError(f"obstacle {i} must be ((x, y, z), (hx, hy, hz)) with positive half sizes, got {(center, half)}")
        self.bin_spec = bin_spec
        self.obstacle_boxes = tuple(obstacles)
        self.robot_init_qpos_noise = robot_init_qpos_noise
        # Every reset draws the cube under a torch RNG forked from the episode seed, so a seeded reset followed by
        # unseeded ones is reproducible (gymnasium's contract; ManiSkill's default seeds only seeded resets).
        kwargs.setdefault("enhanced_determinism", True)
        super().__init__(*args, robot_uids=robot_uids, **kwargs)

    @property
    def _default_sensor_configs(self):
        pose = sapien_utils.look_at(eye=[0.3, 0, 0.6], target=[-0.1, 0, 0.1])
        return [CameraConfig("base_camera", pose, 128, 128, np.pi / 2, 0.01, 100)]

    @property
    def _default_human_render_camera_configs(self):
        pose = sapien_utils.look_at(eye=[0.75, 0.55, 0.75], target=[-0.15, 0.1, 0.1])
        return CameraConfig("render_camera", pose, 512, 512, 1, 0.01, 100)

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=list(ROBOT_BASE)))

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=self.robot_init_qpos_noise)
        self.table_scene.build()
        self.cube = actors.build_cube(
            self.scene, half_size=self.cube_half_size, color=[0.85, 0.2, 0.15, 1], name="cube",
            initial_pose=sapien.Pose(p=[0, 0, self.cube_half_size]),
        )
        self.bin = build_bin(self.scene, self.bin_spec)
        self.obstacles = [
            actors.build_box(
                self.scene, half_sizes=list(half), color=[0.3, 0.5, 0.8, 1], name=f"obstacle_{i}",
                body_type="static", initial_pose=sapien.Pose(p=list(center)),
            )
            for i, (center, half) in enumerate(self.obstacle_boxes)
        ]

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = len(env_idx)
            self.table_scene.initialize(env_idx)
            xyz = torch.zeros((b, 3))
            xyz[:, :2] = (torch.rand((b, 2)) * 2 - 1) * self.spawn_half_size + torch.tensor(self.spawn_center)
            xyz[:, 2] = self.cube_half_size
            qs = randomization.random_quaternions(b, lock_x=True, lock_y=True)
            self.cube.set_pose(Pose.create_from_pq(xyz, qs))

    def evaluate(self):
        region = self.bin_spec.region()
        p = self.cube.pose.p
        c = torch.as_tensor(region.center, device=p.device, dtype=p.dtype)
        half = torch.as_tensor(region.half_size, device=p.device, dtype=p.dtype)
        inside_xy = torch.all(torch.abs(p[:, :2] - c[:2]) <= half[:2], dim=1)
        inside_z = (p[:, 2] >= c[2]) & (p[:, 2] <= c[2] + 2 * half[2])
        return {"success": inside_xy & inside_z}

    def _get_obs_extra(self, info: dict):
        return dict(tcp_pose=self.agent.tcp_pose.raw_pose, cube_pose=self.cube.pose.raw_pose)

    def compute_dense_reward(self, obs, action: torch.Tensor, info: dict):
        return info["success"].float()

    def compute_normalized_dense_reward(self, obs, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs, action, info)
