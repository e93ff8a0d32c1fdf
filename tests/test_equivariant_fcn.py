"""The rotation-equivariant pixel Q network (backbone "equivariant"): its rotation convention against the workspace's
axes, exact 90-degree equivariance, the grasp's 180-degree symmetry, its use through MultiPrimitiveQNetwork, the DQN
loss and the replay, the presets, and a tiny training run through the recipe (tiny sizes, CPU)."""

from __future__ import annotations

import copy
import io
import json
import math
import pickle
import subprocess
import sys

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.objectives import HardUpdate

from maniskill_pnp.agents.pixel.checkpoint import load_checkpoint
from maniskill_pnp.agents.pixel.config import ClutterConfig
from maniskill_pnp.agents.pixel.equivariant import EquivariantPixelQNetwork
from maniskill_pnp.agents.pixel.factories import load_policy, make_model
from maniskill_pnp.agents.pixel.fcn import MultiPrimitiveQNetwork, PixelQNetwork
from maniskill_pnp.agents.pixel.loss import PixelDQNLoss
from maniskill_pnp.agents.pixel.replay import make_pixel_replay, pack_transition, unpack_transition
from maniskill_pnp.cell.pixel_action import PixelActionLayout
from maniskill_pnp.cell.workspace import WorkspaceSpec

H = W = 32
R = 8
GS = ("grasp", "left_slide", "right_slide")

#: ``torch.rot90(x, 1, dims=(-2, -1))`` turns the scene by -90 degrees about world z (col = +x, row = +y; derived
#: from the workspace's axes in the first test), so a grasp of yaw ``theta`` becomes one of yaw ``theta - 90``: the
#: rotation index moves by -R/4, and the maps of the turned heightmap are ``roll(rot90(q), -R/4)`` over the rotations.
QUARTER_TURNS_OF_ROT90 = -1


def turn(x: torch.Tensor) -> torch.Tensor:
    """The heightmap (or maps) turned by ``torch.rot90`` on its last two (row, col) dims."""
    return torch.rot90(x, 1, dims=(-2, -1))


def expected_maps_of_turned(q: torch.Tensor, num_rotations: int, rotation_dim: int = -3) -> torch.Tensor:
    """The Q maps of the turned heightmap, from the maps ``q`` of the original one."""
    return torch.roll(turn(q), QUARTER_TURNS_OF_ROT90 * num_rotations // 4, dims=rotation_dim)


def heightmaps(b: int, seed: int, size: int = H) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(b, 3, size, size, generator=g)
    height = 0.1 * torch.rand(b, 1, size, size, generator=g)
    return torch.cat([rgb, height], dim=1)


def transitions(b: int, layout: PixelActionLayout, actions, *, seed: int) -> TensorDict:
    done = torch.tensor([False, True, False, False][:b]).unsqueeze(-1)
    return TensorDict(
        {
            "observation": heightmaps(b, seed, layout.height),
            "action": torch.tensor(actions),
            "next": {"observation": heightmaps(b, seed + 1, layout.height), "reward": torch.tensor([1.0, 0.5, 0.0, 0.8][:b]).unsqueeze(-1),
                     "terminated": done, "done": done},
        },
        batch_size=[b],
    )


# ---------------------------------------------------------------------------------------------------- convention
def test_rot90_of_the_heightmap_turns_the_world_by_minus_90_degrees_and_the_rotation_index_by_minus_r_over_4():
    """Derive the index shift from WorkspaceSpec itself: where rot90 sends a pixel, in world coordinates, and what
    that turn does to a grasp's jaw direction and to a slide's push direction."""
    ws = WorkspaceSpec(heightmap_size=8, pixel_size=0.05, num_rotations=R)
    index = torch.arange(64).reshape(8, 8)
    centre = np.asarray(ws.center)
    angles = []
    for row, col in [(1, 6), (0, 0), (5, 2), (7, 3)]:
        new_row, new_col = (int(v) for v in (turn(index) == index[row, col]).nonzero()[0])
        p = ws.pixel_to_world(row, col, 0.0)[:2] - centre
        q = ws.pixel_to_world(new_row, new_col, 0.0)[:2] - centre
        assert np.isclose(np.linalg.norm(p), np.linalg.norm(q))
        angles.append(math.atan2(p[0] * q[1] - p[1] * q[0], p @ q))
    np.testing.assert_allclose(angles, -math.pi / 2)  # the scene turns by -90 degrees about world z
    turn_by = lambda v: np.array([[0.0, 1.0], [-1.0, 0.0]]) @ v  # noqa: E731  (rotation by -90 degrees)
    shift = QUARTER_TURNS_OF_ROT90 * R // 4
    for r in range(R):
        yaw = ws.rotation_to_yaw(r)
        jaw = np.array([math.cos(yaw), math.sin(yaw)])
        turned_yaw = ws.rotation_to_yaw((r + shift) % R)
        np.testing.assert_allclose(turn_by(jaw), [math.cos(turned_yaw), math.sin(turned_yaw)], atol=1e-12)
        for side in ("left", "right"):
            np.testing.assert_allclose(turn_by(ws.slide_direction(r, side)), ws.slide_direction((r + shift) % R, side),
                                       atol=1e-12)


def test_the_rotated_trunk_network_follows_the_same_convention():
    """The reference: PixelQNetwork (rotated copies) has the same index shift, with a small trunk and R = 4."""
    torch.manual_seed(0)
    net = PixelQNetwork(num_rotations=4, backbone="small").eval()
    x = heightmaps(1, 3)
    with torch.no_grad():
        q, q_turned = net(x), net(turn(x))
    torch.testing.assert_close(q_turned, expected_maps_of_turned(q, 4), atol=1e-4 * q.abs().max(), rtol=1e-4)


# ---------------------------------------------------------------------------------------------------- equivariance
@pytest.mark.parametrize("size", [32, 30])  # sides of 0 and 2 mod 4: symmetric padding, exact 90-degree turns
@pytest.mark.parametrize("symmetric", [False, True])
@pytest.mark.parametrize("num_rotations", [8, 16])
def test_turning_the_heightmap_turns_every_map_and_shifts_the_rotation_index(size, symmetric, num_rotations):
    torch.manual_seed(1)
    net = EquivariantPixelQNetwork(num_rotations=num_rotations, symmetric=symmetric).eval()
    x = heightmaps(2, 4, size)
    with torch.no_grad():
        q, q_turned = net(x), net(turn(x))
    assert q.shape == (2, num_rotations, size, size)
    scale = q.abs().max()
    assert (q[:, 0] - q[:, 1]).abs().max() > 1e-2 * scale  # the rotation maps differ: the check has teeth
    torch.testing.assert_close(q_turned, expected_maps_of_turned(q, num_rotations), atol=1e-5 * scale, rtol=1e-5)
    twice = net(turn(turn(x))).detach()
    torch.testing.assert_close(twice, expected_maps_of_turned(expected_maps_of_turned(q, num_rotations), num_rotations),
                               atol=1e-5 * scale, rtol=1e-5)
    if not symmetric:  # the other direction is wrong (for the grasp it is the same map: r + R/2 is tied to r)
        wrong = torch.roll(turn(q), num_rotations // 4, dims=-3)
        assert (q_turned - wrong).abs().max() > 1e-2 * scale


def test_equivariance_holds_in_train_mode_and_through_the_multi_primitive_network():
    """BatchNorm's batch statistics are per field (over all of its rotation channels), so train mode keeps it."""
    torch.manual_seed(2)
    net = MultiPrimitiveQNetwork(GS, num_rotations=R, backbone="equivariant").train()
    x = heightmaps(2, 5)
    with torch.no_grad():
        q, q_turned = net(x), net(turn(x))
    assert q.shape == (2, 3, R, H, W)
    torch.testing.assert_close(q_turned, expected_maps_of_turned(q, R), atol=1e-5 * q.abs().max(), rtol=1e-5)


def test_grasp_maps_of_opposite_jaws_are_equal_and_slide_maps_are_not():
    torch.manual_seed(3)
    net = MultiPrimitiveQNetwork(GS, num_rotations=R, backbone="equivariant").eval()
    assert [net.nets[p].symmetric for p in GS] == [True, False, False]
    with torch.no_grad():
        q = net(heightmaps(2, 6))
    grasp, left, right = q[:, 0], q[:, 1], q[:, 2]
    assert torch.equal(grasp[:, : R // 2], grasp[:, R // 2 :])
    for slide in (left, right):
        assert (slide[:, : R // 2] - slide[:, R // 2 :]).abs().amax(dim=(-2, -1)).min() > 1e-3 * slide.abs().max()


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="num_rotations >= 2"):
        EquivariantPixelQNetwork(num_rotations=1)
    with pytest.raises(ValueError, match="no pretrained weights"):
        MultiPrimitiveQNetwork(("grasp",), num_rotations=R, backbone="equivariant", pretrained_path="/some/weights.pth")
    with pytest.raises(ValueError, match="equivariant"):
        MultiPrimitiveQNetwork(("grasp",), num_rotations=R, backbone="vgg")
    with pytest.raises(ValueError, match="RGB"):
        EquivariantPixelQNetwork(num_rotations=R)(torch.zeros(1, 3, H, W))
    with pytest.raises(ValueError, match="equivariant backbone"):
        ClutterConfig.from_preset("cpu-equi", num_rotations=1)
    with pytest.raises(ValueError, match="equivariant backbone"):
        ClutterConfig.from_preset("cpu-equi", pretrained_path="/some/weights.pth")


def test_colour_only_network_ignores_the_height_channel():
    torch.manual_seed(4)
    net = EquivariantPixelQNetwork(num_rotations=4, use_depth=False).eval()
    x = heightmaps(1, 7)
    y = x.clone()
    y[:, 3] = 0.5
    with torch.no_grad():
        assert torch.equal(net(x), net(y))


# ---------------------------------------------------------------------------------------------------- the weights
def test_eval_mode_follows_the_weights_and_the_state_dict_round_trips():
    """No filter is cached in eval mode: an in-place update, a functional parameter swap (the loss's target network)
    and load_state_dict all change what the network computes; the state_dict holds weights and BN statistics only,
    and a pickled or deep-copied network computes the same maps."""
    from tensordict import TensorDict as TD

    torch.manual_seed(5)
    net = MultiPrimitiveQNetwork(GS[:2], num_rotations=R, backbone="equivariant").eval()
    x = heightmaps(1, 8)
    with torch.no_grad():
        before = net(x)
        state = copy.deepcopy(net.state_dict())
        assert all(k.split(".")[-1] in ("weights", "bias", "weight", "running_mean", "running_var", "num_batches_tracked")
                   for k in state)
        halved = TD.from_module(net).named_apply(lambda key, t: t * 0.5 if key == "weights" else t)
        with halved.to_module(net):
            assert not torch.allclose(net(x), before)
        torch.testing.assert_close(net(x), before)
        net.nets["grasp"].head.weights.add_(1.0)
        assert not torch.allclose(net(x), before)
        net.load_state_dict(state)
        torch.testing.assert_close(net(x), before)
        buffer = io.BytesIO()
        torch.save(net.state_dict(), buffer)
        buffer.seek(0)
        fresh = MultiPrimitiveQNetwork(GS[:2], num_rotations=R, backbone="equivariant")
        fresh.load_state_dict(torch.load(buffer, weights_only=True))
        torch.testing.assert_close(fresh.eval()(x), before)
        for clone in (pickle.loads(pickle.dumps(net)), copy.deepcopy(net)):
            assert not clone.training and not clone.nets["grasp"].training
            torch.testing.assert_close(clone(x), before)


def test_parameters_swap_in_as_meta_copies_as_a_collector_worker_does():
    """TorchRL's weight sync swaps the policy's parameters into a worker's copy with ``TensorDict.to_module``, meta
    copies included. e2cnn's basis expansions of two layers with equal field types hash alike and compare by content
    (which raises on meta tensors); the network's expansions compare by identity, so the swap goes through."""
    torch.manual_seed(8)
    net = MultiPrimitiveQNetwork(GS, num_rotations=R, backbone="equivariant").eval()
    x = heightmaps(1, 11)
    params = TensorDict.from_module(net)
    with torch.no_grad():
        before = net(x)
        with params.to("meta").to_module(net):
            pass
        with params.apply(torch.zeros_like).to_module(net):
            assert not torch.allclose(net(x), before)
        torch.testing.assert_close(net(x), before)


# ---------------------------------------------------------------------------------------------------- loss and replay
@pytest.mark.parametrize("primitives", [GS[:1], GS])
def test_executed_values_equal_the_full_maps(primitives):
    torch.manual_seed(6)
    net = MultiPrimitiveQNetwork(primitives, num_rotations=R, backbone="equivariant").eval()
    layout = PixelActionLayout(len(primitives), R, H, W)
    p = len(primitives) - 1
    actions = torch.tensor([layout.encode(0, 1, 3, 4), layout.encode(p, 7, 30, 0), layout.encode(p, 0, 0, 31),
                            layout.encode(0, 2, 16, 16)])
    x = heightmaps(4, 9)
    with torch.no_grad():
        q = net(x)
        values = net.executed_values(x, actions)
    assert q.shape == (4, len(primitives), R, H, W)
    torch.testing.assert_close(values, q.reshape(4, -1)[torch.arange(4), actions])


def test_one_dqn_step_from_the_replay_changes_the_executed_nets_and_syncs_the_target(tmp_path):
    """The replay stores what it stores for any backbone; one train-mode SGD step of the DQN loss (double DQN, target
    network) on a sampled batch changes the executed primitives' weights, and HardUpdate copies them to the target."""
    torch.manual_seed(7)
    net = MultiPrimitiveQNetwork(GS, num_rotations=R, backbone="equivariant").train()
    layout = PixelActionLayout(3, R, H, W)
    td = transitions(2, layout, [layout.encode(0, 3, 5, 6), layout.encode(2, 6, 20, 11)], seed=10)
    rb = make_pixel_replay(10, tmp_path, batch_size=2)
    rb.extend(pack_transition(td))
    batch = unpack_transition(rb.sample())
    assert batch["observation"].shape == (2, 4, H, W) and set(batch["action"].tolist()) <= set(td["action"].tolist())

    loss_fn = PixelDQNLoss(net, gamma=0.5, delay_value=True, double_dqn=True)
    updater = HardUpdate(loss_fn, value_network_update_interval=1)
    optim = torch.optim.SGD(loss_fn.parameters(), lr=1e-2, momentum=0.9, weight_decay=1e-3)
    before = {p: net.nets[p].head.weights.detach().clone() for p in GS}
    loss = loss_fn(batch)["loss_qvalue"]
    loss.backward()
    executed = {GS[int(a) // (R * H * W)] for a in batch["action"]}
    for p in GS:
        grad = net.nets[p].head.weights.grad
        assert (grad is not None and grad.abs().sum() > 0) == (p in executed)
    optim.step()
    for _ in range(2):  # HardUpdate copies when its step counter reaches the interval
        updater.step()
    assert torch.isfinite(loss)
    for p in executed:
        assert not torch.equal(net.nets[p].head.weights, before[p])
        target = loss_fn.target_value_network_params.get(("nets", p, "head", "weights"))
        assert torch.equal(target, net.nets[p].head.weights)
    rb.update_tensordict_priority(batch)
    assert torch.tensor(rb.sampler._sum_tree[batch["index"].tolist()]).gt(0).all()


# ---------------------------------------------------------------------------------------------------- presets, recipe
@pytest.mark.parametrize("name, task", [("cpu-equi", "grasp"), ("gs-cpu-equi", "grasp_slide")])
def test_presets_build_equivariant_nets(name, task):
    cfg = ClutterConfig.from_preset(name)
    assert (cfg.task, cfg.backbone, cfg.num_rotations, cfg.heightmap_size) == (task, "equivariant", 16, 64)
    model = make_model(cfg)
    assert all(isinstance(net, EquivariantPixelQNetwork) for net in model.nets.values())
    assert [model.nets[p].symmetric for p in cfg.primitives] == [p == "grasp" for p in cfg.primitives]
    assert model.num_rotations == 16


def test_tiny_training_run_with_the_equivariant_backbone(tmp_path):
    """The whole stack (env, actor, mask, replay, loss, checkpoint, CLI) with the equivariant backbone: G&S, 32 px,
    2 objects, 2 steps; the checkpoint's greedy policy loads and acts."""
    cmd = [sys.executable, "-m", "maniskill_pnp.cli", "train-clutter", "--preset", "gs-cpu-equi", "--heightmap-size", "32",
           "--num-objects", "2", "--steps", "2", "--checkpoint-interval", "2", "--log-interval", "1", "--out", str(tmp_path)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index("{"):])
    assert summary["steps"] == 2 and summary["updates"] == 2
    run_dir = tmp_path / "gs-cpu-equi_equivariant_r16_px32_seed0"
    ckpt = load_checkpoint(run_dir / "checkpoint.pt")
    assert ClutterConfig.from_json(ckpt["config"]).backbone == "equivariant"
    assert {key.split(".")[1] for key in ckpt["model"]} == set(GS)

    actor, cfg, counters = load_policy(run_dir / "checkpoint.pt", torch.device("cpu"))
    assert counters["steps"] == 2 and cfg.num_rotations == 16
    color = torch.randint(0, 256, (1, 32, 32, 3), dtype=torch.uint8)
    depth = torch.zeros(1, 32, 32)
    depth[0, 12:18, 14:20] = 0.04  # one box: the mask allows grasps on it and slides towards it
    with torch.no_grad():
        values, action, mask = actor(color, depth)
    assert values.shape == (1, 3 * 16 * 32 * 32) and mask[0, action[0]]


def test_without_gradients_each_filter_is_expanded_once_per_weight_update(monkeypatch):
    """Acting reuses the expanded filters until the weights change; with gradients every pass expands (and
    backpropagates through) them anew."""
    from maniskill_pnp.agents.pixel import equivariant

    calls = []
    real = equivariant.enn.R2Conv.expand_parameters
    monkeypatch.setattr(equivariant.enn.R2Conv, "expand_parameters", lambda self: calls.append(self) or real(self))
    torch.manual_seed(3)
    net = EquivariantPixelQNetwork(num_rotations=R).eval()
    convs = sum(isinstance(m, equivariant._SteerableConv) for m in net.modules())
    x = heightmaps(1, 2)
    with torch.inference_mode():
        first = net(x)
        torch.testing.assert_close(net(x), first)
    assert len(calls) == convs
    with torch.no_grad():
        net.head.weights.mul_(0.5)  # an in-place update of the same tensor
        changed = net(x)
    assert len(calls) == 2 * convs and not torch.allclose(changed, first)
    net.head.weights.data.mul_(2.0)  # as a worker's weight sync writes: no new version, the values of ``first``
    with torch.no_grad():
        torch.testing.assert_close(net(x), first)
    assert len(calls) == 2 * convs + 1  # the head's filter only: the other layers' weights hold their values
    net.train()
    net(x).sum().backward()
    assert len(calls) == 3 * convs + 1 and net.head.weights.grad is not None
    copied = pickle.loads(pickle.dumps(net.eval()))
    assert all(getattr(m, "_expanded", None) is None for m in copied.modules())
