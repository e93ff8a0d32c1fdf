"""Fully convolutional pixelwise Q networks over rotated RGB-D heightmaps (thesis Parts II and III).

A :class:`PixelQNetwork` maps a heightmap batch ``(B, 4, H, W)`` (RGB in 0..1, height above the table in metres) to
one Q map per rotation, ``(B, R, H, W)``. Its structure follows the thesis (and VPG):

* the heightmap is rotated ``R`` times so that the jaw direction of rotation ``r`` becomes the image's +col axis
  (the input is first zero-padded to a square at least as large as its diagonal, so no content is cut);
* all ``B * R`` rotated images go through the network in one batch;
* two trunks, one on the colour image and one on the height channel cloned to 3 channels (``use_depth=False``
  keeps the colour trunk only); their feature maps are concatenated;
* a head of two 1x1 convolutions, each preceded by BatchNorm + ReLU, the last giving one channel;
* bilinear upsampling to the padded resolution, aligned so each pixel reads the features centred on it
  (:meth:`PixelQNetwork.upsample`), rotation back, and a centre crop to ``H x W``.

Rotation ``r`` is the one of :class:`~maniskill_pnp.cell.workspace.WorkspaceSpec`: jaws closing along
``yaw = r * 2*pi / R`` from world x, where the heightmap's col axis is world x and its row axis world y.

:class:`MultiPrimitiveQNetwork` holds one Q network per primitive (grasp; left slide; right slide), a
:class:`PixelQNetwork` or, with the ``"equivariant"`` backbone, an
:class:`~maniskill_pnp.agents.pixel.equivariant.EquivariantPixelQNetwork`, and stacks their maps to
``(B, P, R, H, W)``, whose row-major flat index is the one of :class:`~maniskill_pnp.cell.pixel_action.PixelActionLayout`.

Backbones (``backbone=``):

* ``"densenet121"`` (thesis default): ``torchvision.models.densenet121(memory_efficient=True).features``,
  1024 channels at stride 32.
* ``"resnet101"`` (the thesis' ablation): ResNet-101 up to ``layer4``, 2048 channels at stride 32.
* ``"densenet121-s8"`` / ``"resnet101-s8"``: the thesis' pair cut to stride 8 (DenseNet-121 up to its second dense
  block, ResNet-101 up to ``layer2``; 512 channels each), for heightmaps of 64 px, where the whole trunks leave a
  2 x 2 feature map. Their weights keep the torchvision layout of the full classifier.
* ``"small"`` (CPU presets and tests): ResNet-18 truncated after ``layer2``, 128 channels at stride 8. It keeps
  the torchvision weight layout (so a local ResNet-18 checkpoint can initialise it), costs about a tenth of a
  DenseNet-121 trunk per pixel and, at stride 8, still gives usable maps on small heightmaps.

* ``"equivariant"``: no rotated copies at all: a small ``C_R``-equivariant network (e2cnn steerable convolutions)
  whose output fibre is one Q map per rotation, from a single forward pass on the unrotated heightmap; the grasp
  net ties each jaw orientation to the one turned by 180 degrees. See
  :class:`~maniskill_pnp.agents.pixel.equivariant.EquivariantPixelQNetwork`; :class:`MultiPrimitiveQNetwork` builds
  it instead of a :class:`PixelQNetwork` (:func:`make_pixel_q_network`). It has no pretrained weights.

Pretrained weights are never downloaded: pass ``pretrained_path``, a local file holding the ``state_dict`` of the
complete torchvision classifier of the chosen backbone; it is loaded strictly, then truncated to the trunk.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Callable, Sequence

import torch
import torch.nn.functional as F
import torchvision
from torch import nn

from maniskill_pnp.agents.pixel.rotations import rotation_query
from maniskill_pnp.cell.pixel_action import PixelActionLayout

#: ImageNet statistics, used to normalise both trunks' inputs (as torchvision's pretrained weights expect).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class _Backbone:
    build: Callable[[], nn.Module]
    truncate: Callable[[nn.Module], nn.Module]
    channels: int
    stride: int
    #: Input pixel at the centre of feature 0's receptive field: feature ``i`` is centred on ``offset + stride * i``
    #: (ResNets: strided convolutions centre on ``stride * i``; DenseNet's 2x2 average-pool transitions add 14 px).
    offset: float


def _resnet_trunk(last_layer: str) -> Callable[[nn.Module], nn.Module]:
    def truncate(model: nn.Module) -> nn.Module:
        names = ["conv1", "bn1", "relu", "maxpool", "layer1", "layer2", "layer3", "layer4"]
        names = names[: names.index(last_layer) + 1]
        return nn.Sequential(*[getattr(model, n) for n in names])

    return truncate


def _densenet121() -> nn.Module:
    return torchvision.models.densenet121(weights=None, memory_efficient=True)


def _resnet101() -> nn.Module:
    return torchvision.models.resnet101(weights=None)


BACKBONES: dict[str, _Backbone] = {
    "densenet121": _Backbone(
        build=_densenet121,
        truncate=lambda m: m.features,
        channels=1024,
        stride=32,
        offset=14.0,
    ),
    "resnet101": _Backbone(
        build=_resnet101,
        truncate=_resnet_trunk("layer4"),
        channels=2048,
        stride=32,
        offset=0.0,
    ),
    "densenet121-s8": _Backbone(
        build=_densenet121,
        truncate=lambda m: m.features[:7],  # conv0 .. pool0, denseblock1, transition1, denseblock2
        channels=512,
        stride=8,
        offset=2.0,
    ),
    "resnet101-s8": _Backbone(
        build=_resnet101,
        truncate=_resnet_trunk("layer2"),
        channels=512,
        stride=8,
        offset=0.0,
    ),
    "small": _Backbone(
        build=lambda: torchvision.models.resnet18(weights=None),
        truncate=_resnet_trunk("layer2"),
        channels=128,
        stride=8,
        offset=0.0,
    ),
}


#: The backbone that is not a trunk of :class:`PixelQNetwork` but a rotation-equivariant network of its own.
EQUIVARIANT = "equivariant"
#: Every backbone a :class:`MultiPrimitiveQNetwork` can be built with.
BACKBONE_CHOICES = tuple(sorted([*BACKBONES, EQUIVARIANT]))
#: Primitives whose action is the same when the jaws are turned by 180 degrees (rotation ``r`` and ``r + R/2``): the
#: equivariant backbone ties their maps.
HALF_TURN_SYMMETRIC = frozenset({"grasp"})


def make_trunk(backbone: str, pretrained_path: str | os.PathLike | None = None) -> nn.Module:
    """A feature trunk of ``backbone`` (a key of :data:`BACKBONES`), optionally initialised from a local file.

    Raises:
        ValueError: unknown backbone.
        FileNotFoundError: ``pretrained_path`` does not exist.
    """
    if backbone not in BACKBONES:
        raise ValueError(f"backbone must be one of {sorted(BACKBONES)}, got {backbone!r}")
    spec = BACKBONES[backbone]
    model = spec.build()
    if pretrained_path is not None:
        if not os.path.isfile(pretrained_path):
            raise FileNotFoundError(f"pretrained weights not found: {pretrained_path}")
        state = torch.load(pretrained_path, map_location="cpu", weights_only=True)
        model.load_state_dict(state, strict=True)
    return spec.truncate(model)


def rotation_angles(num_rotations: int) -> torch.Tensor:
    """Yaw (rad) of each rotation index: ``r * 2*pi / num_rotations``."""
    return torch.arange(num_rotations, dtype=torch.float64) * (2 * math.pi / num_rotations)


def rotate_images(images: torch.Tensor, angles: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
    """Rotate square images ``(N, C, S, S)`` about their centre; image ``n`` by ``angles[n]`` (rad).

    Angles are measured in the (col, row) frame, i.e. from world x towards world y. Positive ``angle`` rotates
    the *frame*: the output's +col axis points along the input direction ``angle``, so ``rotate_images(x, a)``
    turns the content by ``-a``. Pixels coming from outside the image are zero.
    """
    if images.shape[-1] != images.shape[-2]:
        raise ValueError(f"rotate_images needs square images, got {tuple(images.shape[-2:])}")
    a = angles.to(torch.float64)
    cos, sin = torch.cos(a), torch.sin(a)
    zero = torch.zeros_like(a)
    # affine_grid's theta maps output normalised coords to input coords: input = Rot(angle) @ output.
    theta = torch.stack([torch.stack([cos, -sin, zero], -1), torch.stack([sin, cos, zero], -1)], -2)
    theta = theta.to(device=images.device, dtype=images.dtype)
    grid = F.affine_grid(theta, list(images.shape), align_corners=False)
    return F.grid_sample(images, grid, mode=mode, padding_mode="zeros", align_corners=False)


def padded_size(height: int, width: int, multiple: int) -> int:
    """Side of the square that holds an ``height x width`` image under any rotation.

    At least the diagonal and of the same parity as both sides, so that the padding is symmetric and the centre
    stays the centre (exact 90-degree equivariance); also a multiple of ``multiple`` (the trunk's stride) when that
    parity allows it.
    """
    if (height - width) % 2:
        raise ValueError(f"height and width must have the same parity, got {height}x{width}")
    side = math.ceil(math.hypot(height, width))
    side = max(side, height, width)
    if multiple % 2 == 0 and height % 2:
        multiple = 1  # an odd side cannot be padded symmetrically to an even multiple: keep the symmetry
    while side % multiple or (side - height) % 2:
        side += 1
    return side


class PixelQNetwork(nn.Module):
    """Rotated fully convolutional Q network: ``(B, 4, H, W)`` heightmap -> ``(B, R, H, W)`` Q maps.

    Args:
        num_rotations: Number of rotations ``R`` (the thesis uses 16).
        backbone: A key of :data:`BACKBONES` (see the module docstring).
        use_depth: Keep the depth trunk (False: the thesis' "no depth" ablation, colour trunk only).
        head_channels: Width of the hidden 1x1 convolution.
        pretrained_path: Local ``state_dict`` of the full torchvision classifier, loaded into both trunks.
        depth_mean: Subtracted from heights (m) before the depth trunk.
        depth_std: Heights are divided by this (m) after ``depth_mean`` is subtracted.

    Example:
        >>> net = PixelQNetwork(num_rotations=4, backbone="small").eval()
        >>> net(torch.zeros(2, 4, 32, 32)).shape
        torch.Size([2, 4, 32, 32])
    """

    def __init__(
        self,
        *,
        num_rotations: int = 16,
        backbone: str = "densenet121",
        use_depth: bool = True,
        head_channels: int = 64,
        pretrained_path: str | os.PathLike | None = None,
        depth_mean: float = 0.01,
        depth_std: float = 0.03,
    ):
        super().__init__()
        if not isinstance(num_rotations, int) or isinstance(num_rotations, bool) or num_rotations <= 0:
            raise ValueError(f"num_rotations must be a positive integer, got {num_rotations!r}")
        if head_channels <= 0:
            raise ValueError(f"head_channels must be positive, got {head_channels!r}")
        if not depth_std > 0:
            raise ValueError(f"depth_std must be > 0, got {depth_std!r}")
        spec = BACKBONES.get(backbone)
        if spec is None:
            raise ValueError(f"backbone must be one of {sorted(BACKBONES)}, got {backbone!r}")
        self.num_rotations = num_rotations
        self.backbone = backbone
        self.use_depth = use_depth
        self.stride = spec.stride
        self.offset = spec.offset
        self.depth_mean = float(depth_mean)
        self.depth_std = float(depth_std)
        self.color_trunk = make_trunk(backbone, pretrained_path)
        self.depth_trunk = make_trunk(backbone, pretrained_path) if use_depth else None
        features = spec.channels * (2 if use_depth else 1)
        self.head = nn.Sequential(
            nn.BatchNorm2d(features),
            nn.ReLU(inplace=True),
            nn.Conv2d(features, head_channels, kernel_size=1, bias=False),
            nn.BatchNorm2d(head_channels),
            nn.ReLU(inplace=True),
            nn.Conv2d(head_channels, 1, kernel_size=1, bias=False),
        )
        self.register_buffer("angles", rotation_angles(num_rotations).float(), persistent=False)
        self.register_buffer("rgb_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def _features(self, heightmaps: torch.Tensor) -> torch.Tensor:
        color = (heightmaps[:, :3] - self.rgb_mean) / self.rgb_std
        feats = [self.color_trunk(color)]
        if self.depth_trunk is not None:
            depth = (heightmaps[:, 3:4] - self.depth_mean) / self.depth_std
            depth = (depth.expand(-1, 3, -1, -1) - self.rgb_mean) / self.rgb_std
            feats.append(self.depth_trunk(depth))
        return torch.cat(feats, dim=1)

    def _maps_at(self, x: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
        """Q map ``(N, H, W)`` of each heightmap ``x[n]`` ``(N, 4, H, W)`` at the rotation ``angles[n]`` (rad)."""
        H, W = x.shape[-2:]
        S = padded_size(H, W, self.stride)
        top, left = (S - H) // 2, (S - W) // 2
        x = rotate_images(F.pad(x, (left, S - W - left, top, S - H - top)), angles)
        q = self.upsample(self.head(self._features(x)), S)
        q = rotate_images(q, -angles)
        return q[:, 0, top : top + H, left : left + W]

    def upsample(self, q: torch.Tensor, size: int) -> torch.Tensor:
        """Bilinear upsampling of feature-grid maps ``(N, C, h, w)`` to ``(N, C, size, size)`` pixels, aligned so
        that pixel ``j`` reads the features at grid coordinate ``(j - offset) / stride``: each pixel's value comes
        from the features whose receptive fields are centred on it (a plain ``interpolate`` would shift the maps by
        up to half a stride, 3.5 px for the small trunk and 15.5 px for ResNet-101)."""
        h, w = q.shape[-2:]
        u = (torch.arange(size, device=q.device, dtype=q.dtype) - self.offset) / self.stride

        def normalized(n: int) -> torch.Tensor:  # grid_sample coordinates with align_corners=True
            return 2.0 * u / (n - 1) - 1.0 if n > 1 else torch.zeros_like(u)

        gy, gx = torch.meshgrid(normalized(h), normalized(w), indexing="ij")
        grid = torch.stack([gx, gy], dim=-1).expand(q.shape[0], size, size, 2)
        return F.grid_sample(q, grid, mode="bilinear", padding_mode="border", align_corners=True)

    @staticmethod
    def _check(heightmaps: torch.Tensor) -> None:
        if heightmaps.ndim < 4 or heightmaps.shape[-3] != 4:
            raise ValueError(f"heightmaps must be (..., 4, H, W) (RGB + height), got {tuple(heightmaps.shape)}")

    def forward(self, heightmaps: torch.Tensor) -> torch.Tensor:
        """Q maps ``(*batch, R, H, W)`` of heightmaps ``(*batch, 4, H, W)``."""
        self._check(heightmaps)
        batch = heightmaps.shape[:-3]
        H, W = heightmaps.shape[-2:]
        x = heightmaps.reshape(-1, 4, H, W)
        B, R = x.shape[0], self.num_rotations
        # (B, R, 4, H, W) -> (B*R, 4, H, W): every rotation in one batch.
        q = self._maps_at(x.repeat_interleave(R, dim=0), self.angles.repeat(B))
        return q.reshape(*batch, R, H, W)

    def rotation_maps(self, heightmaps: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
        """Q map ``(N, H, W)`` of each heightmap ``(N, 4, H, W)`` at its rotation index ``rotation[n]`` only.

        What a training step needs for the executed action: one rotated image per sample instead of ``R``
        (VPG trains the same way). In eval mode it equals ``forward(heightmaps)[n, rotation[n]]``; in train
        mode BatchNorm sees a batch of ``N`` images instead of ``N * R``.
        """
        self._check(heightmaps)
        rotation = rotation_query(heightmaps, rotation, self.num_rotations)
        return self._maps_at(heightmaps, self.angles[rotation])


def make_pixel_q_network(primitive: str, *, backbone: str = "densenet121",
                         pretrained_path: str | os.PathLike | None = None, **net_kwargs) -> nn.Module:
    """The Q network of one primitive: a :class:`PixelQNetwork` with a trunk ``backbone``, or for ``"equivariant"``
    an :class:`~maniskill_pnp.agents.pixel.equivariant.EquivariantPixelQNetwork`, whose maps ``r`` and ``r + R/2``
    are tied for the primitives of :data:`HALF_TURN_SYMMETRIC` (the grasp) and free for the others (slides).

    ``net_kwargs``: ``num_rotations``, ``use_depth``, ``head_channels``, ``depth_mean``, ``depth_std`` (both kinds).

    Raises:
        ValueError: an unknown backbone, or a ``pretrained_path`` for the equivariant one.
    """
    if backbone not in BACKBONE_CHOICES:
        raise ValueError(f"backbone must be one of {list(BACKBONE_CHOICES)}, got {backbone!r}")
    if backbone != EQUIVARIANT:
        return PixelQNetwork(backbone=backbone, pretrained_path=pretrained_path, **net_kwargs)
    if pretrained_path is not None:
        raise ValueError("the equivariant backbone has no pretrained weights: pretrained_path must be None")
    from maniskill_pnp.agents.pixel.equivariant import EquivariantPixelQNetwork  # imports e2cnn (about a second)

    return EquivariantPixelQNetwork(symmetric=primitive in HALF_TURN_SYMMETRIC, **net_kwargs)


class MultiPrimitiveQNetwork(nn.Module):
    """One pixel Q network per primitive: ``(B, 4, H, W)`` -> ``(B, P, R, H, W)``.

    Args:
        primitives: Primitive names, in action-index order (e.g. ``("grasp", "left_slide", "right_slide")``).
        **net_kwargs: Keyword arguments of every primitive's network (:func:`make_pixel_q_network`): those of
            :class:`PixelQNetwork`, whose ``backbone="equivariant"`` builds
            :class:`~maniskill_pnp.agents.pixel.equivariant.EquivariantPixelQNetwork` instead.
    """

    def __init__(self, primitives: Sequence[str] = ("grasp",), **net_kwargs):
        super().__init__()
        primitives = tuple(primitives)
        if not primitives or len(set(primitives)) != len(primitives):
            raise ValueError(f"primitives must be a non-empty sequence of unique names, got {primitives!r}")
        self.primitives = primitives
        self.nets = nn.ModuleDict({name: make_pixel_q_network(name, **net_kwargs) for name in primitives})

    @property
    def num_rotations(self) -> int:
        return self.nets[self.primitives[0]].num_rotations

    def forward(self, heightmaps: torch.Tensor) -> torch.Tensor:
        """Q maps ``(*batch, P, R, H, W)`` of heightmaps ``(*batch, 4, H, W)``."""
        return torch.stack([self.nets[name](heightmaps) for name in self.primitives], dim=-4)

    def executed_values(self, heightmaps: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """``Q(s, a)`` ``(N,)`` at flat actions ``action`` (N entries) of heightmaps ``(N, 4, H, W)``.

        Equal to ``forward(heightmaps).reshape(N, -1)[n, action[n]]`` in eval mode, but only the executed
        primitive's network runs, on the executed rotation's image (:meth:`PixelQNetwork.rotation_maps`): a
        ``P * R`` times smaller forward and backward than the full maps (the equivariant backbone gets every
        rotation from one pass anyway: a ``P`` times smaller one).

        Raises:
            ValueError: a non-integer action or an index outside ``0..P*R*H*W-1``.
        """
        if heightmaps.ndim != 4 or heightmaps.shape[1] != 4:
            raise ValueError(f"heightmaps must be (N, 4, H, W), got {tuple(heightmaps.shape)}")
        n, (H, W) = heightmaps.shape[0], heightmaps.shape[-2:]
        layout = PixelActionLayout(len(self.primitives), self.num_rotations, H, W)
        primitive, rotation, row, col = layout.decode(action.reshape(n))  # raises on a bad dtype or index
        pixel = row * W + col
        values = heightmaps.new_zeros(n)
        for p, name in enumerate(self.primitives):
            rows = (primitive == p).nonzero().squeeze(1)
            if rows.numel():
                maps = self.nets[name].rotation_maps(heightmaps[rows], rotation[rows]).reshape(rows.numel(), H * W)
                values = values.index_put((rows,), maps.gather(1, pixel[rows, None]).squeeze(1))
        return values
