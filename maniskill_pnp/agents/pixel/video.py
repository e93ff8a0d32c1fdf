"""Film a clutter DQN agent: one greedy episode as an MP4 of the arm's motion, and a strip of its decisions.

Every frame of ``episode.mp4`` shows the scene from the task's render camera (the arm moving through each
primitive, one frame every ``frame_every`` control steps) beside the decision being executed: the colour
heightmap with the chosen action drawn on it, and the Q map of the chosen primitive and rotation. ``decisions.png``
has one row per decision: colour heightmap, depth heightmap, the Q map of the chosen primitive and rotation, the
action drawn on the heightmap and its outcome. Grasps are drawn as the jaw line (the fingers close along it),
slides as an arrow of the slide's length.

Run it with ``maniskill-pnp record-clutter runs/clutter/<run folder>`` (``--scenario complicated`` for a locking
layout of ClutterGraspSlide-v1, ``--layout-file my_scene.yaml`` for your own arrangement).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from maniskill_pnp.agents.pixel.checkpoint import checkpoint_file
from maniskill_pnp.agents.pixel.decision_strip import (PANEL, decision_panels, decisions_strip, describe, failure_reason,
                                                        outcome_lines)
from maniskill_pnp.agents.pixel.evaluate import decide
from maniskill_pnp.agents.pixel.failure_memory import FailureMemory
from maniskill_pnp.agents.pixel.factories import SCENARIOS, is_scenario, load_policy, make_env
from maniskill_pnp.agents.run_io import require_positive, write_json
from maniskill_pnp.agents.video_frames import even_frame
from maniskill_pnp.runtime import resolve_device
from maniskill_pnp.scenes.scene_file import read_scene


@dataclass(frozen=True)
class ClutterVideoConfig:
    """Settings of one filmed greedy episode of a clutter DQN checkpoint."""

    checkpoint: Path
    """checkpoint.pt of a clutter DQN run (train-clutter), or the run folder that holds it."""
    scenario: str = "train"
    """Scene: "train" (the checkpoint's object count), an object count, "min", "medium", "max" or "complicated"."""
    layout_file: Path | None = None
    """Scene file (YAML or JSON) of your own arrangement to film instead of a scenario."""
    seed: int = 1000
    """Seed of the scene."""
    max_steps: int = 10
    """Cap on the decisions filmed (the episode may end earlier: cleared, or truncated by the task)."""
    grasp_only: bool = False
    """Mask out every primitive but grasps (a G&S agent filmed as a grasp-only agent)."""
    avoid_repeats: bool = True
    """Never repeat a failed action nor its neighbours until the heightmap changes, as ``eval-clutter`` acts (see
    :class:`~maniskill_pnp.agents.pixel.failure_memory.FailureMemory`); False: the plain argmax."""
    frame_every: int = 3
    """Keep one video frame every this many control steps (20 Hz control)."""
    fps: int = 20
    """Frame rate of the MP4."""
    out: Path = Path("runs/clutter_video")
    """Folder for episode.mp4, decisions.png and video_summary.json."""
    device: str = "auto"
    """Torch device of the Q network ("auto": CUDA when available, else CPU)."""

    def __post_init__(self):
        object.__setattr__(self, "checkpoint", Path(self.checkpoint))
        object.__setattr__(self, "out", Path(self.out))
        object.__setattr__(self, "scenario", str(self.scenario))
        if not is_scenario(self.scenario):
            raise ValueError(f"unknown scenario {self.scenario!r}; valid: a positive object count or one of {list(SCENARIOS)}")
        if self.layout_file is not None:
            object.__setattr__(self, "layout_file", Path(self.layout_file))
            if self.scenario != "train":
                raise ValueError(f"give a scenario ({self.scenario!r}) or a layout_file, not both")
            read_scene(self.layout_file)  # schema errors before any env is made (the workspace is checked then)
        require_positive(self, ("max_steps", "frame_every", "fps"))
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")

    @property
    def checkpoint_path(self) -> Path:
        return checkpoint_file(self.checkpoint)


# ----------------------------------------------------------------------------- drawing
def run(cfg: ClutterVideoConfig) -> dict:
    """Film one greedy episode; write ``episode.mp4``, ``decisions.png`` and ``video_summary.json`` into ``cfg.out``.

    Raises:
        FileNotFoundError: the checkpoint does not exist.
        ValueError: the checkpoint is unreadable, or the scenario does not fit its task.
    """
    import imageio.v3 as iio

    device = resolve_device(cfg.device)
    actor, train_cfg, counters = load_policy(cfg.checkpoint_path, device, grasp_only=cfg.grasp_only)
    scene = {} if cfg.layout_file is None else dict(layout_file=str(cfg.layout_file))
    torchrl_env = make_env(train_cfg, cfg.scenario, render_mode="rgb_array", **scene)
    env = torchrl_env.maniskill_env
    size = train_cfg.heightmap_size
    frames: list[np.ndarray] = []
    current: list[np.ndarray] = []  # the decision panel shown beside the scene while its primitive runs
    counter = [0]

    def grab():
        counter[0] += 1
        if counter[0] % cfg.frame_every == 0:
            frames.append(np.concatenate([env.render()[0].cpu().numpy(), current[0]], axis=1))

    decisions, records = [], []
    try:
        obs, info = env.reset(seed=cfg.seed)
        objects = int(info["num_objects"])
        env.unwrapped.set_control_step_callback(grab)
        memory = FailureMemory(env.unwrapped.action_layout, env.unwrapped.primitive_names) if cfg.avoid_repeats else None
        done = False
        while not done and len(decisions) < cfg.max_steps:
            action, maps = decide(actor, obs, device, exclude=() if memory is None else memory.excluded())
            decision = describe(env, action, maps.numpy(), obs, len(decisions))
            panels = decision_panels(decision, size)
            scene = env.render()[0].cpu().numpy()
            side = np.concatenate([panels[3], panels[2]], axis=0)  # action on the heightmap above its Q map
            current[:] = [_fit_height(side, scene.shape[0])]
            frames.append(np.concatenate([scene, current[0]], axis=1))
            obs, reward, terminated, truncated, info = env.step(action)
            decision["outcome_lines"] = outcome_lines(info, float(reward.item()), decision["primitive"])
            decisions.append(decision)
            if memory is not None:
                memory.observe(action, int(info["consecutive_failures"]) > 0, obs["depth_heightmap"][0].cpu().numpy())
            records.append(dict(decision=decision["index"], primitive=decision["primitive"], rotation=decision["rotation"],
                                row=decision["row"], col=decision["col"], q=decision["q"], reward=float(reward.item()),
                                grasp_success=bool(info["grasp_success"]), place_success=bool(info["place_success"]),
                                placed_objects=int(info["placed_objects"]),
                                objects_remaining=int(info["objects_remaining"]), reason=failure_reason(info)))
            done = bool(terminated.item() or truncated.item())
        env.unwrapped.set_control_step_callback(None)
    finally:
        torchrl_env.close()

    out = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    video = out / "episode.mp4"
    iio.imwrite(video, np.stack([even_frame(f) for f in frames]), fps=cfg.fps, codec="libx264")
    strip = decisions_strip(decisions, size, out / "decisions.png")
    summary = dict(
        checkpoint=str(cfg.checkpoint_path), scenario=cfg.scenario if cfg.layout_file is None else cfg.layout_file.stem,
        layout_file=None if cfg.layout_file is None else str(cfg.layout_file), seed=cfg.seed, objects=objects,
        decisions=records,
        placed=sum(r["placed_objects"] for r in records), cleared=bool(info["objects_remaining"] == 0), frames=len(frames),
        train_counters=counters, config={k: str(v) for k, v in dataclasses.asdict(cfg).items()},
        files=dict(video=str(video), strip=str(strip), summary=str(out / "video_summary.json")),
    )
    write_json(out / "video_summary.json", summary)
    return summary


def _fit_height(img: np.ndarray, height: int) -> np.ndarray:
    import cv2

    width = int(round(img.shape[1] * height / img.shape[0]))
    return cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)


__all__ = ["ClutterVideoConfig", "PANEL", "run"]
