"""The package's demo job: plan and execute a pick-and-place of a cube with OMPL, and film it.

Run with ``maniskill-pnp demo`` (or ``python -m maniskill_pnp.demo``); writes an MP4 of the arm's whole
motion and a PNG strip of key moments into the output folder.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from maniskill_pnp.planning import MotionPrimitives, grasp_pose
from maniskill_pnp.runtime import default_backends

STATIC_ACTORS = ("table-workspace", "ground", "bin")


@dataclass(frozen=True)
class DemoConfig:
    """Settings of the pick-and-place demo.

    Attributes:
        out: Output folder (created); the video, image strip and a JSON summary go there.
        seed: Episode seed (cube position and yaw).
        frame_every: Record one video frame every this many control steps.
        fps: Frame rate of the MP4.
    """

    out: Path = Path("runs/demo")
    seed: int = 0
    frame_every: int = 2
    fps: int = 20


def cube_grasp_pose(env):
    """Top-down grasp at the cube's centre, jaws across the cube's faces."""
    cube = env.unwrapped.cube.pose
    p, q = cube.p[0].cpu().numpy(), cube.q[0].cpu().numpy()
    return grasp_pose(p, yaw=2 * np.arctan2(q[3], q[0]))


def run_demo(cfg: DemoConfig) -> dict:
    """Pick the cube, place it in the bin, go home; return a summary and write the media files."""
    import imageio.v3 as iio

    cfg.out.mkdir(parents=True, exist_ok=True)
    env = gym.make("CubeToBin-v1", obs_mode="state", control_mode="pd_joint_pos", render_mode="rgb_array", **default_backends())
    env.reset(seed=cfg.seed)
    frames: list[np.ndarray] = []
    counter = [0]

    def grab():
        counter[0] += 1
        if counter[0] % cfg.frame_every == 0:
            frames.append(env.render()[0].cpu().numpy())

    prims = MotionPrimitives(env, static_actors=STATIC_ACTORS, seed=cfg.seed, on_control_step=grab)
    frames.append(env.render()[0].cpu().numpy())
    t0 = time.perf_counter()
    results = {"pick": prims.pick(cube_grasp_pose(env), target="cube")}
    keyframes = [frames[0], frames[-1]]
    if results["pick"].ok:
        results["place"] = prims.place(env.unwrapped.bin_spec.region())
        keyframes.append(frames[-1])
    results["home"] = prims.go_home()
    keyframes.append(frames[-1])
    wall = time.perf_counter() - t0
    success = bool(env.unwrapped.evaluate()["success"].item())
    env.close()

    video = cfg.out / "pick_and_place.mp4"
    iio.imwrite(video, np.stack(frames), fps=cfg.fps, codec="libx264")
    strip = cfg.out / "pick_and_place_strip.png"
    iio.imwrite(strip, np.concatenate(keyframes, axis=1))
    summary = {
        "success": success,
        "wall_time_s_incl_rendering": round(wall, 2),
        "sim_steps": sum(r.sim_steps for r in results.values()),
        "planning_time_s": round(sum(r.planning_time for r in results.values()), 3),
        "stages": {k: {"ok": r.ok, "stage": r.stage, "reason": r.reason} for k, r in results.items()},
        "video": str(video),
        "strip": str(strip),
        "config": {k: str(v) for k, v in asdict(cfg).items()},
    }
    (cfg.out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    print(json.dumps(run_demo(DemoConfig()), indent=2))
