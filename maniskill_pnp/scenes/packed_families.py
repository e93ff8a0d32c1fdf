"""More families of tightly packed arrangements than the hard set's rows and blocks, and a test set of families that
training never draws.

:func:`packed_layout` draws, from a seed, one arrangement of the given families, turned by a random yaw (any angle)
about the workspace centre (within 2 cm of it); every gap between neighbours is 1-3 mm. Each family places its parts
at right angles to each other in its own frame:

* ``arch_nest``: an arch with a cube or an upright cylinder under its lintel, or a U with one inside it, and a bar
  against one or both of the sides left open;
* ``interlock``: two L shapes, one turned by 180 degrees, closing a frame around a block; or a T with a block on
  each side of its stem, against its bar;
* ``tall_block``: a 2 x 2 or 2 x 3 block of low cubes (2-3 cm) in which one or two are tall (6-9 cm);
* ``ring``: 5-7 blocks around an upright cylinder, each 1-3 mm from it and from its neighbours' inner corners (held
  out);
* ``wedge_block``: bars with triangular prisms (``wedge``) leaning on them, the prisms' upright faces against the
  bars' sides (held out).

An arrangement has 3-8 objects. A draw is kept when it passes
:func:`~maniskill_pnp.scenes.layout_check.check_layout` and at least half of its objects are *locked* (no top-down
grasp fits: :func:`~maniskill_pnp.scenes.grasp_feasibility.grasp_feasibility`); otherwise the next draw of the same
seeded generator is tried.

Two shipped sets, written by ``python -m maniskill_pnp.scenes.packed_families [--train]``:

* ``scenes/hard_unseen/unseen_<ii>.yaml``: :data:`UNSEEN_COUNT` scenes of the :data:`HELD_OUT_FAMILIES` (seeds
  :data:`UNSEEN_SEED` + i), the ``hard_unseen`` scenario of ``eval-clutter``. No training draws these families.
* ``scenes/packed_train/train_<ii>.yaml``: :data:`PACKED_TRAIN_COUNT` scenes of the :data:`TRAIN_FAMILIES` (seeds
  :data:`PACKED_TRAIN_SEED` + i), which the clutter tasks' ``hard_fraction`` draws from with
  ``hard_sets=("hard_train", "packed_train")`` (:data:`TRAINING_SETS`), beside the hard set's training arrangements.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import sapien

from maniskill_pnp.cell.workspace import WorkspaceSpec
from maniskill_pnp.scenes.hard_scenes import first_qualifying_draw, hard_train_files, place_parts, write_scene_set
from maniskill_pnp.scenes.objects import PALETTE, ObjectSpec

TRAIN_FAMILIES = ("arch_nest", "interlock", "tall_block")
HELD_OUT_FAMILIES = ("ring", "wedge_block")
FAMILIES = TRAIN_FAMILIES + HELD_OUT_FAMILIES
SCENES_DIR = Path(__file__).resolve().parent
UNSEEN_DIR = SCENES_DIR / "hard_unseen"
UNSEEN_SEED = 59000
UNSEEN_COUNT = 48
PACKED_TRAIN_DIR = SCENES_DIR / "packed_train"
PACKED_TRAIN_SEED = 49000
PACKED_TRAIN_COUNT = 24
#: Draws tried per seed before giving up.
MAX_DRAWS = 100

#: A part of an arrangement: the object, its centre (x, y) in the arrangement's frame and its yaw there (a multiple
#: of 90 degrees, except in a ring).
Part = tuple[ObjectSpec, float, float, float]


def unseen_scene_files() -> list[Path]:
    """The ``hard_unseen`` scenario: the shipped scenes of the held-out families, in seed order."""
    return [UNSEEN_DIR / f"unseen_{i:02d}.yaml" for i in range(UNSEEN_COUNT)]


def packed_train_files() -> list[Path]:
    """The shipped training arrangements of the training families, in seed order."""
    return [PACKED_TRAIN_DIR / f"train_{i:02d}.yaml" for i in range(PACKED_TRAIN_COUNT)]


#: The sets of training arrangements a clutter task's ``hard_fraction`` can draw from (``hard_sets=``): the hard
#: set's generator at training seeds (rows and blocks), and the training families of this module. Never a test set.
TRAINING_SETS = {"hard_train": hard_train_files, "packed_train": packed_train_files}


def check_training_sets(sets) -> tuple[str, ...]:
    """``sets`` (the clutter tasks' ``hard_sets``) as a tuple of names of :data:`TRAINING_SETS`.

    Raises:
        ValueError: an unknown name, or no name.
    """
    sets = tuple(sets)
    if not sets or any(name not in TRAINING_SETS for name in sets):
        raise ValueError(f"unknown hard_sets {list(sets)}; valid: {list(TRAINING_SETS)}")
    return sets


def training_arrangement_files(sets: tuple[str, ...] = ("hard_train",)) -> list[Path]:
    """The scene files of the training arrangement sets named in ``sets`` (:data:`TRAINING_SETS`), in order.

    Raises:
        ValueError: an unknown or empty set list.
    """
    return [path for name in check_training_sets(sets) for path in TRAINING_SETS[name]()]


def _half_footprint(spec: ObjectSpec, yaw: float) -> np.ndarray:
    """Half extents (x, y) of ``spec``'s footprint turned by ``yaw`` (a multiple of 90 degrees)."""
    ext = spec.extents[:2] / 2
    return ext[::-1] if round(yaw / (math.pi / 2)) % 2 else ext


class _Drawer:
    """The random draws of one arrangement: sizes, gaps, colours."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng

    def u(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))

    def gap(self) -> float:
        return self.u(0.001, 0.003)

    def color(self) -> tuple[float, float, float]:
        return PALETTE[int(self.rng.integers(len(PALETTE)))]

    def chance(self, p: float) -> bool:
        return bool(self.rng.random() < p)

    def block(self, half_x: float, half_y: float, height: float) -> ObjectSpec:
        """A cuboid of these half sides, or (a chance in four, when square enough) an upright cylinder in it."""
        if abs(half_x - half_y) < 0.004 and self.chance(0.25):
            return ObjectSpec("cylinder", (min(half_x, half_y), height / 2), self.color())
        return ObjectSpec("cuboid", (half_x, half_y, height / 2), self.color())

    def bar_along_x(self, parts: list[Part], side: int) -> None:
        """A bar against the parts' side ``side`` (+1: +y, -1: -y), as long as the parts are wide in x (8.4-11 cm, so
        no jaw closes along it)."""
        lo, hi = _bounds(parts)
        length = max(hi[0] - lo[0], 0.084)
        half_w = self.u(0.015, 0.022)
        y = (hi[1] + self.gap() + half_w) if side > 0 else (lo[1] - self.gap() - half_w)
        bar = ObjectSpec("cuboid", (min(length, 0.11) / 2, half_w, self.u(0.015, 0.025)), self.color())
        parts.append((bar, (lo[0] + hi[0]) / 2, y, 0.0))


def _bounds(parts: list[Part]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.min([[x, y] - _half_footprint(s, yaw) for s, x, y, yaw in parts], axis=0)
    hi = np.max([[x, y] + _half_footprint(s, yaw) for s, x, y, yaw in parts], axis=0)
    return lo, hi


def _arch_nest(d: _Drawer) -> list[Part]:
    if d.chance(0.5):  # an arch over a block: the block wholly under the lintel
        length, width, leg, height = d.u(0.085, 0.1), d.u(0.045, 0.065), d.u(0.012, 0.016), d.u(0.055, 0.068)
        arch = ObjectSpec("arch", (length, width, leg, height), d.color())
        leg_height = 2 * arch.boxes()[0][1][2]  # the legs' height, under the lintel
        inner = length - 2 * leg
        inside = d.block(inner / 2 - d.gap(), min(width / 2 - 0.004, d.u(0.02, 0.03)), leg_height - d.u(0.003, 0.008))
        parts = [(arch, 0.0, 0.0, 0.0), (inside, 0.0, 0.0, 0.0)]
    else:  # a U around a block, the block pressed 1-3 mm from its base and arms
        length, width, thick, height = d.u(0.085, 0.1), d.u(0.06, 0.08), d.u(0.01, 0.014), d.u(0.03, 0.05)
        u_shape = ObjectSpec("U", (length, width, thick, height), d.color())
        half_x = (length - 2 * thick) / 2 - d.gap()
        base_gap = d.gap()
        depth = width - thick - base_gap + d.u(0.0, 0.015)  # reaching to the U's open end or beyond it
        inside = ObjectSpec("cuboid", (half_x, min(depth / 2, 0.035), d.u(0.012, 0.022)), d.color())
        y = -width / 2 + thick + base_gap + inside.size[1]
        parts = [(u_shape, 0.0, 0.0, 0.0), (inside, 0.0, y, 0.0)]
    for side in (-1, 1) if d.chance(0.5) else (int(d.rng.choice([-1, 1])),):
        d.bar_along_x(parts, side)
    return parts


def _interlock(d: _Drawer) -> list[Part]:
    if d.chance(0.5):  # two L's closing a frame around a block
        length, width, thick, height = d.u(0.085, 0.1), d.u(0.06, 0.075), d.u(0.01, 0.014), d.u(0.03, 0.045)
        gap = d.gap()
        first = ObjectSpec("L", (length, width, thick, height), d.color())
        second = ObjectSpec("L", (length, width, thick, height), d.color())
        # The second L, turned by 180 degrees, sits thick + gap higher in y: its foot closes the frame at +x, its bar
        # at +y, each gap clear of the first L's bar and foot. Inside: x within the feet, y between the bars.
        inner_x = length - 2 * thick - 2 * gap
        inner_y = width - thick - gap
        block = d.block(inner_x / 2 - d.u(0.0, 0.002), inner_y / 2 - d.u(0.0, 0.002), d.u(0.02, height))
        parts = [(first, 0.0, 0.0, 0.0), (second, 0.0, thick + gap, math.pi), (block, 0.0, (thick + gap) / 2, 0.0)]
    else:  # a T, and a block on each side of its stem resting against its bar
        length, width, thick, height = d.u(0.085, 0.11), d.u(0.05, 0.07), d.u(0.012, 0.018), d.u(0.025, 0.045)
        tee = ObjectSpec("T", (length, width, thick, height), d.color())
        parts = [(tee, 0.0, 0.0, 0.0)]
        for side in (-1, 1):
            g1, g2 = d.gap(), d.gap()
            half_x = d.u(0.02, (length - thick) / 2 - g1) / 2
            half_y = min(d.u(0.018, 0.03), (width - thick - g2) / 2)
            x = side * (thick / 2 + g1 + half_x)
            y = -width / 2 + thick + g2 + half_y
            parts.append((d.block(half_x, half_y, d.u(0.02, 0.045)), x, y, 0.0))
    if d.chance(0.5):
        d.bar_along_x(parts, int(d.rng.choice([-1, 1])))
    return parts


def _tall_block(d: _Drawer) -> list[Part]:
    cols = 2 if d.chance(0.5) else 3
    half = d.u(0.018, 0.026)
    tall = set(d.rng.choice(2 * cols, size=1 if d.chance(0.6) else 2, replace=False).tolist())
    parts, x = [], 0.0
    for c in range(cols):
        for r in range(2):
            height = d.u(0.06, 0.09) if 2 * c + r in tall else d.u(0.02, 0.03)
            parts.append((d.block(half, half, height), x, r * (2 * half + d.gap()), 0.0))
        x += 2 * half + d.gap()
    return parts


def _ring(d: _Drawer) -> list[Part]:
    radius = d.u(0.018, 0.028)
    parts: list[Part] = [(ObjectSpec("cylinder", (radius, d.u(0.015, 0.03)), d.color()), 0.0, 0.0, 0.0)]
    count = int(d.rng.integers(5, 8))
    inner = radius + d.gap()  # the blocks' inner faces, 1-3 mm from the cylinder
    # Half widths across the ring that bring neighbours' inner corners within 1-3 mm of each other.
    half_across = inner * math.tan(math.pi / count) - d.u(0.0005, 0.0015)
    for k in range(count):
        angle = 2 * math.pi * k / count
        half_out = d.u(0.012, 0.02)  # half depth along the ray from the cylinder
        spec = d.block(half_out, half_across, d.u(0.02, 0.04))
        parts.append((spec, (inner + half_out) * math.cos(angle), (inner + half_out) * math.sin(angle), angle))
    return parts


def _wedge_block(d: _Drawer) -> list[Part]:
    length = d.u(0.084, 0.11)  # along y: longer than the open jaws
    parts: list[Part] = []
    x = 0.0  # where the next part's -x side goes

    def wedge(height: float, yaw: float) -> None:
        nonlocal x
        run = d.u(0.025, 0.04)
        parts.append((ObjectSpec("wedge", (run, length, d.u(0.8, 1.0) * height), d.color()), x + run / 2, 0.0, yaw))
        x += run + d.gap()

    for _ in range(int(d.rng.integers(1, 3))):  # one or two bars, each with a prism on one or both sides
        half_w, height = d.u(0.015, 0.022), d.u(0.03, 0.05)
        sides = (-1, 1) if d.chance(0.6) else (int(d.rng.choice([-1, 1])),)
        if -1 in sides:
            wedge(height, math.pi)  # turned: its upright face at +x, against the bar
        parts.append((ObjectSpec("cuboid", (half_w, length / 2, height / 2), d.color()), x + half_w, 0.0, 0.0))
        x += 2 * half_w + d.gap()
        if 1 in sides:
            wedge(height, 0.0)  # its upright face at -x, against the bar
    return parts


_FAMILY_PARTS = dict(arch_nest=_arch_nest, interlock=_interlock, tall_block=_tall_block, ring=_ring,
                     wedge_block=_wedge_block)


def family_parts(rng: np.random.Generator, family: str) -> list[Part]:
    """One draw of ``family``'s parts in its own frame (see the module docstring)."""
    return _FAMILY_PARTS[family](_Drawer(rng))


def _draw(rng: np.random.Generator, families: tuple[str, ...], workspace: WorkspaceSpec
          ) -> tuple[str, list[tuple[ObjectSpec, sapien.Pose]]]:
    family = families[int(rng.integers(len(families)))]
    parts = family_parts(rng, family)
    turn = rng.uniform(0.0, 2 * math.pi)
    centre = np.asarray(workspace.center) + rng.uniform(-0.02, 0.02, size=2)
    return family, place_parts(parts, turn, centre, workspace)


def packed_layout(seed: int, families: tuple[str, ...] = FAMILIES, workspace: WorkspaceSpec | None = None
                  ) -> tuple[str, list[tuple[ObjectSpec, sapien.Pose]], int]:
    """The arrangement of ``seed`` among ``families``: ``(family, layout, locked count)``, the first draw of the
    seeded generator that passes the layout check with 3-8 objects, at least half of them locked.

    Raises:
        ValueError: an unknown family.
        RuntimeError: no draw of :data:`MAX_DRAWS` qualified.
    """
    unknown = [f for f in families if f not in FAMILIES]
    if unknown or not families:
        raise ValueError(f"unknown packed families {unknown or families!r}; valid: {list(FAMILIES)}")
    workspace = workspace or WorkspaceSpec()
    found = first_qualifying_draw(np.random.default_rng(seed), lambda rng: _draw(rng, tuple(families), workspace),
                                  workspace, MAX_DRAWS, objects=(3, 8))
    if found is None:
        raise RuntimeError(f"no packed arrangement of {list(families)} for seed {seed} in {MAX_DRAWS} draws")
    return found


def write_packed_scenes(out: Path, count: int, seed: int, families: tuple[str, ...], prefix: str) -> list[Path]:
    """Write ``count`` arrangements of seeds ``seed + i`` as ``out/<prefix>_<ii>.yaml`` (workspace frame)."""
    return write_scene_set(out, count, seed, lambda s, ws: packed_layout(s, families, ws), prefix, Path(out).name,
                           "maniskill_pnp.scenes.packed_families")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="write the held-out families' test set (or the training families' set)")
    parser.add_argument("--train", action="store_true",
                        help=f"the training families' arrangements ({', '.join(TRAIN_FAMILIES)}) instead of the "
                             f"held-out test set ({', '.join(HELD_OUT_FAMILIES)})")
    parser.add_argument("--out", type=Path, default=None, help="folder (default: the package's scene folder)")
    parser.add_argument("--count", type=int, default=None)
    args = parser.parse_args(argv)
    if args.train:
        out, count, seed, families, prefix = PACKED_TRAIN_DIR, PACKED_TRAIN_COUNT, PACKED_TRAIN_SEED, TRAIN_FAMILIES, "train"
    else:
        out, count, seed, families, prefix = UNSEEN_DIR, UNSEEN_COUNT, UNSEEN_SEED, HELD_OUT_FAMILIES, "unseen"
    write_packed_scenes(args.out or out, count if args.count is None else args.count, seed, families, prefix)


if __name__ == "__main__":
    main()
