"""Unit tests of the pixelwise Q networks, losses and replay buffer (tiny sizes, CPU)."""

from __future__ import annotations

import pytest
from torch import nn
import torch
from tensordict import TensorDict
from torchrl.objectives import HardUpdate

from maniskill_pnp.agents.pixel.fcn import MultiPrimitiveQNetwork, PixelQNetwork, make_trunk, padded_size
from maniskill_pnp.agents.pixel.loss import PixelBCELoss, PixelDQNLoss
from maniskill_pnp.agents.pixel.replay import (NEXT_MASK_KEY, make_pixel_replay, pack, pack_bits, pack_transition,
                                               unpack, unpack_bits, unpack_transition)
from maniskill_pnp.cell.pixel_action import PixelActionLayout

H = W = 32
R = 4


def heightmaps(b: int, seed: int, size: int = H) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(b, 3, size, size, generator=g)
    height = 0.1 * torch.rand(b, 1, size, size, generator=g)
    return torch.cat([rgb, height], dim=1)


def rotate_world_90(x: torch.Tensor) -> torch.Tensor:
    """Turn the scene by +90 degrees about the workspace centre (world x -> world y; col is x, row is y)."""
    return torch.rot90(x, 1, dims=(-1, -2))


@pytest.fixture(scope="module")
def small_net() -> PixelQNetwork:
    torch.manual_seed(0)
    return PixelQNetwork(num_rotations=R, backbone="small").eval()


def transitions(b: int, layout: PixelActionLayout, *, seed: int, terminated) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    return TensorDict(
        {
            "observation": heightmaps(b, seed),
            "action": torch.randint(layout.size, (b,), generator=g),
            "next": {
                "observation": heightmaps(b, seed + 1),
                "reward": torch.tensor([1.0, 0.5, 0.0, 0.8][:b]).unsqueeze(-1),
                "terminated": torch.tensor(terminated).unsqueeze(-1),
                "done": torch.tensor(terminated).unsqueeze(-1),
            },
        },
        batch_size=[b],
    )


# ---------------------------------------------------------------------------------------------------- networks
def test_helper_rotation_is_world_plus_90():
    x = torch.zeros(1, 1, 5, 5)
    x[0, 0, 2, 4] = 1.0  # centre row, last col: the +x direction
    assert rotate_world_90(x)[0, 0, 4, 2] == 1.0  # last row, centre col: the +y direction


def test_padded_size_holds_the_diagonal_symmetrically():
    for h, m in [(32, 8), (33, 8), (224, 32), (20, 1)]:
        s = padded_size(h, h, m)
        assert s * s >= 2 * h * h and (s - h) % 2 == 0


def test_small_network_shape(small_net):
    with torch.no_grad():
        assert small_net(heightmaps(2, 0)).shape == (2, R, H, W)


def test_no_depth_network_shape():
    net = PixelQNetwork(num_rotations=R, backbone="small", use_depth=False).eval()
    assert net.depth_trunk is None
    with torch.no_grad():
        assert net(heightmaps(2, 0)).shape == (2, R, H, W)


@pytest.mark.parametrize("backbone", ["densenet121", "resnet101", "densenet121-s8", "resnet101-s8"])
def test_heavy_backbone_shape(backbone):
    net = PixelQNetwork(num_rotations=R, backbone=backbone).eval()
    with torch.no_grad():
        assert net(heightmaps(1, 0)).shape == (1, R, H, W)


def test_multi_primitive_shape_and_layout():
    net = MultiPrimitiveQNetwork(("grasp", "left_slide", "right_slide"), num_rotations=R, backbone="small").eval()
    with torch.no_grad():
        q = net(heightmaps(1, 0))
    assert q.shape == (1, 3, R, H, W)
    layout = PixelActionLayout(3, R, H, W)
    flat = q.reshape(1, -1).argmax(1)
    p, r, i, j = layout.decode(flat)
    assert q[0, p, r, i, j] == q.max()


def test_bad_inputs_raise():
    with pytest.raises(ValueError):
        PixelQNetwork(num_rotations=R, backbone="vgg")
    with pytest.raises(ValueError):
        PixelQNetwork(num_rotations=0, backbone="small")
    with pytest.raises(FileNotFoundError):
        PixelQNetwork(num_rotations=R, backbone="small", pretrained_path="/nonexistent/weights.pth")
    with pytest.raises(ValueError):
        MultiPrimitiveQNetwork(("grasp", "grasp"), num_rotations=R, backbone="small")


def test_pretrained_weights_load_from_local_file(tmp_path):
    import torchvision

    full = torchvision.models.resnet18(weights=None)
    path = tmp_path / "resnet18.pth"
    torch.save(full.state_dict(), path)
    net = PixelQNetwork(num_rotations=R, backbone="small", pretrained_path=path)
    assert torch.equal(net.color_trunk[0].weight, full.conv1.weight)
    assert torch.equal(net.depth_trunk[0].weight, full.conv1.weight)


def test_rotating_the_scene_permutes_the_rotation_maps(small_net):
    x = heightmaps(1, 3)
    with torch.no_grad():
        q = small_net(x)
        q_rot = small_net(rotate_world_90(x))
    scale = q.abs().max()
    for r in range(R):
        # A grasp at yaw r in the turned scene is a grasp at yaw r - 1 in the original one.
        expected = rotate_world_90(q[:, (r - 1) % R])
        torch.testing.assert_close(q_rot[:, r], expected, atol=1e-4 * scale, rtol=1e-4)


# ---------------------------------------------------------------------------------------------------- DQN loss
def test_dqn_loss_matches_hand_computation_and_grad_only_at_executed_pixel(small_net):
    layout = PixelActionLayout(1, R, H, W)
    td = transitions(2, layout, seed=5, terminated=[False, True])
    gamma = 0.5
    loss_fn = PixelDQNLoss(small_net, gamma=gamma, delay_value=False)

    captured = []

    def keep(module, inputs, output):
        if output.requires_grad:
            output.retain_grad()
            captured.append(output)

    handle = small_net.register_forward_hook(keep)
    try:
        out = loss_fn(td)
        out["loss_qvalue"].backward()
    finally:
        handle.remove()
        small_net.zero_grad(set_to_none=True)

    with torch.no_grad():
        q = small_net(td["observation"]).reshape(2, -1)
        next_q = small_net(td["next", "observation"]).reshape(2, -1)
    a = td["action"]
    q_sa = q[torch.arange(2), a]
    r = td["next", "reward"].squeeze(-1)
    target = torch.stack([r[0] + gamma * next_q[0].max(), r[1]])  # the second transition is terminal
    expected = torch.nn.functional.huber_loss(q_sa, target, delta=1.0)
    torch.testing.assert_close(out["loss_qvalue"], expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(td["td_error"], (target - q_sa).abs(), rtol=1e-5, atol=1e-6)
    # Terminal: the bootstrap is zero, so the TD error is |r - Q(s, a)|.
    torch.testing.assert_close(td["td_error"][1], (r[1] - q_sa[1]).abs(), rtol=1e-5, atol=1e-6)

    assert len(captured) == 1  # only the online forward on s carries gradient
    grad = captured[0].grad.reshape(2, -1)
    mask = torch.zeros_like(grad, dtype=torch.bool)
    mask[torch.arange(2), a] = True
    assert (grad[mask] != 0).all()
    assert (grad[~mask] == 0).all()


def test_terminal_transitions_do_not_bootstrap(small_net):
    layout = PixelActionLayout(1, R, H, W)
    loss_fn = PixelDQNLoss(small_net, gamma=0.9, delay_value=False)
    td = transitions(2, layout, seed=7, terminated=[True, True])
    td_far = td.clone()
    td_far["next", "observation"] = td["next", "observation"] * 5.0
    loss_fn(td)
    loss_fn(td_far)
    torch.testing.assert_close(td["td_error"], td_far["td_error"])


def test_terminated_falls_back_to_done(small_net):
    layout = PixelActionLayout(1, R, H, W)
    loss_fn = PixelDQNLoss(small_net, gamma=0.9, delay_value=False)
    td = transitions(2, layout, seed=7, terminated=[True, False])
    td_done_only = td.clone()
    del td_done_only["next", "terminated"]
    loss_fn(td)
    loss_fn(td_done_only)
    torch.testing.assert_close(td["td_error"], td_done_only["td_error"])


def test_double_dqn_argmax_by_online_value_by_target():
    torch.manual_seed(1)
    net = PixelQNetwork(num_rotations=R, backbone="small").eval()
    loss_fn = PixelDQNLoss(net, gamma=0.9, delay_value=True, double_dqn=True)
    HardUpdate(loss_fn, value_network_update_interval=1)  # initialises the target from the online parameters
    online = loss_fn.value_network_params.data
    target = loss_fn.target_value_network_params
    for key, value in online.items(True, True):
        assert torch.equal(target.get(key), value)  # synced by HardUpdate
    with torch.no_grad():
        for key, value in target.items(True, True):
            if value.is_floating_point():
                value.add_(0.05 * torch.randn_like(value))

    x = heightmaps(2, 11)
    with torch.no_grad():
        q_online = net(x).reshape(2, -1)
        with target.to_module(net):
            q_target = net(x).reshape(2, -1)
    expected = q_target.gather(1, q_online.argmax(1, keepdim=True)).squeeze(1)
    torch.testing.assert_close(loss_fn.bootstrap(x), expected)
    assert not torch.allclose(q_online, q_target)

    plain = PixelDQNLoss(net, gamma=0.9, delay_value=True)
    HardUpdate(plain, value_network_update_interval=10**6)  # registers an updater (no sync within this test)
    with torch.no_grad():
        for key, value in target.items(True, True):
            plain.target_value_network_params.get(key).copy_(value)
    torch.testing.assert_close(plain.bootstrap(x), q_target.max(1).values)


def test_loss_bad_arguments_raise(small_net):
    with pytest.raises(ValueError):
        PixelDQNLoss(small_net, gamma=0.9, delay_value=False, double_dqn=True)
    with pytest.raises(ValueError):
        PixelDQNLoss(small_net, gamma=1.5)
    with pytest.raises(ValueError):
        PixelDQNLoss(small_net, gamma=0.9, reduction="median")
    loss_fn = PixelDQNLoss(small_net, gamma=0.9, delay_value=False)
    td = transitions(2, PixelActionLayout(1, R, H, W), seed=1, terminated=[False, False])
    td["action"] = torch.tensor([0, R * H * W])
    with pytest.raises(ValueError):
        loss_fn(td)


def test_prioritized_weights_scale_the_loss(small_net):
    td = transitions(2, PixelActionLayout(1, R, H, W), seed=2, terminated=[False, True])
    loss_fn = PixelDQNLoss(small_net, gamma=0.9, delay_value=False, reduction="none")
    per_sample = loss_fn(td.clone())["loss_qvalue"]
    td["priority_weight"] = torch.tensor([2.0, 0.0])
    weighted = loss_fn(td)["loss_qvalue"]
    torch.testing.assert_close(weighted, per_sample * torch.tensor([2.0, 0.0]))


# ---------------------------------------------------------------------------------------------------- BCE loss
def test_bce_loss_on_executed_pixel(small_net):
    layout = PixelActionLayout(1, R, H, W)
    td = transitions(3, layout, seed=9, terminated=[False, False, True])
    td["next", "reward"] = torch.tensor([[1.0], [0.0], [0.5]])
    loss_fn = PixelBCELoss(small_net)
    out = loss_fn(td)
    with torch.no_grad():
        logit = small_net(td["observation"]).reshape(3, -1)[torch.arange(3), td["action"]]
    label = torch.tensor([1.0, 0.0, 1.0])
    expected = torch.nn.functional.binary_cross_entropy_with_logits(logit, label)
    torch.testing.assert_close(out["loss_bce"], expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(td["td_error"], (label - logit.sigmoid()).abs(), rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------------------------------------------- replay
def test_pack_unpack_round_trip():
    x = heightmaps(3, 4)
    x[..., 3, :, :] *= 3.0  # heights up to 0.3 m
    packed = pack(x)
    assert packed["color"].dtype == torch.uint8 and packed["height"].dtype == torch.float16
    y = unpack(packed)
    assert y.dtype == torch.float32 and y.shape == x.shape
    torch.testing.assert_close(y[:, :3], x[:, :3], atol=0.5 / 255 + 1e-6, rtol=0)
    torch.testing.assert_close(y[:, 3:], x[:, 3:], atol=0, rtol=2**-11)


def test_prioritized_sampling_prefers_high_td(tmp_path):
    n = 10
    rb = make_pixel_replay(100, tmp_path, alpha=1.0, beta=0.4, batch_size=16)
    td = TensorDict(
        {"observation": heightmaps(n, 0, size=8), "action": torch.arange(n), "next": {"reward": torch.zeros(n, 1)}},
        batch_size=[n],
    )
    rb.extend(pack_transition(td))
    batch = rb.sample()
    batch.set("td_error", torch.where(batch["action"] == 3, 100.0, 1e-3))
    rb.update_tensordict_priority(batch)
    rb.update_priority(torch.arange(n), torch.where(torch.arange(n) == 3, 100.0, 1.0))
    counts = torch.zeros(n)
    for _ in range(50):
        sample = unpack_transition(rb.sample())
        assert sample["observation"].dtype == torch.float32
        counts += torch.bincount(sample["action"], minlength=n)
    assert counts[3] / counts.sum() > 0.8  # expected 100 / 109
    w = rb.sample()["priority_weight"]
    assert w.shape == (16,)


def test_replay_feeds_the_loss_and_takes_its_priorities(tmp_path, small_net):
    layout = PixelActionLayout(1, R, H, W)
    rb = make_pixel_replay(10, tmp_path, batch_size=2)
    rb.extend(pack_transition(transitions(4, layout, seed=3, terminated=[False, True, False, True])))
    batch = unpack_transition(rb.sample())
    loss_fn = PixelDQNLoss(small_net, gamma=0.5, delay_value=False)
    loss_fn(batch)
    rb.update_tensordict_priority(batch)
    prio = rb.sampler._sum_tree[batch["index"].tolist()]  # stored priorities ((|td| + eps) ** alpha)
    assert torch.tensor(prio).gt(0).all()


def test_a_stored_next_mask_replaces_the_bootstraps_own(tmp_path, small_net):
    """A transition stored with its next state's action mask (as bits) gives the loss what computing the mask on its
    next heightmap gives; a bad mask length is refused by name."""
    layout = PixelActionLayout(1, R, H, W)
    td = transitions(4, layout, seed=5, terminated=[False, False, True, False])
    some = lambda obs: torch.rand(obs.shape[0], layout.size, generator=torch.Generator().manual_seed(9)) > 0.7  # noqa: E731
    allowed = some(td["next", "observation"])
    assert torch.equal(unpack_bits(pack_bits(allowed)), allowed)
    rb = make_pixel_replay(10, tmp_path, batch_size=4)
    rb.extend(pack_transition(td.clone().set(NEXT_MASK_KEY, allowed)))
    stored = unpack_transition(rb[:4])
    assert torch.equal(stored[NEXT_MASK_KEY], allowed) and ("next", "action_mask_bits") not in stored.keys(True)
    computing = PixelDQNLoss(small_net, gamma=0.5, delay_value=False, action_mask=some)
    reading = PixelDQNLoss(small_net, gamma=0.5, delay_value=False, action_mask=lambda obs: pytest.fail("computed"))
    with torch.no_grad():
        torch.testing.assert_close(reading(stored)["target_value"], computing(unpack_transition(rb[:4]).exclude(
            NEXT_MASK_KEY))["target_value"], rtol=0, atol=0)
    with pytest.raises(ValueError, match="7 actions does not split into bytes"):
        pack_bits(torch.ones(2, 7, dtype=torch.bool))


def test_train_mode_sgd_step_with_target_network():
    torch.manual_seed(2)
    net = MultiPrimitiveQNetwork(("grasp", "left_slide"), num_rotations=R, backbone="small").train()
    loss_fn = PixelDQNLoss(net, gamma=0.5, delay_value=True, double_dqn=True)
    updater = HardUpdate(loss_fn, value_network_update_interval=1)
    optim = torch.optim.SGD(loss_fn.parameters(), lr=1e-2, momentum=0.9, weight_decay=1e-3)
    td = transitions(2, PixelActionLayout(2, R, H, W), seed=4, terminated=[False, True])
    before = net.nets["grasp"].head[-1].weight.detach().clone()
    loss = loss_fn(td)["loss_qvalue"]
    loss.backward()
    optim.step()
    for _ in range(2):  # HardUpdate copies when its step counter reaches the interval
        updater.step()
    assert torch.isfinite(loss)
    assert not torch.equal(net.nets["grasp"].head[-1].weight, before)
    target_w = loss_fn.target_value_network_params.get(("nets", "grasp", "head", "5", "weight"))
    assert torch.equal(target_w, net.nets["grasp"].head[-1].weight)


def test_executed_values_equal_the_full_maps_and_give_the_same_gradient():
    """The training path (executed primitive and rotation only) matches the full maps in eval mode."""
    torch.manual_seed(3)
    net = MultiPrimitiveQNetwork(("grasp", "left_slide", "right_slide"), num_rotations=R, backbone="small").eval()
    layout = PixelActionLayout(3, R, H, W)
    td = transitions(4, layout, seed=9, terminated=[False, True, False, False])
    td["action"] = torch.tensor([layout.encode(0, 1, 3, 4), layout.encode(2, 3, 30, 0), layout.encode(1, 0, 0, 31),
                                 layout.encode(0, 2, 16, 16)])
    x = td["observation"]
    with torch.no_grad():
        full = net(x).reshape(4, -1).gather(1, td["action"][:, None]).squeeze(1)
        torch.testing.assert_close(net.executed_values(x, td["action"]), full, rtol=1e-5, atol=1e-6)

    grads = []
    for executed_only in (True, False):
        loss_fn = PixelDQNLoss(net, gamma=0.5, delay_value=False, executed_only=executed_only)
        loss_fn(td.clone())["loss_qvalue"].backward()
        grads.append({k: p.grad.clone() for k, p in net.named_parameters() if p.grad is not None})
        net.zero_grad(set_to_none=True)
    assert grads[0].keys() == grads[1].keys() and len(grads[0]) > 0
    for k in grads[0]:
        torch.testing.assert_close(grads[0][k], grads[1][k], rtol=1e-4, atol=1e-6)
    with pytest.raises(ValueError, match="out of range"):
        net.executed_values(x, torch.tensor([0, 1, 2, layout.size]))


@pytest.mark.parametrize("backbone", ["small", "densenet121-s8", "resnet101-s8"])
def test_stride_8_trunks_centre_feature_i_on_offset_plus_stride_i(backbone):
    """The receptive field of a trunk's feature ``i`` (the input pixels its gradient reaches) is centred on
    ``offset + stride * i``, the pixel :meth:`PixelQNetwork.upsample` puts it on."""
    from maniskill_pnp.agents.pixel.fcn import BACKBONES

    spec = BACKBONES[backbone]
    trunk = make_trunk(backbone).eval()
    for module in list(trunk.modules()):  # linear stand-ins with the same geometry: every path carries gradient
        for name, child in module.named_children():
            if isinstance(child, nn.ReLU):
                setattr(module, name, nn.Identity())
            elif isinstance(child, nn.MaxPool2d):
                setattr(module, name, nn.AvgPool2d(child.kernel_size, child.stride, child.padding))
    x = torch.ones(1, 3, 512, 512, requires_grad=True)
    features = trunk(x)
    assert features.shape[1:] == (spec.channels, 512 // spec.stride, 512 // spec.stride)
    i = features.shape[-1] // 2
    features[0, :, i, i].sum().backward()
    reached = x.grad[0].abs().sum(0) > 0
    rows = torch.nonzero(reached.any(1)).flatten()
    assert 0 < rows.min() and rows.max() < 511  # the field lies inside the image, so its extent is its own
    assert (rows.min() + rows.max()).item() / 2 == pytest.approx(spec.offset + spec.stride * i, abs=0.5)


@pytest.mark.parametrize("backbone, cell, pixel", [("small", 3, 24), ("densenet121", 2, 78), ("resnet101", 1, 32)])
def test_upsampling_puts_each_feature_on_its_receptive_field_centre(backbone, cell, pixel):
    """Feature ``i`` of a trunk is centred on input pixel ``offset + stride * i``; the upsampled map peaks there."""
    net = PixelQNetwork.__new__(PixelQNetwork)  # only the geometry of the backbone is needed
    nn.Module.__init__(net)
    from maniskill_pnp.agents.pixel.fcn import BACKBONES

    net.stride, net.offset = BACKBONES[backbone].stride, BACKBONES[backbone].offset
    grid = torch.zeros(1, 1, 6, 6)
    grid[0, 0, cell, cell + 1] = 1.0
    up = net.upsample(grid, 6 * net.stride)[0, 0]
    assert up.shape == (6 * net.stride, 6 * net.stride)
    assert divmod(int(up.argmax()), up.shape[1]) == (pixel, pixel + net.stride)
    assert up[pixel, pixel + net.stride] == pytest.approx(1.0, abs=1e-5)
