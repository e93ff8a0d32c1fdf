"""Workspace geometry, the pixel action index and RGB-D heightmaps (a box of known size at a known pose)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch

from maniskill_pnp.scenes.clutter import validate_layout
from maniskill_pnp.scenes.objects import ObjectSpec
from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.cell.workspace import WorkspaceSpec

WS = WorkspaceSpec()
LAYOUT = PixelActionLayout(1, WS.num_rotations, WS.heightmap_size, WS.heightmap_size)


def test_workspace_defaults_and_pixel_world_round_trip():
    assert WS.heightmap_size == 224 and WS.pixel_size == 0.002 and WS.num_rotations == 16
    assert WS.side == pytest.approx(0.448)
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, 224, 100), rng.integers(0, 224, 100)
    xyz = WS.pixel_to_world(rows, cols, 0.01)
    assert xyz.shape == (100, 3) and np.allclose(xyz[:, 2], WS.table_z + 0.01)
    r, c = WS.world_to_pixel(xyz)
    assert (r == rows).all() and (c == cols).all()
    tr, tc = WS.world_to_pixel(torch.as_tensor(WS.pixel_to_world(torch.as_tensor(rows), torch.as_tensor(cols), 0.0)))
    assert (tr.numpy() == rows).all() and (tc.numpy() == cols).all()
    assert WS.world_to_pixel(np.array([5.0, 5.0, 0.0])) == (-1, -1)
    assert WS.rotation_to_yaw(4) == pytest.approx(np.pi / 2)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(num_rotations=7), "num_rotations"),
        (dict(num_rotations=0), "num_rotations"),
        (dict(heightmap_size=0), "heightmap_size"),
        (dict(pixel_size=0.0), "pixel_size"),
        (dict(max_height=-1.0), "max_height"),
    ],
)
def test_workspace_rejects_bad_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        WorkspaceSpec(**kwargs)


def test_encode_decode_round_trip_vectorized():
    g = torch.Generator().manual_seed(0)
    idx = torch.randint(0, LAYOUT.size, (1000,), generator=g)
    p, r, i, j = LAYOUT.decode(idx)
    assert (LAYOUT.encode(p, r, i, j) == idx).all()
    assert int(r.max()) < 16 and int(i.max()) < 224 and int(j.max()) < 224
    npidx = idx.numpy()
    assert (LAYOUT.encode(*LAYOUT.decode(npidx)) == npidx).all()
    assert LAYOUT.decode(LAYOUT.encode(0, 15, 223, 223)) == (0, 15, 223, 223)
    assert LAYOUT.encode(0, 1, 0, 0) == 224 * 224
    # Matches the flat index of a (primitives, rotations, H, W) Q-value tensor.
    q = torch.zeros(LAYOUT.shape)
    q[0, 3, 10, 20] = 1.0
    assert int(q.argmax()) == LAYOUT.encode(0, 3, 10, 20)


@pytest.mark.parametrize("bad", [-1, LAYOUT.size, 1.0, float("nan"), True, np.array([0.5]), torch.tensor([-3, 0])])
def test_decode_rejects_bad_indices(bad):
    with pytest.raises(ValueError, match="0..|integer"):
        LAYOUT.decode(bad)


def test_encode_rejects_out_of_range_parts():
    with pytest.raises(ValueError, match="rotation out of range"):
        LAYOUT.encode(0, 16, 0, 0)
    with pytest.raises(ValueError, match="col"):
        LAYOUT.encode(0, 0, 0, np.array([0, 224]))
    with pytest.raises(ValueError, match="row must be an integer"):
        LAYOUT.encode(0, 0, 1.5, 0)


def test_layout_validation():
    cube = ObjectSpec("cuboid", (0.02, 0.02, 0.02))
    cx, cy = WS.center
    with pytest.raises(ValueError, match="overlap"):
        validate_layout([(cube, (cx, cy, 0.02)), (cube, (cx + 0.03, cy, 0.02))], WS)
    with pytest.raises(ValueError, match="not wholly over the workspace"):
        validate_layout([(cube, (cx + 0.3, cy, 0.02))], WS)
    with pytest.raises(ValueError, match="at least one"):
        validate_layout([], WS)
    ok = validate_layout([(cube, (cx, cy, 0.02)), (cube, (cx + 0.041, cy, 0.02))], WS)
    assert len(ok) == 2 and isinstance(ok[0][1], sapien.Pose)


def test_object_specs_are_checked():
    with pytest.raises(ValueError, match="unknown object kind"):
        ObjectSpec("torus", (0.01,))
    with pytest.raises(ValueError, match="at least"):
        ObjectSpec("cuboid", (0.02, 0.02, 0.005))
    with pytest.raises(ValueError, match="gripper"):
        ObjectSpec("cuboid", (0.05, 0.05, 0.02))


BOX = ObjectSpec("cuboid", (0.03, 0.015, 0.025), color=(0.1, 0.2, 0.9))  # 6 x 3 x 5 cm
BOX_XY = (WS.center[0] + 0.04, WS.center[1] - 0.05)
BOX_YAW = 0.0


@pytest.fixture(scope="module")
def box_env():
    """ClutterGrasp-v1 whose only object is BOX, placed by an explicit layout."""
    q = [np.cos(BOX_YAW / 2), 0.0, 0.0, np.sin(BOX_YAW / 2)]
    env = gym.make(
        "ClutterGrasp-v1", layout=[(BOX, (*BOX_XY, BOX.extents[2] / 2, *q))], sim_backend="physx_cpu", render_backend="cpu"
    )
    yield env
    env.close()


def test_heightmap_of_a_known_box(box_env):
    """One 6 x 3 x 5 cm box: height within 3 mm and footprint within 2 px, from both fused cameras."""
    obs, _ = box_env.reset(seed=0)
    h = obs["depth_heightmap"][0].numpy()
    assert h.shape == (224, 224) and h.dtype == np.float32
    assert obs["color_heightmap"].shape == (1, 224, 224, 3) and obs["color_heightmap"].dtype == torch.uint8
    mask = h > 0.01
    rows, cols = np.nonzero(mask)
    assert np.median(h[mask]) == pytest.approx(0.05, abs=0.003)
    assert np.abs(h[~mask]).max() < 0.003  # the table is flat at 0
    # Footprint: 60 mm along x (cols) = 30 px, 30 mm along y (rows) = 15 px, centred on the box.
    assert abs((cols.max() - cols.min() + 1) - 30) <= 2 and abs((rows.max() - rows.min() + 1) - 15) <= 2
    r0, c0 = box_env.unwrapped.workspace.world_to_pixel(np.array(BOX_XY))
    assert abs(rows.mean() - (r0 + 0.5)) <= 2 and abs(cols.mean() - (c0 + 0.5)) <= 2
    # The box's colour (blue) is seen on top of it.
    rgb = obs["color_heightmap"][0].numpy()[mask].astype(float).mean(0)
    assert rgb[2] > rgb[0] + 30


def test_projection_keeps_the_highest_point_and_the_colour_of_the_last_one_at_that_height():
    """Per pixel the highest point wins; among points at that height the last one's colour (the same for every batch
    entry); points outside the grid, too high or not valid are dropped; pixels no point reached stay unfilled."""
    from maniskill_pnp.cell.heightmap import project_heightmap

    ws = WorkspaceSpec(heightmap_size=4, pixel_size=0.1, center=(0.0, 0.0))
    x0, y0 = ws.bounds[0, 0], ws.bounds[1, 0]
    z = ws.table_z
    pts = torch.tensor([[x0 + 0.05, y0 + 0.05, z + 0.02], [x0 + 0.05, y0 + 0.05, z + 0.03],  # pixel (0, 0): 3 cm
                        [x0 + 0.06, y0 + 0.04, z + 0.03], [x0 + 0.35, y0 + 0.15, z + 0.01],  # a tie; pixel (1, 3)
                        [x0 + 0.35, y0 + 0.15, z + 0.5], [x0 - 0.05, y0 + 0.05, z + 0.1],  # too high; off the grid
                        [x0 + 0.15, y0 + 0.25, z + 0.04]], dtype=torch.float32)  # not valid
    colors = torch.arange(21, dtype=torch.uint8).reshape(7, 3)
    valid = torch.tensor([True] * 6 + [False])
    height, color, filled = project_heightmap(pts.expand(2, -1, -1), colors.expand(2, -1, -1), valid.expand(2, -1), ws)
    for b in range(2):
        assert filled[b].sum() == 2 and filled[b, 0, 0] and filled[b, 1, 3]
        assert height[b, 0, 0].item() == pytest.approx(0.03, abs=1e-6) and height[b, 1, 3].item() == pytest.approx(0.01, abs=1e-6)
        assert color[b, 0, 0].tolist() == [6.0, 7.0, 8.0] and color[b, 1, 3].tolist() == [9.0, 10.0, 11.0]
        assert height[b][~filled[b]].eq(0).all() and color[b][~filled[b]].eq(0).all()


def test_workspace_fit_grid_and_bad_fit_scales():
    ws = WorkspaceSpec(heightmap_size=64, pixel_size=0.007, fit_scale=2)
    grid = ws.fit_grid
    assert (grid.heightmap_size, grid.pixel_size, grid.fit_scale) == (128, 0.0035, 1)
    assert np.array_equal(grid.bounds, ws.bounds) and grid.cameras == ws.cameras
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="fit_scale"):
            WorkspaceSpec(fit_scale=bad)


@pytest.fixture(scope="module")
def fit_box_env():
    """BOX on a 64 px heightmap (7 mm pixels) that also observes the fit heightmap (3.5 mm) and the raw cameras."""
    q = [np.cos(BOX_YAW / 2), 0.0, 0.0, np.sin(BOX_YAW / 2)]
    env = gym.make("ClutterGrasp-v1", layout=[(BOX, (*BOX_XY, BOX.extents[2] / 2, *q))], sim_backend="physx_cpu",
                   render_backend="cpu", workspace=WorkspaceSpec(heightmap_size=64, pixel_size=0.007, fit_scale=2),
                   include_camera_data=True)
    yield env
    env.close()


def test_fit_heightmap_is_the_same_points_on_a_finer_grid(fit_box_env):
    """The env observes the fit heightmap (its space says so); without hole filling, the highest point of each
    heightmap pixel is the highest of its 2 x 2 fit pixels, exactly; the box is 60 x 30 mm and 5 cm tall on it."""
    from maniskill_pnp.cell.heightmap import heightmaps_from_sensors

    obs, _ = fit_box_env.reset(seed=0)
    fit = obs["fit_heightmap"]
    assert fit.shape == (1, 128, 128) and fit.dtype == torch.float32
    assert fit_box_env.unwrapped.single_observation_space["fit_heightmap"].shape == (128, 128)
    assert fit_box_env.unwrapped.observation_space["fit_heightmap"].shape == (1, 128, 128)
    ws = fit_box_env.unwrapped.workspace
    color, height, fine = heightmaps_from_sensors(obs["sensor_data"], obs["sensor_param"], ws, fill_passes=0, fit=True)
    assert torch.equal(torch.nn.functional.max_pool2d(fine[:, None], 2)[:, 0], height)
    h = fit[0].numpy()
    top = h > 0.01
    rows, cols = np.nonzero(top)
    assert np.median(h[top]) == pytest.approx(0.05, abs=0.003)
    assert abs((cols.max() - cols.min() + 1) - 60 / 3.5) <= 2 and abs((rows.max() - rows.min() + 1) - 30 / 3.5) <= 2
