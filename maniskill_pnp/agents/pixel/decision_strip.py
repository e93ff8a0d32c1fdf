"""A clutter agent's decisions drawn for people: per decision, the colour and depth heightmaps, the Q map of the
chosen primitive and rotation, the action drawn on the heightmap (a grasp as the jaw line the fingers close along,
a slide as an arrow of the slide's length) and its outcome.

``record-clutter`` films with these panels, and ``eval-clutter --strips K`` / ``benchmark`` draw the decisions of
the worst episodes with them (:func:`decisions_strip`: one row per decision), so that a failure can be looked at.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from maniskill_pnp.agents.video_frames import label

#: Side (px) of each heightmap / Q-map panel in the video and the strip.
PANEL = 256
#: Span (m) of the Panda's open jaws, the length of a grasp's jaw line.
JAW_SPAN = 0.08
#: Colours (RGB) of the action drawn per primitive.
ACTION_COLOURS = {"grasp": (255, 40, 40), "left_slide": (40, 220, 255), "right_slide": (255, 200, 0)}


def _resize(img: np.ndarray, size: int = PANEL) -> np.ndarray:
    import cv2

    return cv2.resize(img, (size, size), interpolation=cv2.INTER_NEAREST)


def colorize(values: np.ndarray, vmin: float, vmax: float, cmap: str = "jet") -> np.ndarray:
    """A 2-D array as an RGB uint8 image through a matplotlib colour map over ``[vmin, vmax]``."""
    from matplotlib import colormaps

    scaled = (values - vmin) / (vmax - vmin) if vmax > vmin else np.zeros_like(values)
    return (colormaps[cmap](np.clip(scaled, 0.0, 1.0))[..., :3] * 255).astype(np.uint8)


def draw_action(img: np.ndarray, decision: dict, heightmap_size: int) -> np.ndarray:
    """``img`` (a panel of the heightmap, any size) with the decision's action drawn: the grasp's jaw line or the
    slide's arrow (``decision["direction"]``: unit (x, y) of the jaws or of the push; pixel col follows x, row y)."""
    import cv2

    out = np.ascontiguousarray(img.copy())
    scale = out.shape[0] / heightmap_size
    centre = np.array([decision["col"] + 0.5, decision["row"] + 0.5]) * scale
    d = np.asarray(decision["direction"]) * decision["length_px"] * scale
    colour = ACTION_COLOURS.get(decision["primitive"], (255, 255, 255))
    if decision["primitive"] == "grasp":
        a, b = centre - d / 2, centre + d / 2
        cv2.line(out, tuple(int(v) for v in a), tuple(int(v) for v in b), colour, 2, cv2.LINE_AA)
        cv2.circle(out, tuple(int(v) for v in centre), 4, colour, -1, cv2.LINE_AA)
    else:
        cv2.arrowedLine(out, tuple(int(v) for v in centre), tuple(int(v) for v in centre + d), colour, 2, cv2.LINE_AA, tipLength=0.25)
    return out


def decision_panels(decision: dict, heightmap_size: int) -> list[np.ndarray]:
    """Colour heightmap, depth heightmap, Q map of the chosen primitive and rotation, and the action on the heightmap."""
    depth = decision["depth"]
    qmap = decision["qmap"]
    action_text = f"{decision['primitive']} {decision['degrees']:g}deg r{decision['row']} c{decision['col']}"
    return [
        label(_resize(decision["color"]), f"decision {decision['index']}: colour"),
        label(_resize(colorize(depth, 0.0, max(float(depth.max()), 1e-3), "viridis")), "depth"),
        label(draw_action(_resize(colorize(qmap, float(qmap.min()), float(qmap.max()))), decision, heightmap_size),
              f"Q {qmap.min():.2f}..{qmap.max():.2f}"),
        label(draw_action(_resize(decision["color"]), decision, heightmap_size), action_text),
    ]


def decisions_strip(decisions: list[dict], heightmap_size: int, path: Path) -> Path:
    """One row per decision (:func:`decision_panels`) plus its outcome, written as a PNG."""
    import imageio.v3 as iio

    rows = []
    for d in decisions:
        panels = decision_panels(d, heightmap_size)
        outcome = np.zeros((PANEL, PANEL, 3), np.uint8)
        for i, line in enumerate(d["outcome_lines"]):
            outcome = _text(outcome, line, 30 + 22 * i)
        rows.append(np.concatenate([*panels, outcome], axis=1))
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.concatenate(rows, axis=0))
    return path


def _text(img: np.ndarray, text: str, y: int) -> np.ndarray:
    import cv2

    out = np.ascontiguousarray(img)
    cv2.putText(out, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def describe(env, action: int, maps: np.ndarray, obs: dict, index: int) -> dict:
    """The decision ``action`` of the task ``env`` for drawing: pixel, primitive (decoded by the task's
    ``action_layout``), direction and length."""
    task = env.unwrapped
    ws = task.workspace
    p, r, row, col = (int(v) for v in task.action_layout.decode(action))
    name = task.primitive_names[p]
    yaw = float(ws.rotation_to_yaw(r))
    if name == "grasp":
        direction, length = np.array([math.cos(yaw), math.sin(yaw)]), JAW_SPAN / ws.pixel_size
    else:
        direction, length = ws.slide_direction(r, name.split("_")[0]), ws.slide_length / ws.pixel_size
    return dict(index=index, action=action, primitive=name, rotation=r, row=row, col=col, degrees=math.degrees(yaw) % 360,
                direction=direction, length_px=length, qmap=maps[p, r], q=float(maps[p, r, row, col]),
                color=obs["color_heightmap"][0].cpu().numpy(), depth=obs["depth_heightmap"][0].cpu().numpy())


def outcome_lines(info: dict, reward: float, primitive: str) -> list[str]:
    """The outcome of a decision of ``primitive`` as text lines, from the step's ``info``."""
    lines = [f"reward {reward:.2f}", f"grasped {bool(info['grasp_success'])}", f"placed {int(info['placed_objects'])}"]
    if primitive != "grasp":
        lines.append(f"scene changed {bool(info['slide_changed'])}")
    lines.append(f"left {int(info['objects_remaining'])} objects")
    # the reason, wrapped to the outcome panel's width (34 characters), in at most 4 lines
    lines += textwrap.wrap(failure_reason(info), 34, max_lines=4, placeholder="...")
    return lines


def failure_reason(info: dict) -> str:
    """Why the step failed or the episode cannot go on (empty when neither)."""
    return str(info.get("fault_reason") or info.get("reason") or "")


#: Most decisions one strip shows (an episode of 90 actions would be a 23,000 px tall image).
MAX_STRIP_ROWS = 16


def strip_rows(decisions: list[dict], limit: int = MAX_STRIP_ROWS) -> list[dict]:
    """At most ``limit`` of an episode's drawn decisions, in order: all when they fit, else the failures (no reward,
    or an object lost) first, then the latest of the others; each row's label keeps its decision index."""
    if len(decisions) <= limit:
        return list(decisions)
    bad = [d for d in decisions if d.get("failed") or d.get("lost")]
    rest = [d for d in decisions if d not in bad]
    keep = (bad[:limit] + rest[-max(0, limit - len(bad)):]) if len(bad) < limit else bad[:limit]
    return sorted(keep, key=lambda d: d["index"])


__all__ = ["ACTION_COLOURS", "JAW_SPAN", "MAX_STRIP_ROWS", "PANEL", "colorize", "decision_panels", "decisions_strip",
           "describe", "draw_action", "outcome_lines", "failure_reason", "strip_rows"]
