"""Tightly packed arrangements where grasping cannot work at the start: the ``hard`` test set.

:func:`hard_layout` draws, from a seed, one of three families, turned by a random yaw about the workspace centre
(within 2 cm of it), every gap between neighbours 1-3 mm:

* ``row``: 3-4 bars side by side, 8.4-11 cm long (wider than the open jaws' 8 cm), 3-5 cm wide;
* ``block2x2``: four 4-6 cm cubes (or upright cylinders of that diameter) in a 2×2 square;
* ``block2x3``: six such cubes or 3-4 cm × 8.4-11 cm bars in two rows of three.

Heights are 3-5 cm. A draw is kept only when it passes :func:`~maniskill_pnp.scenes.layout_check.check_layout` and
at least half of its objects are *locked* (:func:`~maniskill_pnp.scenes.grasp_feasibility.grasp_feasibility`: no
top-down grasp fits); otherwise the next draw of the same generator is tried.

The shipped set: :data:`HARD_SCENE_COUNT` scenes of seeds ``HARD_SEED + i`` in ``scenes/hard/hard_<ii>.yaml``
(workspace frame), written by ``python -m maniskill_pnp.scenes.hard_scenes`` (``--out`` another folder). Training
never sees them: these layouts are only played as explicit scene files (the ``hard`` scenario of ``eval-clutter``:
these files and the 8 locking layouts of :mod:`~maniskill_pnp.scenes.complicated_layouts`, :func:`hard_layout_files`).

Training draws its hard arrangements from a disjoint set: :data:`HARD_TRAIN_COUNT` scenes of seeds
``HARD_TRAIN_SEED + i`` in ``scenes/hard_train/train_<ii>.yaml`` (``python -m maniskill_pnp.scenes.hard_scenes
--train``), each placed at a random yaw and offset per episode (the ``hard_fraction`` of the clutter tasks).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import sapien

from maniskill_pnp.scenes.complicated_layouts import complicated_layout_files
from maniskill_pnp.scenes.grasp_feasibility import grasp_feasibility
from maniskill_pnp.scenes.layout_check import check_layout
from maniskill_pnp.scenes.objects import PALETTE, ObjectSpec
from maniskill_pnp.cell.workspace import WorkspaceSpec

FAMILIES = ("row", "block2x2", "block2x3")
#: Seed of the first shipped scene, and how many there are.
HARD_SEED = 29000
HARD_SCENE_COUNT = 24
#: Folder of the shipped scene files.
HARD_SCENES_DIR = Path(__file__).resolve().parent / "hard"
#: The training arrangements: seeds (disjoint from the test set's), count and folder.
HARD_TRAIN_SEED = 39000
HARD_TRAIN_COUNT = 24
HARD_TRAIN_DIR = HARD_SCENES_DIR.with_name("hard_train")
#: Draws tried per seed before giving up.
MAX_DRAWS = 50


def hard_scene_files() -> list[Path]:
    """The shipped hard scene files, in seed order."""
    return [HARD_SCENES_DIR / f"hard_{i:02d}.yaml" for i in range(HARD_SCENE_COUNT)]


def hard_train_files() -> list[Path]:
    """The shipped training arrangements, in seed order (never the test set's seeds)."""
    return [HARD_TRAIN_DIR / f"train_{i:02d}.yaml" for i in range(HARD_TRAIN_COUNT)]


def hard_layout_files() -> list[Path]:
    """The ``hard`` scenario: the shipped hard scenes, then the 8 locking layouts."""
    return hard_scene_files() + complicated_layout_files()


def cells(rng: np.random.Generator, family: str) -> list[tuple[ObjectSpec, float, float]]:
    """Objects and their centres (x, y) in the arrangement's frame, before it is turned and placed."""
    u = rng.uniform
    gap = lambda: u(0.001, 0.003)  # noqa: E731
    color = lambda: PALETTE[int(rng.integers(len(PALETTE)))]  # noqa: E731
    out = []
    if family == "row":
        length = u(0.042, 0.055)
        x = 0.0
        for _ in range(int(rng.integers(3, 5))):
            half = u(0.015, 0.025)
            out.append((ObjectSpec("cuboid", (half, length, u(0.015, 0.025)), color()), x + half, 0.0))
            x += 2 * half + gap()
        return out
    cols = 2 if family == "block2x2" else 3
    bars = family == "block2x3" and rng.random() < 0.5
    hx, hy = (u(0.015, 0.02), u(0.042, 0.055)) if bars else (u(0.02, 0.03),) * 2
    xs = np.cumsum([0.0] + [2 * hx + gap() for _ in range(cols - 1)])
    ys = [0.0, 2 * hy + gap()]
    for x in xs:
        for y in ys:
            if not bars and rng.random() < 0.25:
                spec = ObjectSpec("cylinder", (hx, u(0.015, 0.025)), color())
            else:
                spec = ObjectSpec("cuboid", (hx, hy, u(0.015, 0.025)), color())
            out.append((spec, float(x), float(y)))
    return out


def place_parts(parts, turn: float, centre: np.ndarray, workspace: WorkspaceSpec) -> list[tuple[ObjectSpec, sapien.Pose]]:
    """An arrangement's parts ``(spec, x, y, yaw)`` (its own frame) turned by ``turn`` as one piece about their mean
    centre, which goes to ``centre`` (world xy); each part standing on the table at yaw ``turn + yaw``."""
    mid = np.mean([[x, y] for _, x, y, _ in parts], axis=0)
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    layout = []
    for spec, x, y, yaw in parts:
        xy = centre + rot @ (np.array([x, y]) - mid)
        q = [math.cos((turn + yaw) / 2), 0.0, 0.0, math.sin((turn + yaw) / 2)]
        layout.append((spec, sapien.Pose(p=[xy[0], xy[1], workspace.table_z + spec.extents[2] / 2], q=q)))
    return layout


def first_qualifying_draw(rng: np.random.Generator, draw, workspace: WorkspaceSpec, max_draws: int,
                          objects: tuple[int, float] = (1, math.inf)):
    """The first of ``max_draws`` draws ``draw(rng) -> (family, layout)`` that has ``objects[0]..objects[1]``
    objects, passes :func:`~maniskill_pnp.scenes.layout_check.check_layout` and has at least half of its objects
    locked: ``(family, layout, locked count)``, or None. A draw that raises ValueError (a part the gripper cannot
    take) is passed over like one that fails the check."""
    for _ in range(max_draws):
        try:
            family, layout = draw(rng)
            if not objects[0] <= len(layout) <= objects[1]:
                continue
            check_layout(layout, workspace)
        except ValueError:
            continue
        locked = sum(g.locked for g in grasp_feasibility(layout, workspace))
        if 2 * locked >= len(layout):
            return family, layout, locked
    return None


def write_scene_set(out: Path, count: int, seed: int, layout_of, prefix: str, set_name: str, source: str) -> list[Path]:
    """Write the arrangements ``layout_of(seed + i, workspace) -> (family, layout, locked)`` of ``count`` seeds as
    ``out/<prefix>_<ii>.yaml`` (workspace frame), each described as of ``set_name`` and written by ``source``; returns
    the paths."""
    from maniskill_pnp.scenes.scene_file import save_scene

    workspace = WorkspaceSpec()
    paths = []
    for i in range(count):
        family, layout, locked = layout_of(seed + i, workspace)
        name = f"{prefix}_{i:02d}"
        path = save_scene(Path(out) / f"{name}.yaml", layout, workspace, name=name,
                          description=f"{set_name} set, seed {seed + i}: {family}, {len(layout)} objects, {locked} "
                                      f"locked at the start ({source})")
        print(f"{path}: {family}, {len(layout)} objects, {locked} locked", flush=True)
        paths.append(path)
    return paths


def _draw(rng: np.random.Generator, workspace: WorkspaceSpec) -> tuple[str, list[tuple[ObjectSpec, sapien.Pose]]]:
    family = FAMILIES[int(rng.integers(len(FAMILIES)))]
    parts = [(spec, x, y, 0.0) for spec, x, y in cells(rng, family)]
    yaw = rng.uniform(0.0, math.pi)
    centre = np.asarray(workspace.center) + rng.uniform(-0.02, 0.02, size=2)
    return family, place_parts(parts, yaw, centre, workspace)


def hard_layout(seed: int, workspace: WorkspaceSpec | None = None) -> tuple[str, list[tuple[ObjectSpec, sapien.Pose]], int]:
    """The hard arrangement of ``seed``: ``(family, layout, locked count)``, the first draw of the seeded generator
    that passes the layout check with at least half of its objects locked.

    Raises:
        RuntimeError: no draw of :data:`MAX_DRAWS` qualified.
    """
    workspace = workspace or WorkspaceSpec()
    found = first_qualifying_draw(np.random.default_rng(seed), lambda rng: _draw(rng, workspace), workspace, MAX_DRAWS)
    if found is None:
        raise RuntimeError(f"no hard arrangement of seed {seed} in {MAX_DRAWS} draws")
    return found


def write_hard_scenes(out: Path = HARD_SCENES_DIR, count: int = HARD_SCENE_COUNT, seed: int = HARD_SEED,
                      prefix: str = "hard") -> list[Path]:
    """Write ``count`` hard scenes of seeds ``seed + i`` as ``out/<prefix>_<ii>.yaml`` (workspace frame); returns the
    paths."""
    return write_scene_set(out, count, seed, hard_layout, prefix, prefix, "maniskill_pnp.scenes.hard_scenes")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="write the hard test set's scene files (or the training set's)")
    parser.add_argument("--train", action="store_true",
                        help=f"the training arrangements (seeds {HARD_TRAIN_SEED}.., scenes/hard_train) instead of the test set")
    parser.add_argument("--out", type=Path, default=None, help="folder (default: the package's scenes/hard or scenes/hard_train)")
    parser.add_argument("--count", type=int, default=None)
    parser.add_argument("--seed", type=int, default=None)
    args = parser.parse_args(argv)
    default = (HARD_TRAIN_DIR, HARD_TRAIN_COUNT, HARD_TRAIN_SEED, "train") if args.train else \
        (HARD_SCENES_DIR, HARD_SCENE_COUNT, HARD_SEED, "hard")
    seed = default[2] if args.seed is None else args.seed
    count = default[1] if args.count is None else args.count
    if not args.train and seed < HARD_TRAIN_SEED + HARD_TRAIN_COUNT and seed + count > HARD_TRAIN_SEED or \
            args.train and seed < HARD_SEED + HARD_SCENE_COUNT and seed + count > HARD_SEED:
        parser.error(f"seeds {seed}..{seed + count - 1} overlap the other set's: test and training arrangements stay disjoint")
    write_hard_scenes(args.out or default[0], count, seed, default[3])


if __name__ == "__main__":
    main()
