"""Action masks of the pixelwise agents: which (primitive, rotation, row, col) actions can touch anything.

A grasp at a pixel where the heightmap shows bare table closes the jaws on nothing, whatever the network says, and
a slide whose path holds no object pushes air. Masking those actions out is the "common sense" action space of
Hundt et al. (2020, *"Good Robot!"*): the argmax, the ε-random exploration and the bootstrap's ``max_a' Q(s', a')``
all range over the actions that can change something. It changes no reward and leaves the network free to rank the
remaining actions; on a 64 px map of 10 objects it removes about 90% of the grasps and 93% of the slides.

A slide is allowed where its start is bare table (nothing within ``slide_clear_px``, so the closed fingertips come
down to their lowest height, :meth:`~maniskill_pnp.cell.workspace.WorkspaceSpec.slide_tip_height`) and material lies
ahead on its path, within ``slide_ahead_px`` along the push direction of its rotation and side
(:meth:`~maniskill_pnp.cell.workspace.WorkspaceSpec.slide_direction`). A start merely *near* material is not
enough: the greedy policy of an early G&S run repeated a slide that began beside an object and pushed away from it.

With ``slide_length_px`` no slide is offered that would push material off the heightmap (out of the workspace,
where the object is lost). Along the push, within the pusher's width (``slide_band_px`` either side), the pusher
meets material at some step ``t0`` of its ``L`` steps and carries it the remaining ``L - t0``; material further on is
carried too where the push closes the gap to it, by what is left. Compacted against the pusher, the carried material
then ends ``L + M`` steps from the start, ``M`` being the carried material's steps past the first contact. A slide
whose carried material would end beyond the heightmap's edge is masked out. It reads only the heightmap: objects do
not turn or spread sideways in this picture, so it is a first-order model of the push, not a simulation.

With ``reach`` (the arm's :class:`~maniskill_pnp.cell.reach_map.ReachMap` read per rotation and pixel) only what the
arm can reach is offered: grasps where its IK reaches the grasp and the pre-grasp, slides whose start and end it
reaches.

With ``grasp_fit`` a grasp must also *fit* where the heightmap shows it (the "predicted to fail" masks of SPOT):
the open Panda gripper (its fingers' collision boxes and its hand's hull, from the robot's URDF) lowered straight down
to the grasp's fingertip height (:meth:`~maniskill_pnp.cell.workspace.WorkspaceSpec.grasp_tcp_height` of the height at
the pixel) must stay above every height of the map under it, within ``fit_tolerance``. A grasp whose fingers would
strike a neighbour (an object in a row pressed against others, a 1-3 mm gap that the map cannot resolve) or land on
the object itself (wider than the open jaws) is masked out, so a grasp-and-slide agent facing a locked arrangement
has only its slides left. Where no grasp fits and no other primitive may act (a grasp-only agent, or no slide
starts anywhere), the grasps fall back to the material test, so the agent still acts. It is the heightmap's view
of :mod:`~maniskill_pnp.scenes.grasp_feasibility` (which sees the collision shapes): no object state, only what the
camera shows. Given a *fit heightmap* (the env's ``fit_heightmap``: the same camera points on a grid ``k`` times finer,
see :attr:`~maniskill_pnp.cell.workspace.WorkspaceSpec.fit_scale`) the test reads that instead, so the pads' edges and
the friction slope are judged at ``pixel_size / k``; the network keeps its heightmap.

The mask is a pure function of the height channel, so it costs no replay storage: the actor computes it from the
current heightmap and the loss from the next one.

Example:
    >>> mask = HeightmapActionMask(("grasp",), num_rotations=4)
    >>> mask(torch.zeros(1, 32, 32)).shape  # (B, P*R*H*W) booleans; an empty map allows every action
    torch.Size([1, 4096])
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import functools
from functools import cached_property

import torch
import torch.nn.functional as F

from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.heightmap_fit import FIT_TOLERANCE, HeightmapGraspFit, pusher_half_width

#: Primitive names the mask knows: grasps need material at the pixel, slides material ahead on their path.
GRASP, SLIDES = "grasp", ("left_slide", "right_slide")


@dataclass(frozen=True)
class HeightmapActionMask:
    """Boolean mask over the flat pixel actions of a heightmap.

    Args:
        primitives: Primitive names in action order (``"grasp"``, ``"left_slide"``, ``"right_slide"``).
        num_rotations: Rotations per primitive; they set the slides' push directions (the workspace convention:
            rotation ``r`` closes the jaws along ``r * 360° / num_rotations`` from world x, which is the column axis).
        min_height: A pixel holds material when its height above the table (m) is more than this; None: no
            material test (every pixel of an enabled primitive is allowed).
        slide_clear_px: A slide may start only where no material lies within this many pixels (Chebyshev
            distance); 0: only the start pixel itself must be bare.
        slide_ahead_px: ... and where material lies within this many pixels ahead along its push direction.
        enabled: Primitives that may act at all (None: all); the others are masked out everywhere, e.g.
            ``("grasp",)`` restricts a grasp-and-slide agent to its grasps.
        grasp_fit: Also mask out grasps where the open gripper, lowered to the grasp's depth, would strike the
            heightmap (needs ``min_height``).
        pixel_size: Side of a heightmap pixel (m), for ``grasp_fit``.
        grasp_depth: How far below the height at the pixel the fingertip TCP goes (m), for ``grasp_fit``.
        min_tip_height: The fingertip TCP never goes below this height above the table (m), for ``grasp_fit``.
        fit_tolerance: A gripper point may be this far (m) below a height of the map and still count as clear.
        slide_length_px: The slide's length in pixels: with it, slides that would carry material off the heightmap
            are masked out (see the module docstring); None: no such test.
        slide_band_px: Half the pusher's width across the push, in pixels, for ``slide_length_px``.
        reach: ``bool (R, H, W)``: the rotations and pixels the arm reaches (:meth:`ReachMap.pixels
            <maniskill_pnp.cell.reach_map.ReachMap.pixels>`); None: no reach test.
    """

    primitives: tuple[str, ...]
    num_rotations: int
    min_height: float | None = 0.01
    slide_clear_px: int = 1
    slide_ahead_px: int = 6
    enabled: tuple[str, ...] | None = None
    grasp_fit: bool = False
    pixel_size: float = 0.002
    grasp_depth: float = 0.02
    min_tip_height: float = 0.012
    fit_tolerance: float = FIT_TOLERANCE
    slide_length_px: int | None = None
    slide_band_px: int = 3
    reach: torch.Tensor | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "primitives", tuple(self.primitives))
        unknown = [p for p in self.primitives if p != GRASP and p not in SLIDES]
        if not self.primitives or unknown:
            raise ValueError(f"primitives must be names among {(GRASP, *SLIDES)}, got {self.primitives!r}")
        if not isinstance(self.num_rotations, int) or self.num_rotations < 1:
            raise ValueError(f"num_rotations must be a positive int, got {self.num_rotations!r}")
        if self.min_height is not None and self.min_height < 0:
            raise ValueError(f"min_height must be >= 0 (m), got {self.min_height}")
        if self.slide_clear_px < 0 or self.slide_ahead_px < 1:
            raise ValueError(
                f"slide_clear_px must be >= 0 and slide_ahead_px >= 1, got {self.slide_clear_px}, {self.slide_ahead_px}"
            )
        if self.enabled is not None:
            object.__setattr__(self, "enabled", tuple(self.enabled))
            if not self.enabled or set(self.enabled) - set(self.primitives):
                raise ValueError(f"enabled must be a non-empty subset of {self.primitives}, got {self.enabled!r}")
        if self.slide_length_px is not None and not (isinstance(self.slide_length_px, int) and self.slide_length_px >= 1):
            raise ValueError(f"slide_length_px must be a positive int or None, got {self.slide_length_px!r}")
        if not (isinstance(self.slide_band_px, int) and self.slide_band_px >= 0):
            raise ValueError(f"slide_band_px must be an int >= 0, got {self.slide_band_px!r}")
        if self.reach is not None:
            reach = torch.as_tensor(self.reach, dtype=torch.bool)
            if reach.ndim != 3 or reach.shape[0] != self.num_rotations:
                raise ValueError(f"reach must be (num_rotations={self.num_rotations}, H, W) booleans, got shape "
                                 f"{tuple(reach.shape)}")
            object.__setattr__(self, "reach", reach)
        if self.grasp_fit and self.min_height is None:
            raise ValueError("grasp_fit needs the material test (a min_height)")
        if not self.pixel_size > 0 or self.min_tip_height < 0 or self.fit_tolerance < 0:
            raise ValueError(
                f"pixel_size must be > 0, min_tip_height and fit_tolerance >= 0 (m), got {self.pixel_size!r}, "
                f"{self.min_tip_height!r}, {self.fit_tolerance!r}"
            )

    def to_json(self) -> dict:
        """The mask's settings as JSON values; ``reach`` as the share of the (rotation, pixel) grasps it keeps."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "reach"}
        out["reach"] = None if self.reach is None else round(float(self.reach.float().mean()), 4)
        return out

    @classmethod
    def for_workspace(cls, primitives, workspace: WorkspaceSpec, ahead_fraction: float = 0.5, keep_in: bool = False,
                      **kwargs):
        """The mask of a workspace: slides start clear of material by its ``slide_clearance`` and must meet material
        within ``ahead_fraction`` of its ``slide_length`` (so a slide moves what it meets by at least the rest); with
        ``keep_in``, slides that would carry material off the heightmap are masked out (the slide's length and the
        closed Panda fingers' width across the push, in pixels)."""
        if not 0 < ahead_fraction <= 1:
            raise ValueError(f"ahead_fraction must be in (0, 1], got {ahead_fraction!r}")
        px = workspace.pixel_size
        if keep_in:
            kwargs.update(slide_length_px=max(1, int(round(workspace.slide_length / px))),
                          slide_band_px=int(round(pusher_half_width() / px)))
        return cls(
            primitives, workspace.num_rotations, slide_clear_px=int(round(workspace.slide_clearance / px)),
            slide_ahead_px=max(1, int(round(ahead_fraction * workspace.slide_length / px))), pixel_size=px,
            grasp_depth=workspace.finger_length - workspace.grasp_z_offset, min_tip_height=workspace.min_tip_height,
            **kwargs,
        )

    @cached_property
    def _fit(self) -> HeightmapGraspFit:
        return HeightmapGraspFit(self.num_rotations, self.pixel_size, self.grasp_depth, self.min_tip_height,
                                 self.fit_tolerance)

    def grasp_fits(self, height: torch.Tensor, where: torch.Tensor, fit: torch.Tensor | None = None) -> torch.Tensor:
        """``bool (N, R, H, W)``: at the pixels of ``where`` ``(N, H, W)``, whether a grasp at each rotation fits the
        heightmap ``height`` ``(N, H, W)``, read from the fit heightmap ``fit`` where there is one
        (:class:`~maniskill_pnp.scenes.heightmap_fit.HeightmapGraspFit`); False elsewhere."""
        return self._fit(height, where, fit)

    @cached_property
    def _ahead_kernels(self) -> dict[str, torch.Tensor]:
        """Per slide side, ``(R, 1, K, K)`` line kernels: 1 at the pixels 1..``slide_ahead_px`` ahead of the centre
        along the push direction of each rotation (cross-correlation, so output pixel (r, c) sums the input ahead of
        it). Built once per mask."""
        k = self.slide_ahead_px
        ws = WorkspaceSpec(num_rotations=self.num_rotations)
        steps = torch.linspace(0.5, k, 2 * k, dtype=torch.float64)
        kernels = {}
        for side in ("left", "right"):
            lines = torch.zeros(self.num_rotations, 1, 2 * k + 1, 2 * k + 1)
            for rot in range(self.num_rotations):
                dx, dy = ws.slide_direction(rot, side)  # columns follow world x, rows world y
                lines[rot, 0, torch.round(k + steps * dy).long(), torch.round(k + steps * dx).long()] = 1.0
                lines[rot, 0, k, k] = 0.0  # the start pixel is not ahead of itself
            kernels[side] = lines
        return kernels

    @cached_property
    def _push_rays(self) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The pusher's band and path, built once per mask: ``(band, steps)``. ``band`` ``(R, 1, K, K)``: per rotation,
        a line kernel across the push direction, ``slide_band_px`` either side of the centre (both sides push along
        one line). ``steps[side]`` ``(R, T, 2)``: the (row, col) offsets of the steps 1..T along each rotation's push,
        ``T`` three slide lengths."""
        b, n = self.slide_band_px, 3 * self.slide_length_px
        ws = WorkspaceSpec(num_rotations=self.num_rotations)
        across = torch.linspace(-b, b, 4 * b + 1, dtype=torch.float64)
        band = torch.zeros(self.num_rotations, 1, 2 * b + 1, 2 * b + 1)
        t = torch.arange(1, n + 1, dtype=torch.float64)
        steps = {side: torch.zeros(self.num_rotations, n, 2, dtype=torch.long) for side in ("left", "right")}
        for rot in range(self.num_rotations):
            dx, dy = ws.slide_direction(rot, "left")  # columns follow world x, rows world y
            band[rot, 0, torch.round(b + across * dx).long(), torch.round(b - across * dy).long()] = 1.0
            for side, sign in (("left", 1.0), ("right", -1.0)):
                steps[side][rot] = torch.stack([torch.round(sign * t * dy), torch.round(sign * t * dx)], dim=1).long()
        return band, steps

    @functools.lru_cache(maxsize=8)
    def _push_paths(self, side: str, h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
        """For an ``h`` x ``w`` map: ``(offsets, off)``. ``offsets`` ``(R, T)``: the steps along each rotation's push as
        offsets into the map padded by ``T`` on every side, flattened; ``off`` ``(R, h, w)``: per start pixel, the
        first step whose pixel lies off the map (``T + 1`` where none does)."""
        steps = self._push_rays[1][side]
        n = steps.shape[1]
        offsets = steps[..., 0] * (w + 2 * n) + steps[..., 1]
        rows = torch.arange(h)[None, :, None, None] + steps[:, None, None, :, 0]  # (R, h, 1, T)
        cols = torch.arange(w)[None, None, :, None] + steps[:, None, None, :, 1]  # (R, 1, w, T)
        outside = (rows < 0) | (rows >= h) | (cols < 0) | (cols >= w)  # (R, h, w, T)
        off = torch.where(outside.any(dim=-1), outside.float().argmax(dim=-1) + 1, torch.tensor(n + 1))
        return offsets, off

    def slides_keep_in(self, occupied: torch.Tensor, side: str, where: torch.Tensor) -> torch.Tensor:
        """``bool (N, R, H, W)``: at the slide starts ``where`` ``(N, R, H, W)``, whether the slide to ``side`` keeps
        the material it carries on the heightmap (see the module docstring); True elsewhere. ``occupied``
        ``(N, 1, H, W)``: the material pixels."""
        return self._keeps_in(self._under_band(occupied), side, where)

    def _under_band(self, occupied: torch.Tensor) -> torch.Tensor:
        """``bool (N, R, H, W)``: whether material lies under the pusher's band of each rotation centred at each pixel
        (the same for both sides)."""
        band = self._push_rays[0].to(occupied.device)
        return F.conv2d(occupied.float(), band, padding=self.slide_band_px) > 0

    def _keeps_in(self, under: torch.Tensor, side: str, where: torch.Tensor) -> torch.Tensor:
        """:meth:`slides_keep_in` from the material under the band (:meth:`_under_band`)."""
        keep = torch.ones_like(where)
        at = where.nonzero(as_tuple=True)
        if not len(at[0]):
            return keep
        _, r, h, w = under.shape
        dev, length = under.device, self.slide_length_px
        offsets, off = (v.to(dev) for v in self._push_paths(side, h, w))
        t_max = offsets.shape[1]
        ahead = F.pad(under, (t_max, t_max, t_max, t_max)).flatten()  # the map padded with bare table
        size = (h + 2 * t_max) * (w + 2 * t_max)
        base = (at[0] * r + at[1]) * size + (at[2] + t_max) * (w + 2 * t_max) + at[3] + t_max
        met = ahead[base[:, None] + offsets[at[1]]]  # (K, T): material under the pusher at each step
        contact = met[:, :length].any(dim=1)
        t0 = met[:, :length].to(torch.uint8).argmax(dim=1, keepdim=True) + 1  # the first contact's step (1-based)
        gaps = torch.cumsum(~met, dim=1)  # empty steps up to each step
        steps = torch.arange(1, t_max + 1, device=dev)
        carried = met & (steps > t0) & (gaps - gaps.gather(1, t0 - 1) < length - t0)
        front = length + carried.sum(dim=1)  # the step where the carried material's leading pixel ends
        keep[at] = ~(contact & (front >= off[at[1], at[2], at[3]]))
        return keep

    def _reached(self, name: str, device: torch.device) -> torch.Tensor:
        """``bool (R, H, W)``: where primitive ``name`` is within the arm's reach: a grasp where :attr:`reach` says so,
        a slide where its start and its end (``slide_length_px`` on, or the ahead test's reach, along its push; an end
        off the map counts as the nearest pixel) are."""
        cache = self.__dict__.setdefault("_reached_maps", {})  # per instance: masks equal but for their reach differ
        if (name, device) not in cache:
            cache[name, device] = self._reach_of(name).to(device)
        return cache[name, device]

    def _reach_of(self, name: str) -> torch.Tensor:
        reach = self.reach
        if name == GRASP:
            return reach
        r, h, w = reach.shape
        ws = WorkspaceSpec(num_rotations=r)
        length = self.slide_length_px or 2 * self.slide_ahead_px
        rows, cols = torch.arange(h)[:, None], torch.arange(w)[None, :]
        ends = torch.zeros_like(reach)
        for rot in range(r):
            dx, dy = ws.slide_direction(rot, name.removesuffix("_slide"))
            er = (rows + round(length * dy)).clamp(0, h - 1).expand(h, w)
            ec = (cols + round(length * dx)).clamp(0, w - 1).expand(h, w)
            ends[rot] = reach[rot][er, ec]
        return reach & ends

    def pixel_masks(self, height: torch.Tensor, fit: torch.Tensor | None = None) -> torch.Tensor:
        """Per-primitive, per-rotation pixel masks ``(*B, P, R, H, W)`` of heights ``(*B, H, W)`` (m above the table);
        ``fit`` ``(*B, k·H, k·W)``: the fit heightmap the grasp-fit test reads (see :meth:`grasp_fits`)."""
        if height.ndim < 2:
            raise ValueError(f"height must be (*B, H, W), got shape {tuple(height.shape)}")
        batch, (h, w), rots = height.shape[:-2], height.shape[-2:], self.num_rotations
        flat = height.reshape(-1, 1, h, w)
        if fit is not None:
            fit = fit.reshape(-1, *fit.shape[-2:])
        n = flat.shape[0]
        if self.min_height is None:
            occupied = torch.ones_like(flat, dtype=torch.bool)
        else:
            occupied = flat > self.min_height
        c = self.slide_clear_px
        clear = ~(F.max_pool2d(occupied.float(), 2 * c + 1, stride=1, padding=c) > 0)  # bare-table slide starts
        under = None  # the material under the pusher's band, shared by both slide sides
        masks = []
        for name in self.primitives:
            if self.enabled is not None and name not in self.enabled:
                masks.append(torch.zeros(n, rots, h, w, dtype=torch.bool, device=flat.device))
                continue
            # reach first: the costlier tests below then look at fewer actions
            reached = None if self.reach is None else self._reached(name, flat.device).expand(n, rots, h, w)
            if name == GRASP and self.grasp_fit:
                fits = self.grasp_fits(flat[:, 0], occupied[:, 0] & (True if reached is None else reached.any(dim=1)), fit)
                masks.append(fits if reached is None else fits & reached)
            elif name == GRASP or self.min_height is None:
                allowed = occupied.expand(n, rots, h, w)
                masks.append(allowed if reached is None else allowed & reached)
            else:
                side = name.removesuffix("_slide")
                kernels = self._ahead_kernels[side].to(flat.device)
                allowed = clear & (F.conv2d(occupied.float(), kernels, padding=self.slide_ahead_px) > 0)
                if reached is not None:
                    allowed = allowed & reached
                if self.slide_length_px is not None:
                    under = self._under_band(occupied) if under is None else under
                    allowed = allowed & self._keeps_in(under, side, allowed)
                masks.append(allowed)
        if self.grasp_fit and GRASP in self.primitives and (self.enabled is None or GRASP in self.enabled):
            # Where no grasp fits and no other primitive may act, grasps fall back to the material test.
            g = self.primitives.index(GRASP)
            stuck = ~torch.stack([m.flatten(1).any(dim=1) for m in masks], dim=1).any(dim=1)[:, None, None, None]
            masks[g] = torch.where(stuck, occupied.expand(n, rots, h, w), masks[g])
        return torch.stack(masks, dim=1).reshape(*batch, len(self.primitives), rots, h, w)

    def __call__(self, height: torch.Tensor, fit: torch.Tensor | None = None) -> torch.Tensor:
        """Flat action mask ``(*B, P*R*H*W)`` (PixelActionLayout order) of heights ``(*B, H, W)``, with the fit
        heightmap ``fit`` (see :meth:`grasp_fits`) where there is one.

        Where the material test leaves no action (nothing on the table), every action of the enabled primitives
        is allowed, so the mask is never empty.
        """
        flat = self.pixel_masks(height, fit).flatten(-4)
        empty = ~flat.any(dim=-1, keepdim=True)
        if self.enabled is None:
            return flat | empty
        on = torch.tensor([p in self.enabled for p in self.primitives], device=flat.device)
        on = on.repeat_interleave(flat.shape[-1] // len(self.primitives))
        return flat | (empty & on)

    def from_observation(self, observation: torch.Tensor, fit: torch.Tensor | None = None) -> torch.Tensor:
        """Flat mask of network inputs ``(*B, 4, H, W)`` (height in channel 3) and their fit heightmaps."""
        return self(observation[..., 3, :, :], fit)


__all__ = ["FIT_TOLERANCE", "HeightmapActionMask"]
