"""A rotation-equivariant pixel Q network: every rotation's Q map from one forward pass, without rotated inputs.

:class:`EquivariantPixelQNetwork` is a drop-in for :class:`~maniskill_pnp.agents.pixel.fcn.PixelQNetwork` (the same
input ``(B, 4, H, W)``, the same output ``(B, R, H, W)``, the same :meth:`~EquivariantPixelQNetwork.rotation_maps`),
built from ``e2cnn`` steerable convolutions of the cyclic group ``C_R`` (``e2cnn.gspaces.Rot2dOnR2(R)``). Instead of
rotating the heightmap ``R`` times and running one network per rotation, its hidden features are *regular* fields:
``R`` channels per field, one per rotation, which rotating the input turns into a rotated image whose channels are
cyclically shifted. The output fibre is then one Q map per rotation, and the network is equivariant by construction:
rotating the heightmap by 90 degrees rotates every Q map by 90 degrees and shifts the rotation index by a quarter turn
(exactly, on a square grid; for other angles up to the grid's interpolation).

Architecture (``F`` regular fields of ``R`` channels at full resolution, ``F = round(head_channels / R)``, so the
channel count stays about ``head_channels`` whatever ``R``; every convolution is followed by e2cnn's
``InnerBatchNorm`` (one statistic per field) and a ReLU, except the last):

================== ===================================================== ==========
layer              fields                                                resolution
================== ===================================================== ==========
``enc0``           4 trivial (RGB, height; 3 without depth) -> F, 5x5     S
max pool 2x2                                                             S/2
``enc1``           F -> 2F, 3x3                                          S/2
max pool 2x2                                                             S/4
``mid``            2F -> 2F, 3x3, twice                                  S/4
bilinear x2, concatenated with ``enc1``                                  S/2
``dec1``           4F -> F, 3x3                                          S/2
bilinear x2, concatenated with ``enc0``                                  S
``dec0``           2F -> F, 1x1                                          S
``head``           F -> 1 (one Q map per rotation), 1x1, with its bias    S
================== ===================================================== ==========

where ``S`` is the heightmap side padded (with zeros) to a multiple of 4 and cropped back at the end. The receptive
field is about 32 px. All spatial operations commute with a 90-degree rotation of the padded grid: odd kernels with
symmetric zero padding, 2x2 pooling blocks and ``align_corners=False`` bilinear upsampling on even sides. So the 90
degree equivariance is exact (up to float rounding) when the padding is symmetric, i.e. for every even heightmap side;
an odd side is padded one pixel more on one side and is only approximately equivariant.

Output fields:

* directional primitives (slides), ``symmetric=False``: the regular representation, ``R`` maps;
* the grasp, ``symmetric=True``: a parallel-jaw grasp turned by 180 degrees is the same grasp, so map ``r`` and map
  ``r + R/2`` are tied: both are the mean of the regular output's two opposite channels. Averaging opposite channels
  is the equivariant projection of the regular representation onto the quotient ``C_R / C_2`` (``R/2`` channels, one
  per jaw line), so this is a network with a quotient output field, written with a regular last layer (e2cnn 0.2.3's
  one-element kernel bases fail to build on this torch, which the quotient output hits at ``R = 2``). A DQN update
  of one jaw orientation is an update of both. (An odd ``R`` has no opposite rotation: its grasp net is not tied.)

Rotation convention. Rotation ``r`` is the one of :class:`~maniskill_pnp.cell.workspace.WorkspaceSpec`: the jaws
close along ``yaw = r * 2*pi / R`` from world x, where the heightmap's col axis is world x and its row axis world y.
``torch.rot90(x, 1, dims=(-2, -1))`` moves pixel ``(row, col)`` to ``(S-1-col, row)``: in centred coordinates
``(x, y) -> (y, -x)``, a rotation of the scene by -90 degrees about world z. The grasp with yaw ``theta`` at a pixel
of the original scene is therefore the grasp with yaw ``theta - 90`` degrees at the rotated pixel, i.e. the Q maps
of the rotated heightmap are ``q'[r] = rot90(q)[r + R/4]``: ``torch.roll(rot90(q), -R/4, dims=rotation)``.
e2cnn's quarter turn (group element ``R/4``) acts on the grid as that same ``rot90`` but shifts a regular field's
channels the other way: the output field of the turned heightmap is ``torch.roll(rot90(field), +R/4, dims=channel)``.
Map ``r`` is therefore the output field's channel ``-r mod R``, which turns e2cnn's ``+R/4`` channel shift into the
``-R/4`` rotation shift the env's axes need.

The convolutions always build their filters from their weights (e2cnn's ``R2Conv`` would cache the filter in eval
mode, which neither a functional parameter swap, e.g. the DQN loss's target network, nor a weight update sent to a
collector worker would refresh); e2cnn's constant buffers (the sampled steerable bases, field indices) are not saved
in the ``state_dict``, which keeps the learned weights and the BatchNorm statistics only.
"""

from __future__ import annotations

import warnings

import torch
import torch.nn.functional as F
from e2cnn import gspaces
from e2cnn import nn as enn
from e2cnn.nn.modules.r2_conv.basisexpansion_blocks import BlocksBasisExpansion
from e2cnn.nn.modules.r2_conv.basisexpansion_singleblock import SingleBlockBasisExpansion
from torch import nn

from maniskill_pnp.agents.pixel.rotations import rotation_query

#: ImageNet statistics, used to normalise the colour channels (as for the other backbones).
_RGB_MEAN = (0.485, 0.456, 0.406)
_RGB_STD = (0.229, 0.224, 0.225)
#: The heightmap is padded to a multiple of this (two 2x2 poolings).
PAD_MULTIPLE = 4
#: BatchNorm buffers that belong in the state_dict; e2cnn's other buffers are constants rebuilt at construction.
_STATEFUL_BUFFERS = frozenset({"running_mean", "running_var", "num_batches_tracked"})


class _SteerableConv(enn.R2Conv):
    """``e2cnn.nn.R2Conv`` whose filter is expanded from its weights in every forward pass, in train and eval mode.

    ``R2Conv`` caches the expanded filter as a buffer when switched to eval mode; a cached filter would ignore weights
    swapped in later (the DQN loss's target parameters, ``load_state_dict`` or a collector's weight update after
    ``.eval()``). Without gradients (acting, the DQN targets) the expansion is reused while the weight and bias hold
    the values it was expanded from, compared element by element with a copy (a few thousand numbers, against an
    expansion that multiplies them by the sampled basis): neither the tensors' identity nor their version counter
    sees a weight sync that writes into shared memory from the learner's process. So acting expands each filter once
    per weight update, not per decision.
    """

    _expanded: tuple | None = None

    def __init__(self, *args, **kwargs):
        with warnings.catch_warnings():  # e2cnn 0.2.3 indexes its basis masks with uint8 tensors
            warnings.filterwarnings("ignore", message="indexing with dtype torch.uint8", category=UserWarning)
            super().__init__(*args, **kwargs)
        for name in ("filter", "expanded_bias"):
            self._buffers.pop(name, None)
            self.__dict__.pop(name, None)

    def train(self, mode: bool = True):
        return nn.Module.train(self, mode)  # skip R2Conv.train's filter caching

    def forward(self, input: enn.GeometricTensor) -> enn.GeometricTensor:
        assert input.type == self.in_type
        weight, bias = self._expansion()
        out = F.conv2d(input.tensor, weight, bias, stride=self.stride, padding=self.padding, dilation=self.dilation,
                       groups=self.groups)
        return enn.GeometricTensor(out, self.out_type)

    def __getstate__(self):
        state = super().__getstate__()
        state.pop("_expanded", None)  # a cache, not state: copies and worker processes expand their own
        return state

    def _expansion(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        if torch.is_grad_enabled():
            self._expanded = None
            return self.expand_parameters()
        params = (self.weights, self.bias)
        cached = self._expanded  # (copies of the weight and bias, inference mode, expansion)
        if cached is None or cached[1] != torch.is_inference_mode_enabled() or not all(
                _same(a, b) for a, b in zip(cached[0], params)):
            cached = self._expanded = (tuple(None if p is None else p.detach().clone() for p in params),
                                       torch.is_inference_mode_enabled(), self.expand_parameters())
        return cached[2]


def _same(copy: torch.Tensor | None, param: torch.Tensor | None) -> bool:
    return (copy is None) == (param is None) and (copy is None or torch.equal(copy, param))


class _BlocksExpansion(BlocksBasisExpansion):
    """e2cnn's expansion of a filter from its weights, compared by identity.

    e2cnn compares basis expansions by content (``torch.allclose`` of their sampled bases) and hashes them by their
    shared sub-blocks, so the expansions of two layers with the same field types hash alike. TensorDict's
    ``to_module`` (TorchRL's weight sync to collector workers) keys a memo by each submodule: equal hashes make it
    compare two expansions, which on its meta-device copies raises. As submodules of a network they are distinct
    objects, so identity is the right equality here.
    """

    __eq__ = object.__eq__
    __hash__ = object.__hash__


class _SingleBlockExpansion(SingleBlockBasisExpansion):
    """One block of :class:`_BlocksExpansion`, compared by identity for the same reason."""

    __eq__ = object.__eq__
    __hash__ = object.__hash__


_IDENTITY_EQUAL = {BlocksBasisExpansion: _BlocksExpansion, SingleBlockBasisExpansion: _SingleBlockExpansion}


def _conv_block(in_type: enn.FieldType, out_type: enn.FieldType, kernel_size: int) -> enn.SequentialModule:
    return enn.SequentialModule(
        _SteerableConv(in_type, out_type, kernel_size, padding=kernel_size // 2, bias=False),
        enn.InnerBatchNorm(out_type),
        enn.ReLU(out_type, inplace=True),
    )


def symmetric_padding(size: int, multiple: int = PAD_MULTIPLE) -> tuple[int, int]:
    """Zero padding ``(before, after)`` that brings ``size`` to a multiple of ``multiple``; equal on both sides when
    the total is even (always for an even ``size`` and ``multiple = 4``), so the grid's centre stays its centre."""
    total = -size % multiple
    return total // 2, total - total // 2


class EquivariantPixelQNetwork(nn.Module):
    """``C_R``-equivariant fully convolutional Q network: ``(B, 4, H, W)`` heightmap -> ``(B, R, H, W)`` Q maps.

    See the module docstring for the architecture, the grasp's 180-degree symmetry and the rotation convention.

    Args:
        num_rotations: Number of rotations ``R`` >= 2 (the group ``C_R``; a multiple of 4 for an exact 90-degree
            equivariance).
        symmetric: Tie map ``r`` to map ``r + R/2`` (a parallel-jaw grasp); False for directional primitives.
        use_depth: Feed the height channel (False: colour only).
        head_channels: Channels of the full-resolution layers, rounded to whole regular fields of ``R`` channels
            (at least one); the coarser layers have twice as many.
        depth_mean: Subtracted from heights (m).
        depth_std: Heights are divided by this (m) after ``depth_mean`` is subtracted.

    Example:
        >>> net = EquivariantPixelQNetwork(num_rotations=8, symmetric=True).eval()
        >>> q = net(torch.rand(2, 4, 32, 32))
        >>> q.shape, torch.equal(q[:, :4], q[:, 4:])
        (torch.Size([2, 8, 32, 32]), True)
    """

    def __init__(
        self,
        *,
        num_rotations: int = 16,
        symmetric: bool = False,
        use_depth: bool = True,
        head_channels: int = 64,
        depth_mean: float = 0.01,
        depth_std: float = 0.03,
    ):
        super().__init__()
        if not isinstance(num_rotations, int) or isinstance(num_rotations, bool) or num_rotations < 2:
            raise ValueError(f"the equivariant network needs an integer num_rotations >= 2, got {num_rotations!r}")
        if head_channels <= 0:
            raise ValueError(f"head_channels must be positive, got {head_channels!r}")
        if not depth_std > 0:
            raise ValueError(f"depth_std must be > 0, got {depth_std!r}")
        self._init_kwargs = dict(num_rotations=num_rotations, symmetric=symmetric, use_depth=use_depth,
                                 head_channels=head_channels, depth_mean=depth_mean, depth_std=depth_std)
        R = num_rotations
        self.num_rotations = R
        self.backbone = "equivariant"
        self.symmetric = bool(symmetric)
        self.use_depth = use_depth
        self.depth_mean = float(depth_mean)
        self.depth_std = float(depth_std)
        self.fields = max(1, round(head_channels / R))

        gspace = gspaces.Rot2dOnR2(R)
        regular = lambda n: enn.FieldType(gspace, n * [gspace.regular_repr])  # noqa: E731
        f = self.fields
        self.in_type = enn.FieldType(gspace, (4 if use_depth else 3) * [gspace.trivial_repr])
        self.out_type = regular(1)

        self.enc0 = _conv_block(self.in_type, regular(f), 5)
        self.pool0 = enn.PointwiseMaxPool(regular(f), 2)
        self.enc1 = _conv_block(regular(f), regular(2 * f), 3)
        self.pool1 = enn.PointwiseMaxPool(regular(2 * f), 2)
        self.mid = enn.SequentialModule(_conv_block(regular(2 * f), regular(2 * f), 3),
                                        _conv_block(regular(2 * f), regular(2 * f), 3))
        self.up1 = enn.R2Upsampling(regular(2 * f), scale_factor=2, mode="bilinear", align_corners=False)
        self.dec1 = _conv_block(regular(4 * f), regular(f), 3)
        self.up0 = enn.R2Upsampling(regular(f), scale_factor=2, mode="bilinear", align_corners=False)
        self.dec0 = _conv_block(regular(2 * f), regular(f), 1)
        self.head = _SteerableConv(regular(f), self.out_type, 1, bias=True)

        # map r is the output field's channel -r (mod R); a symmetric net averages it with channel -r + R/2
        self.register_buffer("channel", (-torch.arange(R)) % R, persistent=False)
        self.register_buffer("rgb_mean", torch.tensor(_RGB_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(_RGB_STD).view(1, 3, 1, 1), persistent=False)
        for module in self.modules():
            if module is not self:
                module._non_persistent_buffers_set.update(set(module._buffers) - _STATEFUL_BUFFERS)
            if type(module) in _IDENTITY_EQUAL:
                module.__class__ = _IDENTITY_EQUAL[type(module)]

    def __reduce__(self):
        """Pickle as constructor arguments + ``state_dict`` (e2cnn's group objects hold lambdas, which the standard
        pickle of a collector's worker processes cannot send); :func:`copy.deepcopy` goes the same way."""
        return _rebuild, (self._init_kwargs, self.state_dict(), self.training)

    @staticmethod
    def _check(heightmaps: torch.Tensor) -> None:
        if heightmaps.ndim < 4 or heightmaps.shape[-3] != 4:
            raise ValueError(f"heightmaps must be (..., 4, H, W) (RGB + height), got {tuple(heightmaps.shape)}")

    def fields_of(self, heightmaps: torch.Tensor) -> torch.Tensor:
        """The output field ``(N, R, H, W)`` of heightmaps ``(N, 4, H, W)``, in e2cnn's channel order (map ``r`` is
        channel ``-r mod R``); a symmetric net's opposite channels already averaged."""
        H, W = heightmaps.shape[-2:]
        rgb = (heightmaps[:, :3] - self.rgb_mean) / self.rgb_std
        x = torch.cat([rgb, (heightmaps[:, 3:4] - self.depth_mean) / self.depth_std], 1) if self.use_depth else rgb
        (top, bottom), (left, right) = symmetric_padding(H), symmetric_padding(W)
        x = F.pad(x, (left, right, top, bottom))
        e0 = self.enc0(enn.GeometricTensor(x, self.in_type))
        e1 = self.enc1(self.pool0(e0))
        d1 = self.dec1(enn.tensor_directsum([self.up1(self.mid(self.pool1(e1))), e1]))
        d0 = self.dec0(enn.tensor_directsum([self.up0(d1), e0]))
        out = self.head(d0).tensor[..., top : top + H, left : left + W]
        if self.symmetric and self.num_rotations % 2 == 0:
            half = self.num_rotations // 2
            out = 0.5 * (out + out.roll(half, dims=1))
        return out

    def forward(self, heightmaps: torch.Tensor) -> torch.Tensor:
        """Q maps ``(*batch, R, H, W)`` of heightmaps ``(*batch, 4, H, W)``."""
        self._check(heightmaps)
        batch, (H, W) = heightmaps.shape[:-3], heightmaps.shape[-2:]
        out = self.fields_of(heightmaps.reshape(-1, 4, H, W))
        return out[:, self.channel].reshape(*batch, self.num_rotations, H, W)

    def rotation_maps(self, heightmaps: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
        """Q map ``(N, H, W)`` of each heightmap ``(N, 4, H, W)`` at its rotation index ``rotation[n]``.

        The same interface as :meth:`PixelQNetwork.rotation_maps
        <maniskill_pnp.agents.pixel.fcn.PixelQNetwork.rotation_maps>`; here one forward pass gives every rotation
        anyway, so this is ``forward(heightmaps)[n, rotation[n]]`` in train and eval mode alike (only the selected
        channels are gathered).
        """
        self._check(heightmaps)
        rotation = rotation_query(heightmaps, rotation, self.num_rotations)
        out = self.fields_of(heightmaps)
        return out[torch.arange(out.shape[0], device=out.device), self.channel[rotation]]


def _rebuild(init_kwargs: dict, state: dict, training: bool) -> EquivariantPixelQNetwork:
    """The network of :meth:`EquivariantPixelQNetwork.__reduce__`: rebuilt, on the device of its state, in its mode."""
    net = EquivariantPixelQNetwork(**init_kwargs)
    tensors = [v for v in state.values() if isinstance(v, torch.Tensor)]
    if tensors:
        net.to(tensors[0].device)
    net.load_state_dict(state)
    return net.train(training)


__all__ = ["EquivariantPixelQNetwork", "PAD_MULTIPLE", "symmetric_padding"]
