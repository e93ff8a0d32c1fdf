"""The heightmap action mask, and the actor and DQN bootstrap acting under it."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from tensordict import TensorDict
import torch.nn.functional as F
from torch import nn
from torchrl.data import Categorical
from torchrl.envs.utils import ExplorationType, set_exploration_type

from maniskill_pnp.agents.pixel.loss import PixelDQNLoss
from maniskill_pnp.agents.pixel.mask import HeightmapActionMask
from maniskill_pnp.agents.pixel.policy import GreedyPixelActor, PrimitiveExploreMask, make_pixel_policy
from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.cell.workspace import WorkspaceSpec

H = W = 8
R = 2


def block_height(b: int = 1) -> torch.Tensor:
    """Heights ``(b, H, W)``: one 2x2 block of 3 cm at rows 2-3, cols 5-6, bare table elsewhere."""
    h = torch.zeros(b, H, W)
    h[:, 2:4, 5:7] = 0.03
    return h


class FixedMaps(nn.Module):
    """Returns preset maps ``(N, *layout.shape)`` whatever the heightmap."""

    def __init__(self, maps: torch.Tensor):
        super().__init__()
        self.maps = nn.Parameter(maps, requires_grad=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.maps.expand(x.shape[0], *self.maps.shape[1:])


def test_grasps_only_on_material_slides_from_bare_table_towards_it():
    layout = PixelActionLayout(3, R, H, W)
    mask = HeightmapActionMask(("grasp", "left_slide", "right_slide"), R, slide_clear_px=0, slide_ahead_px=2)
    flat = mask(block_height())
    assert flat.shape == (1, layout.size) and flat.dtype == torch.bool
    maps = flat.reshape(1, *layout.shape)[0]
    occupied = block_height()[0] > 0.01
    for r in range(R):
        assert torch.equal(maps[0, r], occupied)
    # Rotation 0 pushes left along +y (growing rows), right along -y; rotation 1 (180°) the other way round.
    # The block fills rows 2-3, cols 5-6: a left slide of rotation 0 must start 1-2 rows above it.
    towards_growing_rows = torch.zeros(H, W, dtype=torch.bool)
    towards_growing_rows[0:2, 5:7] = True
    towards_falling_rows = torch.zeros(H, W, dtype=torch.bool)
    towards_falling_rows[4:6, 5:7] = True
    assert torch.equal(maps[1, 0], towards_growing_rows) and torch.equal(maps[2, 1], towards_growing_rows)
    assert torch.equal(maps[2, 0], towards_falling_rows) and torch.equal(maps[1, 1], towards_falling_rows)


def test_slides_keep_clear_of_material_at_their_start_and_follow_the_workspace_direction():
    from maniskill_pnp.cell.workspace import WorkspaceSpec

    rots, size = 4, 16
    height = torch.zeros(1, size, size)
    height[:, 7:9, 7:9] = 0.05
    mask = HeightmapActionMask(("left_slide", "right_slide"), rots, slide_clear_px=1, slide_ahead_px=4)
    maps = mask.pixel_masks(height)[0]
    assert maps.shape == (2, rots, size, size)
    ws = WorkspaceSpec(num_rotations=rots)
    for p, side in enumerate(("left", "right")):
        for r in range(rots):
            rows, cols = torch.nonzero(maps[p, r], as_tuple=True)
            assert len(rows) > 0
            dx, dy = ws.slide_direction(r, side)
            # every allowed start lies on the block's far side from the push: the block centre is ahead of it
            ahead = (7.5 - rows.double()) * dy + (7.5 - cols.double()) * dx
            assert (ahead > 0).all()
            # ... at least two pixels from the block (one pixel of clearance) and at most four
            gap = torch.maximum((rows - 7.5).abs(), (cols - 7.5).abs()) - 0.5
            assert gap.min() >= 2 and gap.max() <= 4


def test_mask_for_workspace_converts_metres_to_pixels():
    from maniskill_pnp.cell.workspace import WorkspaceSpec

    ws = WorkspaceSpec(heightmap_size=64, pixel_size=0.007, num_rotations=16)
    mask = HeightmapActionMask.for_workspace(("grasp", "left_slide"), ws)
    assert (mask.slide_clear_px, mask.slide_ahead_px) == (1, 6)  # 1 cm / 7 mm, half of 8 cm / 7 mm
    with pytest.raises(ValueError, match="ahead_fraction"):
        HeightmapActionMask.for_workspace(("grasp",), ws, ahead_fraction=0.0)


def test_an_empty_heightmap_allows_everything():
    flat = HeightmapActionMask(("grasp",), R)(torch.zeros(2, H, W))
    assert flat.all()


@pytest.mark.parametrize("kwargs", [dict(primitives=("push",)), dict(primitives=()), dict(num_rotations=0),
                                    dict(min_height=-1.0), dict(slide_clear_px=-1),
                                    dict(slide_ahead_px=0), dict(pixel_size=0.0), dict(fit_tolerance=-1e-3)])
def test_bad_mask_options_raise(kwargs):
    args = dict(primitives=("grasp",), num_rotations=R) | kwargs
    with pytest.raises(ValueError):
        HeightmapActionMask(**args)


def test_grasp_fit_masks_grasps_whose_open_fingers_would_strike_the_map():
    from maniskill_pnp.cell.workspace import WorkspaceSpec

    px, size = 0.007, 32
    ws = WorkspaceSpec(heightmap_size=size, pixel_size=px, num_rotations=4)
    mask = HeightmapActionMask.for_workspace(("grasp",), ws, grasp_fit=True)
    assert (mask.grasp_depth, mask.pixel_size) == (pytest.approx(0.02), px)
    lone = torch.zeros(1, size, size)
    lone[0, 13:19, 13:19] = 0.04  # a 4.2 cm cube: the jaws (8 cm open) fit over it wherever their pads bear on it
    maps = mask.pixel_masks(lone)[0, 0]
    across_x, across_y = torch.zeros(size, size, dtype=torch.bool), torch.zeros(size, size, dtype=torch.bool)
    across_x[14:18, 13:19] = True  # pads 1.75 cm wide: their edges lie a pixel beside the grasp's row
    across_y[13:19, 14:18] = True
    assert torch.equal(maps[0], across_x) and torch.equal(maps[1], across_y)
    row = torch.zeros(1, size, size)
    row[0, 13:19, 10:22] = 0.04  # two such cubes pressed together along x (columns): 8.4 cm, wider than the jaws
    maps = mask.pixel_masks(row)[0, 0]
    assert not maps[0].any() and not maps[2].any()  # closing along x lands a finger on the row
    assert maps[1].sum() == maps[3].sum() == 60 and maps[1, 13:19, 11:21].all()  # closing along y fits over it
    tall = row.clone()
    tall[0, 7:9, 13:19] = 0.12  # a tall neighbour 3 cm from the row's side: the fingers, or the hand, strike it
    maps = mask.pixel_masks(tall)[0, 0]
    assert not maps[1, 13:19].any() and maps[1, 7:9, 14:18].all()  # the 1.4 cm thick neighbour can be grasped


def test_grasp_fit_falls_back_to_material_where_no_grasp_fits():
    from maniskill_pnp.cell.workspace import WorkspaceSpec

    ws = WorkspaceSpec(heightmap_size=32, pixel_size=0.007, num_rotations=4)
    block = torch.zeros(1, 32, 32)
    block[0, 8:24, 8:24] = 0.04  # an 11 cm square slab: no jaw opening spans it
    fit = HeightmapActionMask.for_workspace(("grasp", "left_slide"), ws, grasp_fit=True)
    plain = HeightmapActionMask.for_workspace(("grasp", "left_slide"), ws)
    maps, plain_maps = fit.pixel_masks(block)[0], plain.pixel_masks(block)[0]
    assert not maps[0].any() and torch.equal(maps[1], plain_maps[1]) and maps[1].any()  # only slides are left
    grasps_only = dataclasses.replace(fit, enabled=("grasp",)).pixel_masks(block)[0]
    assert torch.equal(grasps_only[0], plain_maps[0]) and plain_maps[0].any()  # ... or, with none, every grasp on material
    with pytest.raises(ValueError, match="min_height"):
        HeightmapActionMask(("grasp",), 4, min_height=None, grasp_fit=True)


def heightmap_td(b: int) -> TensorDict:
    return TensorDict(color_heightmap=torch.zeros(b, H, W, 3, dtype=torch.uint8), depth_heightmap=block_height(b),
                      batch_size=[b])


def test_greedy_and_random_actions_stay_in_the_mask():
    layout = PixelActionLayout(1, R, H, W)
    maps = torch.zeros(1, *layout.shape)
    maps[0, 0, 0, 7, 7] = 10.0  # the unmasked maximum lies on bare table
    maps[0, 0, 1, 3, 5] = 1.0  # the best grasp on the block
    mask = HeightmapActionMask(("grasp",), R)
    spec = Categorical(layout.size, shape=(32,))
    greedy, explore, _ = make_pixel_policy(FixedMaps(maps), spec, eps_init=1.0, eps_end=1.0, annealing_num_steps=1,
                                           action_mask=mask)
    out = greedy(heightmap_td(32))
    assert layout.decode(int(out["action"][0])) == (0, 1, 3, 5)
    with set_exploration_type(ExplorationType.RANDOM):
        actions = explore(heightmap_td(32))["action"]
    allowed = mask(block_height(1))[0]
    assert allowed[actions].all()
    assert len(set(actions.tolist())) > 4  # random, not the greedy action repeated


def explore_actions(weights, b: int = 600) -> tuple[torch.Tensor, torch.Tensor]:
    """``b`` ε = 1 actions of a 3-primitive actor under the block mask with ``explore_weights``, and the mask."""
    layout = PixelActionLayout(3, R, H, W)
    mask = HeightmapActionMask(("grasp", "left_slide", "right_slide"), R, slide_clear_px=0, slide_ahead_px=2)
    _, explore, _ = make_pixel_policy(FixedMaps(torch.zeros(1, *layout.shape)), Categorical(layout.size, shape=(b,)),
                                      eps_init=1.0, eps_end=1.0, annealing_num_steps=1, action_mask=mask,
                                      explore_weights=weights)
    with set_exploration_type(ExplorationType.RANDOM):
        actions = explore(heightmap_td(b))["action"]
    return actions, mask(block_height(1))[0]


def test_explore_weights_set_each_primitives_share_of_random_actions():
    torch.manual_seed(0)
    _, allowed = explore_actions(None, 1)
    per_primitive = allowed.reshape(3, -1).sum(-1)
    assert per_primitive[1:].sum() > per_primitive[0]  # uniform draws would mostly slide on this block
    for weights, primitive in (((1.0, 0.0, 0.0), 0), ((0.0, 0.0, 3.0), 2)):
        actions, allowed = explore_actions(weights)
        assert allowed[actions].all()
        assert (actions // (R * H * W) == primitive).all()
    actions, allowed = explore_actions((2.0, 1.0, 1.0))
    assert allowed[actions].all()
    share = torch.bincount(actions // (R * H * W), minlength=3).float() / len(actions)
    torch.testing.assert_close(share, torch.tensor([0.5, 0.25, 0.25]), atol=0.06, rtol=0)
    assert len(set(actions.tolist())) > 20  # uniform within each primitive, not one pixel per primitive


def test_explore_weights_fall_back_to_the_whole_mask_when_their_primitives_have_no_allowed_action():
    layout = PixelActionLayout(3, R, H, W)
    values = torch.zeros(4, layout.size)
    mask = torch.zeros(4, layout.size, dtype=torch.bool)
    mask[:, layout.size - 5:] = True  # right slides only
    out = PrimitiveExploreMask((1.0, 1.0, 0.0))(values, mask)
    assert torch.equal(out, mask)


@pytest.mark.parametrize("weights", [(), (-1.0, 1.0), (0.0, 0.0), (float("nan"), 1.0)])
def test_bad_explore_weights_raise(weights):
    with pytest.raises(ValueError, match="explore weights"):
        PrimitiveExploreMask(weights)


def test_bootstrap_maximises_over_allowed_actions_only():
    layout = PixelActionLayout(1, R, H, W)
    maps = torch.zeros(1, *layout.shape)
    maps[0, 0, 1, 0, 0] = 5.0  # bare table
    maps[0, 0, 0, 2, 6] = 0.7  # on the block
    obs = torch.cat([torch.zeros(2, 3, H, W), block_height(2).unsqueeze(1)], dim=1)
    net = FixedMaps(maps)
    masked = PixelDQNLoss(net, gamma=0.5, delay_value=False, action_mask=HeightmapActionMask(("grasp",), R).from_observation)
    plain = PixelDQNLoss(net, gamma=0.5, delay_value=False)
    torch.testing.assert_close(masked.bootstrap(obs), torch.full((2,), 0.7))
    torch.testing.assert_close(plain.bootstrap(obs), torch.full((2,), 5.0))


def test_enabled_restricts_to_grasps_and_no_material_test_allows_all_pixels():
    layout = PixelActionLayout(3, R, H, W)
    prims = ("grasp", "left_slide", "right_slide")
    grasps = HeightmapActionMask(prims, R, enabled=("grasp",))(block_height()).reshape(layout.shape)
    assert grasps[1:].sum() == 0 and torch.equal(grasps[0, 0], block_height()[0] > 0.01)
    anywhere = HeightmapActionMask(prims, R, min_height=None, enabled=("grasp",))(block_height()).reshape(layout.shape)
    assert anywhere[0].all() and anywhere[1:].sum() == 0
    empty = HeightmapActionMask(prims, R, enabled=("grasp",))(torch.zeros(1, H, W)).reshape(layout.shape)
    assert empty[0].all() and empty[1:].sum() == 0
    with pytest.raises(ValueError):
        HeightmapActionMask(prims, R, enabled=("push",))


def test_slide_margin_keeps_a_grasp_unless_a_slide_beats_it_by_more():
    layout = PixelActionLayout(3, R, H, W)
    maps = torch.zeros(1, *layout.shape)
    maps[0, 0, 1, 3, 5] = 0.6  # the best grasp
    maps[0, 2, 0, 2, 2] = 0.8  # a slide 0.2 above it
    greedy = lambda margins: make_pixel_policy(FixedMaps(maps), Categorical(layout.size, shape=(1,)), eps_init=0.0,  # noqa: E731
                                               eps_end=0.0, annealing_num_steps=1, primitive_margins=margins)[0]
    for margins, chosen in ((None, (2, 0, 2, 2)), ((0.0, 0.1, 0.1), (2, 0, 2, 2)), ((0.0, 0.3, 0.3), (0, 1, 3, 5))):
        out = greedy(margins)(heightmap_td(1))
        assert layout.decode(int(out["action"][0])) == chosen
        torch.testing.assert_close(out["action_value"], maps.reshape(1, -1))  # the values stay the network's


@pytest.mark.parametrize("margins", [(0.0, float("inf")), ((0.0,),)])
def test_bad_primitive_margins_raise(margins):
    with pytest.raises(ValueError, match="primitive margins"):
        GreedyPixelActor(nn.Identity(), primitive_margins=margins)


def _turned_bar(scale: int, yaw_deg: float, size: int = 32, px: float = 0.007) -> torch.Tensor:
    """Heights ``(1, scale·size, scale·size)``: a 6 x 2 cm bar, 3 cm tall, centred on heightmap pixel (16, 16), its
    long side turned ``yaw_deg`` from the y axis; a fine pixel is material where its centre lies on the bar."""
    q = px / scale
    centres = (torch.arange(scale * size, dtype=torch.float64) + 0.5) * q
    ys, xs = torch.meshgrid(centres, centres, indexing="ij")
    a = math.radians(yaw_deg)
    dx, dy = xs - 16.5 * px, ys - 16.5 * px
    across, along = dx * math.cos(a) + dy * math.sin(a), -dx * math.sin(a) + dy * math.cos(a)
    return ((across.abs() <= 0.01) & (along.abs() <= 0.03)).float()[None] * 0.03


def test_fit_heightmap_rejects_a_bar_turned_out_of_the_friction_cone_that_7_mm_pixels_pass():
    """Jaws closing along x on a bar turned 30 degrees: its faces lie outside the pads' friction cone (17 degrees), but
    on 7 mm pixels the slope across the 1.75 cm pads is within a pixel's slack. The 3.5 mm fit heightmap sees it; both
    pass the bar square to the jaws. The camera's 7 mm map is the fine one max-pooled."""
    from maniskill_pnp.cell.workspace import WorkspaceSpec

    mask = HeightmapActionMask.for_workspace(("grasp",), WorkspaceSpec(heightmap_size=32, pixel_size=0.007, num_rotations=4),
                                             grasp_fit=True)
    for yaw, square in ((0.0, True), (30.0, False)):
        fine = _turned_bar(4, yaw)
        height = F.max_pool2d(fine[:, None], 4)[:, 0]
        at = torch.zeros_like(height, dtype=torch.bool)
        at[0, 16, 16] = True
        coarse = mask.grasp_fits(height, at)[0, 0, 16, 16]
        fit = mask.grasp_fits(height, at, F.max_pool2d(fine[:, None], 2)[:, 0])[0, 0, 16, 16]
        assert bool(coarse) and bool(fit) == square
    with pytest.raises(ValueError, match="fit heightmap"):
        mask.grasp_fits(height, at, torch.zeros(1, 48, 40))


def test_actor_and_bootstrap_read_the_fit_heightmap():
    """A G&S actor over the 30-degree bar: on the 7 mm map its best action is the grasp at the bar's centre; with the
    fit heightmap that grasp is masked out, for the actor and for the loss's bootstrap (from ("next", fit_heightmap))."""
    from maniskill_pnp.cell.workspace import WorkspaceSpec

    prims = ("grasp", "left_slide", "right_slide")
    layout = PixelActionLayout(3, 4, 32, 32)
    mask = HeightmapActionMask.for_workspace(prims, WorkspaceSpec(heightmap_size=32, pixel_size=0.007, num_rotations=4),
                                             grasp_fit=True)
    fine = F.max_pool2d(_turned_bar(4, 30.0)[:, None], 2)[:, 0]
    height = F.max_pool2d(fine[:, None], 2)[:, 0]
    maps = torch.zeros(1, *layout.shape)
    maps[0, 0, 0, 16, 16] = 2.0
    best = layout.encode(0, 0, 16, 16)
    actor = GreedyPixelActor(FixedMaps(maps), mask)
    color = torch.zeros(1, 32, 32, 3, dtype=torch.uint8)
    assert int(actor(color, height)[1]) == best and int(actor(color, height, fine)[1]) != best
    obs = torch.cat([torch.zeros(1, 3, 32, 32), height[:, None]], dim=1)
    loss = PixelDQNLoss(FixedMaps(maps), gamma=1.0, delay_value=False, action_mask=mask.from_observation)
    assert float(loss.bootstrap(obs)) == 2.0 and float(loss.bootstrap(obs, fine)) < 2.0
    batch = TensorDict({"observation": obs, "action": torch.tensor([best]),
                        "next": {"observation": obs, "reward": torch.zeros(1), "terminated": torch.zeros(1, dtype=torch.bool),
                                 "done": torch.zeros(1, dtype=torch.bool), "fit_heightmap": fine.half()}}, batch_size=[1])
    loss(batch)
    torch.testing.assert_close(batch["td_error"], (2.0 - loss.bootstrap(obs, fine)).abs())


# ---------------------------------------------------------------------------------------------- slides kept in
def keep_in_reference(occupied: torch.Tensor, steps: torch.Tensor, band: torch.Tensor, length: int, b: int,
                      row: int, col: int) -> bool:
    """The keep-in judgement of one slide start, step by step in plain Python: the pusher meets material at its first
    step t0 <= length, carries it length - t0 on, and every empty step past t0 uses up one step of that push; each
    material step still reached adds one step to where the carried material ends (length + carried)."""
    h, w = occupied.shape
    lines = band.nonzero().tolist()

    def material(r: int, c: int) -> bool:
        return any(0 <= r + dr - b < h and 0 <= c + dc - b < w and bool(occupied[r + dr - b, c + dc - b])
                   for dr, dc in lines)

    met, off = [], len(steps) + 1
    for t, (dr, dc) in enumerate(steps.tolist(), start=1):
        r, c = row + dr, col + dc
        if not (0 <= r < h and 0 <= c < w):
            off = min(off, t)
            met.append(False)
        else:
            met.append(material(r, c))
    if not any(met[:length]):
        return True
    t0 = met.index(True) + 1
    left, carried = length - t0, 0
    for t in range(t0 + 1, len(met) + 1):
        if met[t - 1]:
            carried += 1
        else:
            left -= 1
            if left <= 0:
                break
    return length + carried < off


def test_keep_in_matches_a_step_by_step_reading_of_the_push():
    ws = WorkspaceSpec(heightmap_size=24, pixel_size=0.448 / 24, num_rotations=8)
    mask = HeightmapActionMask.for_workspace(("grasp", "left_slide", "right_slide"), ws, keep_in=True)
    gen = torch.Generator().manual_seed(0)
    occupied = torch.rand(24, 24, generator=gen) > 0.85
    band, steps = mask._push_rays
    everywhere = torch.ones(1, 8, 24, 24, dtype=torch.bool)
    for side in ("left", "right"):
        keep = mask.slides_keep_in(occupied[None, None], side, everywhere)[0]
        for rot in range(8):
            for row in range(0, 24, 3):
                for col in range(0, 24, 3):
                    want = keep_in_reference(occupied, steps[side][rot], band[rot, 0], mask.slide_length_px,
                                             mask.slide_band_px, row, col)
                    assert bool(keep[rot, row, col]) == want, (side, rot, row, col)
    assert not keep.all() and keep.any()


def test_keep_in_masks_pushes_that_carry_a_block_off_the_heightmap():
    """A 5x7 px block pushed towards the right edge (+x, the right slide of rotation 4 of 16) from 5 px before it: the
    slide's 11 px carry it 6 px on. With 7 px to spare it stays on the map; with 3 px it would leave, and only the
    keep-in test masks that slide. Pushing it the other way stays allowed."""
    ws = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=16)
    primitives = ("grasp", "left_slide", "right_slide")
    keep_in = HeightmapActionMask.for_workspace(primitives, ws, keep_in=True)
    plain = HeightmapActionMask.for_workspace(primitives, ws)
    assert (keep_in.slide_length_px, keep_in.slide_band_px) == (11, 3)
    for first_col, stays in ((50, True), (54, False)):
        h = torch.zeros(1, 64, 64)
        h[0, 30:35, first_col:first_col + 7] = 0.03
        row, col = 32, first_col - 5
        assert plain.pixel_masks(h)[0, 2, 4, row, col]
        assert bool(keep_in.pixel_masks(h)[0, 2, 4, row, col]) == stays
        assert keep_in.pixel_masks(h)[0, 1, 4, row, first_col + 9]  # the left slide pushes it back in


def test_keep_in_carries_what_the_push_reaches_across_a_gap():
    """Blocks 3 px long pushed towards the bottom edge (+y, the left slide of rotation 0) from row 49: the pusher meets
    the first at step 2 and carries it 9 px on, its front ending at step 11 + 2 (row 62), on the map. A second block 2
    px behind it is reached (the push closes the gap) and carried too: the front then ends at step 16, off the map. A
    second block 9 px behind is out of the push's reach."""
    ws = WorkspaceSpec(heightmap_size=64, pixel_size=0.448 / 64, num_rotations=16)
    mask = HeightmapActionMask.for_workspace(("grasp", "left_slide", "right_slide"), ws, keep_in=True)
    start = 49
    for gap, stays in ((None, True), (2, False), (9, True)):
        h = torch.zeros(1, 64, 64)
        h[0, start + 2:start + 5, 20:23] = 0.03
        if gap is not None:
            h[0, start + 5 + gap:start + 8 + gap, 20:23] = 0.03
        where = torch.zeros(1, 16, 64, 64, dtype=torch.bool)
        where[0, 0, start, 21] = True
        assert bool(mask.slides_keep_in((h > 0.01)[:, None], "left", where)[0, 0, start, 21]) == stays, gap


def test_bad_keep_in_options_raise():
    with pytest.raises(ValueError, match="slide_length_px"):
        HeightmapActionMask(("grasp", "left_slide"), 4, slide_length_px=0)
    with pytest.raises(ValueError, match="slide_band_px"):
        HeightmapActionMask(("grasp", "left_slide"), 4, slide_length_px=5, slide_band_px=-1)
