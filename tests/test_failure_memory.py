"""FailureMemory: a greedy agent does not retry a failed action, nor its neighbours, on an unchanged scene."""

from __future__ import annotations

import numpy as np
import pytest

from maniskill_pnp.agents.pixel.failure_memory import FailureMemory
from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.tasks.clutter_grasp_slide import change_threshold

LAYOUT = PixelActionLayout(3, 16, 64, 64)
PRIMITIVES = ("grasp", "left_slide", "right_slide")


def _ruled(memory: FailureMemory) -> set[tuple[int, int, int, int]]:
    return {tuple(int(v) for v in LAYOUT.decode(int(i))) for i in memory.excluded()}


def test_a_failure_rules_out_its_neighbourhood_until_the_heightmap_changes():
    memory = FailureMemory(LAYOUT, PRIMITIVES)
    scene = np.zeros((64, 64), np.float32)
    scene[20:30, 20:30] = 0.05
    memory.observe(LAYOUT.encode(1, 3, 0, 59), failed=True, depth_after=scene)  # a slide at the border that moved nothing
    ruled = _ruled(memory)
    assert (1, 3, 0, 59) in ruled and (1, 2, 2, 61) in ruled and (1, 4, 0, 57) in ruled
    assert (1, 5, 0, 59) not in ruled and (1, 3, 3, 59) not in ruled and (2, 3, 0, 59) not in ruled
    assert len(ruled) == 3 * 3 * 5  # rotations 2-4, rows 0-2 (cut at the border), cols 57-61

    nudged = scene.copy()
    nudged[20:22, 20:30] = 0.0  # fewer changed pixels than VPG's test needs: the same scene
    assert 20 < change_threshold(64, 64)
    memory.observe(LAYOUT.encode(0, 0, 25, 25), failed=True, depth_after=nudged)
    ruled = _ruled(memory)
    assert (1, 3, 0, 59) in ruled and (0, 0, 25, 25) in ruled
    assert (0, 8, 25, 25) in ruled and (0, 15, 27, 23) in ruled  # a grasp turned by 180° is the same grasp
    assert (1, 11, 0, 59) not in ruled  # a slide turned by 180° pushes the other way

    moved = nudged.copy()
    moved[20:30, 20:30] = 0.0  # the block is gone: 100 changed pixels
    memory.observe(LAYOUT.encode(0, 1, 40, 40), failed=False, depth_after=moved)
    assert memory.excluded().size == 0


def test_memory_resets_and_checks_its_arguments():
    memory = FailureMemory(LAYOUT, PRIMITIVES, radius_px=0, rotation_steps=0)
    memory.observe(LAYOUT.encode(2, 7, 10, 10), failed=True, depth_after=np.zeros((64, 64)))
    assert memory.excluded().tolist() == [LAYOUT.encode(2, 7, 10, 10)]
    memory.reset()
    assert memory.excluded().size == 0
    with pytest.raises(ValueError, match="radius_px"):
        FailureMemory(LAYOUT, PRIMITIVES, radius_px=-1)
    with pytest.raises(ValueError, match="primitive names"):
        FailureMemory(LAYOUT, ("grasp",))


def test_the_rechoice_after_a_failure_keeps_the_slide_margin():
    """With a failed grasp ruled out, the greedy choice ranks what is left as the actor does: a slide needs to beat the
    best remaining grasp by the actor's slide margin."""
    import torch
    from torch import nn

    from maniskill_pnp.agents.pixel.evaluate import decide
    from maniskill_pnp.agents.pixel.policy import GreedyPixelActor

    layout = PixelActionLayout(3, 2, 4, 4)
    values = torch.zeros(layout.shape)
    values[0, 0, 1, 1] = 1.0  # the best grasp, which failed
    values[0, 1, 2, 2] = 0.6  # the next grasp
    values[1, 0, 3, 3] = 0.9  # a slide: beats the next grasp, but by less than the margin

    class Fixed(nn.Module):
        primitives, num_rotations = PRIMITIVES, 2

        def forward(self, x):
            return values[None].expand(x.shape[0], *values.shape)

    actor = GreedyPixelActor(Fixed(), primitive_margins=(0.0, 0.5, 0.5))
    obs = dict(color_heightmap=torch.zeros(1, 4, 4, 3, dtype=torch.uint8), depth_heightmap=torch.zeros(1, 4, 4))
    assert decide(actor, obs, torch.device("cpu"))[0] == layout.encode(0, 0, 1, 1)
    action, _ = decide(actor, obs, torch.device("cpu"), exclude=[layout.encode(0, 0, 1, 1)])
    assert action == layout.encode(0, 1, 2, 2)
