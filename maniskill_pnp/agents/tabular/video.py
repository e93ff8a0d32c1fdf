"""Film a conveyor agent: one greedy episode of ConveyorProximity-v1 as an MP4.

The frames come from the task's render camera through its control-step callback, so the video shows the belt
carrying the object past the ray gates while the arm waits, then the planned pre-pick, grasp and place motions.
A band at the top of every frame names the phase, the sensed speed and lane, and the coordinate the agent chose.

Run it with ``maniskill-pnp record-conveyor runs/conveyor/<run folder> --kind cylinder --speed fast``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from maniskill_pnp.agents.run_io import require_positive, write_json
from maniskill_pnp.agents.tabular.qtable import make_qtable_policy
from maniskill_pnp.agents.tabular.recipe import load_qtable, make_env, qtable_file
from maniskill_pnp.agents.video_frames import even_frame, label
from maniskill_pnp.tasks.conveyor_config import ALIGNMENTS, OBJECT_KINDS, PHASES, SPEEDS


@dataclass(frozen=True)
class ConveyorVideoConfig:
    """Settings of one filmed greedy conveyor episode."""

    checkpoint: Path
    """qtable.pt of a train-conveyor run, or the run folder that holds it."""
    kind: str = "cuboid"
    """Object on the belt: cuboid, cylinder or sphere."""
    alignment: str | None = None
    """Lane of the object (left, center, right); None: drawn at random."""
    speed: str | None = None
    """Belt speed class (slow, medium, fast); None: drawn at random."""
    seed: int = 0
    """Seed of the episode."""
    frame_every: int = 2
    """Keep one video frame every this many control steps (20 Hz control)."""
    fps: int = 20
    """Frame rate of the MP4."""
    out: Path = Path("runs/conveyor_video")
    """Folder for episode.mp4 and video_summary.json."""

    def __post_init__(self):
        object.__setattr__(self, "checkpoint", Path(self.checkpoint))
        object.__setattr__(self, "out", Path(self.out))
        for name, value, valid in (("kind", self.kind, OBJECT_KINDS), ("alignment", self.alignment, ALIGNMENTS),
                                   ("speed", self.speed, SPEEDS)):
            if value is not None and value not in valid:
                raise ValueError(f"unknown {name} {value!r}; valid: {list(valid)}")
        require_positive(self, ("frame_every", "fps"))

    @property
    def checkpoint_path(self) -> Path:
        return qtable_file(self.checkpoint)


def run(cfg: ConveyorVideoConfig) -> dict:
    """Film one greedy episode; write ``episode.mp4`` and ``video_summary.json`` into ``cfg.out``.

    Raises:
        FileNotFoundError: the checkpoint does not exist.
        ValueError: it is not a conveyor Q-table.
    """
    import imageio.v3 as iio

    table, train_cfg, _ = load_qtable(cfg.checkpoint_path)
    env = make_env(train_cfg, reward_scheme="normal", object_kinds=(cfg.kind,), alignment=cfg.alignment, speed=cfg.speed,
                   render_mode="rgb_array")
    env.set_seed(cfg.seed)
    policy, _, _ = make_qtable_policy(table, env.action_spec_unbatched, eps_init=0.0, eps_end=0.0, annealing_num_steps=1)
    task = env.base_env.maniskill_env.unwrapped
    frames: list[np.ndarray] = []
    caption = [""]
    counter = [0]

    def grab():
        counter[0] += 1
        if counter[0] % cfg.frame_every == 0:
            frames.append(label(task.render()[0].cpu().numpy(), caption[0]))

    decisions = []
    try:
        td = env.reset()
        task.set_control_step_callback(grab)
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            for _ in PHASES:
                info = task.evaluate()
                phase = info["phase"]
                td = policy(td)
                action = int(td.get("action").reshape(-1)[0])
                caption[0] = f"{phase}: action {action} | sensed speed {info['sensed_speed']}, lane {info['sensed_alignment']}"
                frames.append(label(task.render()[0].cpu().numpy(), caption[0]))
                td = env.step(td)
                decisions.append(dict(phase=phase, action=action, reward=float(td.get(("next", "reward")).reshape(-1)[0])))
                if bool(td.get(("next", "done")).any()):
                    break
                td = step_mdp(td)
        final = task.evaluate()
        task.set_control_step_callback(None)
    finally:
        env.close()

    cfg.out.mkdir(parents=True, exist_ok=True)
    video = cfg.out / "episode.mp4"
    iio.imwrite(video, np.stack([even_frame(f) for f in frames]), fps=cfg.fps, codec="libx264")
    summary = dict(
        checkpoint=str(cfg.checkpoint_path), decisions=decisions, placed=bool(final["success"].item()),
        sensed_speed=final["sensed_speed"], sensed_alignment=final["sensed_alignment"], frames=len(frames),
        config={k: str(v) for k, v in dataclasses.asdict(cfg).items()},
        files=dict(video=str(video), summary=str(cfg.out / "video_summary.json")),
    )
    write_json(cfg.out / "video_summary.json", summary)
    return summary


__all__ = ["ConveyorVideoConfig", "run"]
