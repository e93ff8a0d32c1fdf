"""The objects of a clutter task: one pool of procedural actors shared by every sub-scene, drawn per env.

A :class:`ClutterPool` builds its actors once (a seeded library of random procedural objects, of given objects such
as mesh files or YCB models cycled in a seeded order, or exactly the objects of explicit layouts), parks the unused ones on the floor far from the robot and the cameras, draws each env's episode
clutter from the env's seeded RNG (a random subset dropped by :func:`~maniskill_pnp.scenes.clutter.sample_clutter`,
or one of the layouts), puts the pool at those poses, gives the :class:`~maniskill_pnp.planning.lockstep.Motion`
that lets a dropped clutter come to rest, and says where each env's objects are and whether one blew up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import sapien
import torch

from mani_skill.utils.structs.pose import Pose

from maniskill_pnp.planning.collision import actor_pose
from maniskill_pnp.planning.lockstep import Motion
from maniskill_pnp.scenes.clutter import object_status, random_specs, redrop_poses, sample_clutter, sample_packed
from maniskill_pnp.scenes.layout_check import placement_problem, reachable_pixels
from maniskill_pnp.scenes.objects import ObjectSpec, build_object
from maniskill_pnp.cell.workspace import WorkspaceSpec

#: Height of the floor under ManiSkill's table scene (where unused pool objects wait).
FLOOR_Z = -0.9196


@dataclass(frozen=True)
class SettleSpec:
    """The settle after dropping a clutter: at least ``min_steps``, at most ``max_steps`` control steps, until every
    object moves slower than ``linear`` m/s and ``angular`` rad/s."""

    min_steps: int = 3
    max_steps: int = 60
    linear: float = 0.005
    angular: float = 0.05


@dataclass
class ClutterPool:
    """The pool of object actors of a clutter task and each env's episode objects.

    Args:
        workspace: Where clutters are dropped and objects are counted.
        num_envs: Sub-scenes sharing the pool.
        layouts: Explicit layouts (lists of ``(ObjectSpec, pose)``, validated) or None for random clutters.
        num_objects: (min, max) objects of a random clutter.
        kinds: Object kinds of the random library.
        loosely_packed, min_gap: How random clutters are dropped (:func:`~maniskill_pnp.scenes.clutter.sample_clutter`).
        packed_fraction: Share of random clutters packed tightly instead
            (:func:`~maniskill_pnp.scenes.clutter.sample_packed`), a seeded draw per episode.
        size: Library size of random procedural clutters (at least ``num_objects[1]``).
        library_seed: Seed of the random library (its shapes, sizes and colours).
        settle: The settle after a drop.
        max_speed: Speed (m/s) above which an object counts as blown up by the physics.
        library: Objects random clutters are drawn from instead of random procedural ones of ``kinds`` (e.g. mesh
            files or YCB models): the pool holds each of them once, in a seeded order, and repeats them up to
            ``num_objects[1]`` when there are fewer (``size`` does not apply).
        arrangements: Fixed arrangements (lists of ``(ObjectSpec, pose)``, e.g. the hard training scenes) that
            ``arrangement_fraction`` of the random clutters are replaced by (a seeded draw per episode): one of them,
            turned by a random yaw about its centre and put within 2 cm of the workspace centre. The pool holds
            their objects beside the random library.
        arrangement_fraction: That share (0: never).
    """

    workspace: WorkspaceSpec
    num_envs: int
    layouts: list | None
    num_objects: tuple[int, int]
    kinds: tuple[str, ...]
    loosely_packed: bool = True
    min_gap: float = 0.01
    packed_fraction: float = 0.0
    size: int = 20
    library_seed: int = 1234
    settle: SettleSpec = field(default_factory=SettleSpec)
    max_speed: float = 5.0
    library: tuple[ObjectSpec, ...] | None = None
    arrangements: list | None = None
    arrangement_fraction: float = 0.0

    def __post_init__(self):
        if self.layouts is not None:
            self.specs, self.layout_slots = shared_pool(self.layouts)
        elif self.library is not None:
            if not self.library:
                raise ValueError("a clutter library needs at least one object")
            order = np.random.default_rng(self.library_seed).permutation(len(self.library))
            n = max(self.num_objects[1], len(self.library))
            self.specs = [self.library[order[i % len(order)]] for i in range(n)]
        else:
            rng = np.random.default_rng(self.library_seed)
            self.specs = random_specs(rng, max(self.size, self.num_objects[1]), self.kinds)
        #: Pool indices 0..random_count-1 are what random clutters draw from; the arrangements' objects follow.
        self.random_count = len(self.specs)
        self.arrangement_slots: list[list[int]] = []
        if self.arrangements:
            if self.layouts is not None:
                raise ValueError("arrangements replace random clutters: not with explicit layouts")
            specs, slots = shared_pool(self.arrangements)
            self.arrangement_slots = [[self.random_count + i for i in index] for index in slots]
            self.specs = self.specs + specs
        self.names = [f"obj_{i}_{spec.kind}" for i, spec in enumerate(self.specs)]
        self.actors: list = []
        n = self.num_envs
        #: Per env: the pool indices of the episode's objects, their names and actors, and its layout (-1: random).
        self.active_index: list[list[int]] = [[] for _ in range(n)]
        self.active: list[list[str]] = [[] for _ in range(n)]
        self.active_actors: list[list] = [[] for _ in range(n)]
        self.layout_index = np.full(n, -1)
        #: Per env: whether its random clutter was packed into tight clusters (``packed_fraction``).
        self.packed = np.zeros(n, dtype=bool)
        #: Per env: the arrangement its episode plays instead of a random clutter (-1: none).
        self.arrangement_index = np.full(n, -1)
        #: Per env: the pool indices of the objects taken out of its bin (:meth:`empty_bin`) this episode.
        self.emptied: list[set[int]] = [set() for _ in range(n)]

    def build(self, scene) -> None:
        """Build the pool's actors in ``scene`` (every sub-scene), parked."""
        self.actors = [build_object(scene, spec, name, self._park_pose(i)) for i, (spec, name) in enumerate(zip(self.specs, self.names))]

    def _park_pose(self, i: int) -> sapien.Pose:
        spec = self.specs[i]
        return sapien.Pose(p=[1.6 + 0.15 * (i % 6), -0.5 + 0.15 * (i // 6), FLOOR_Z + spec.extents[2] / 2 + 1e-3])

    def draw(self, envs: list[int], rngs: list[np.random.Generator], layout_choice, device) -> None:
        """New episode objects for ``envs`` (one seeded RNG each), every pool actor put at its pose in those envs
        (drop poses for the chosen ones, parked otherwise) and at rest.

        Args:
            layout_choice: ``layout_choice(rng)`` → the index of the layout to use (explicit layouts only).
        """
        b = len(envs)
        poses = [[self._park_pose(i)] * b for i in range(len(self.actors))]  # pool index -> pose in each reset env
        for k, (e, rng) in enumerate(zip(envs, rngs)):
            if self.layouts is not None:
                j = self.layout_index[e] = layout_choice(rng)
                chosen, placed = list(self.layout_slots[j]), [pose for _, pose in self.layouts[j]]
            elif self.arrangement_fraction > 0 and rng.random() < self.arrangement_fraction:
                self.layout_index[e] = -1
                j = self.arrangement_index[e] = int(rng.integers(len(self.arrangements)))
                chosen, placed = list(self.arrangement_slots[j]), place_arrangement(rng, self.arrangements[j], self.workspace)
                self.packed[e] = True  # upright, tightly packed: what rolls off is dropped upright again
            else:
                self.layout_index[e] = self.arrangement_index[e] = -1
                lo, hi = self.num_objects
                chosen = sorted(rng.choice(self.random_count, size=int(rng.integers(lo, hi + 1)), replace=False).tolist())
                specs = [self.specs[i] for i in chosen]
                self.packed[e] = self.packed_fraction > 0 and rng.random() < self.packed_fraction
                if self.packed[e]:
                    placed = sample_packed(rng, specs, self.workspace)
                else:
                    placed = sample_clutter(rng, specs, self.workspace, self.loosely_packed, self.min_gap)
            for i, pose in zip(chosen, placed):
                poses[i][k] = pose
            self.active_index[e] = chosen
            self.emptied[e] = set()
            self.active[e] = [self.names[i] for i in chosen]
            self.active_actors[e] = [self.actors[i] for i in chosen]
        zeros = torch.zeros(b, 3, device=device)
        for actor, actor_poses in zip(self.actors, poses):
            p = torch.as_tensor(np.stack([pose.p for pose in actor_poses]), dtype=torch.float32, device=device)
            q = torch.as_tensor(np.stack([pose.q for pose in actor_poses]), dtype=torch.float32, device=device)
            actor.set_pose(Pose.create_from_pq(p=p, q=q))
            actor.set_linear_velocity(zeros)
            actor.set_angular_velocity(zeros)

    def redrop(self, envs: list[int], rngs: list[np.random.Generator], device) -> list[int]:
        """Drop again the objects of ``envs``' random clutters that settled outside the workspace, partly over its
        edge, or where the arm reaches no grasp (:func:`~maniskill_pnp.scenes.layout_check.placement_problem`), by
        :func:`~maniskill_pnp.scenes.clutter.redrop_poses`, from each env's RNG, beside or onto those inside; the
        objects of explicit layouts stay as they are. Returns how many objects each env drops again; the caller
        lets them settle (:meth:`settle_motion`) and calls again until none is outside. Call it with the scene's reset
        mask lifted (it sets every env's row of a moved actor)."""
        counts, new_poses = [], {}  # (k, pool index) -> pose
        for k, (e, rng) in enumerate(zip(envs, rngs)):
            status = self.status(e) if self.layout_index[e] < 0 else []
            out = [j for j, where in enumerate(status) if where == "lost" or self._misplaced(e, j)]
            counts.append(len(out))
            if not out:
                continue
            index, actors = self.active_index[e], self.active_actors[e]
            resting = [(self.specs[i], actor_pose(a, e).p) for j, (i, a, where) in enumerate(zip(index, actors, status))
                       if where == "workspace" and j not in out]
            upright = self.loosely_packed or bool(self.packed[e])
            poses = redrop_poses(rng, [self.specs[index[j]] for j in out], resting, self.workspace, upright=upright)
            new_poses.update({(k, index[j]): pose for j, pose in zip(out, poses)})
        for i in sorted({i for _, i in new_poses}):
            self._move(i, {e: new_poses[k, i] for k, e in enumerate(envs) if (k, i) in new_poses}, device)
        return counts

    def _misplaced(self, env: int, j: int) -> bool:
        """Whether env ``env``'s object ``j`` rests partly beyond the workspace's edge or out of the arm's reach."""
        i, actor = self.active_index[env][j], self.active_actors[env][j]
        pose = actor_pose(actor, env)
        return bool(placement_problem(self.specs[i], sapien.Pose(p=pose.p, q=pose.q), self.workspace, self._reach))

    @cached_property
    def _reach(self) -> np.ndarray | None:
        """The heightmap pixels where the arm reaches some grasp, read on first use (None: no reach table at this table
        height, so only the edge is checked)."""
        return reachable_pixels(self.workspace)

    def empty_bin(self, envs, device) -> list[int]:
        """Take the objects that came to rest in the bin of each of ``envs`` out of it (to their parked poses), as a
        station empties a bin: every place then drops into an empty bin, however many objects came before, and an
        overfull bin never throws objects out. They keep counting as in the bin (:meth:`status`). Returns how many
        each env's bin held. Call it with the scene's reset mask lifted (it sets every env's row of a moved actor)."""
        moves: dict[int, dict[int, sapien.Pose]] = {}
        counts = []
        for e in envs:
            inside = [i for i, where in zip(self.active_index[e], self.status(e)) if where == "bin" and i not in self.emptied[e]]
            for i in inside:
                moves.setdefault(i, {})[e] = self._park_pose(i)
            self.emptied[e].update(inside)
            counts.append(len(inside))
        for i, poses in moves.items():
            self._move(i, poses, device)
        return counts

    def _move(self, i: int, poses: dict[int, sapien.Pose], device) -> None:
        """Put pool actor ``i`` at ``poses[e]`` at rest in each env ``e`` of ``poses``; its other envs' rows as they are."""
        actor = self.actors[i]
        raw = actor.pose.raw_pose.clone()
        lin, ang = actor.linear_velocity.clone(), actor.angular_velocity.clone()
        for e, pose in poses.items():
            raw[e] = torch.as_tensor(np.concatenate([pose.p, pose.q]), dtype=raw.dtype, device=device)
            lin[e] = ang[e] = 0.0
        actor.set_pose(Pose.create(raw))
        actor.set_linear_velocity(lin)
        actor.set_angular_velocity(ang)

    def settle_motion(self, env: int, home: np.ndarray) -> Motion:
        """Env ``env``'s settle: its arm held at ``home`` with the gripper open until its objects are at rest."""
        s = self.settle

        def at_rest() -> bool:
            return all(float(torch.linalg.norm(a.linear_velocity[env])) < s.linear
                       and float(torch.linalg.norm(a.angular_velocity[env])) < s.angular
                       for a in self.active_actors[env])

        return Motion(home[None], gripper=1.0, min_steps=s.min_steps, settle_tol=None, until=at_rest,
                      max_settle=s.max_steps - s.min_steps)

    def status(self, env: int) -> list[str]:
        """Where each of env ``env``'s objects is (:func:`~maniskill_pnp.scenes.clutter.object_status`); objects taken
        out of the bin (:meth:`empty_bin`) are in the bin."""
        actors = self.active_actors[env]
        pos = np.stack([actor_pose(a, env).p for a in actors]) if actors else np.zeros((0, 3))
        status = object_status(pos, self.workspace)
        return ["bin" if i in self.emptied[env] else where for i, where in zip(self.active_index[env], status)]

    def in_workspace(self, env: int) -> list[str]:
        """Names of env ``env``'s objects still in the workspace."""
        return [name for name, s in zip(self.active[env], self.status(env)) if s == "workspace"]

    def workspace_layout(self, env: int) -> list[tuple[ObjectSpec, sapien.Pose]]:
        """Env ``env``'s objects still in the workspace at their current poses: ``(ObjectSpec, world pose)`` each,
        in the episode's order (what a scene file of the current scene holds)."""
        if not 0 <= env < self.num_envs:
            raise ValueError(f"env index must be in 0..{self.num_envs - 1}, got {env!r}")
        return list(self.workspace_objects(env).values())

    def workspace_objects(self, env: int) -> dict[int, tuple[ObjectSpec, sapien.Pose]]:
        """Env ``env``'s objects still in the workspace by pool index: ``(ObjectSpec, world pose)`` each."""
        out = {}
        for i, actor, status in zip(self.active_index[env], self.active_actors[env], self.status(env)):
            if status == "workspace":
                p, q = (np.asarray(v[env].cpu().numpy(), dtype=np.float64) for v in (actor.pose.p, actor.pose.q))
                out[i] = (self.specs[i], sapien.Pose(p=p, q=q / np.linalg.norm(q)))
        return out

    def in_play(self) -> list[int]:
        """Pool indices in some env's episode."""
        return sorted({i for index in self.active_index for i in index})

    def blow_ups(self) -> list[str]:
        """Per env, the first of its objects with a non-finite pose or velocity or faster than ``max_speed`` ("" if
        none); each pool object in play is read once for all envs."""
        faults = [""] * self.num_envs
        used = self.in_play()
        pose = {i: self.actors[i].pose.p for i in used}
        vel = {i: self.actors[i].linear_velocity for i in used}
        for e in range(self.num_envs):
            for i in self.active_index[e]:
                p, v = pose[i][e], vel[i][e]
                if not (torch.isfinite(p).all() and torch.isfinite(v).all()) or float(v.norm()) > self.max_speed:
                    faults[e] = f"physics blow-up: {self.names[i]} at {p.tolist()} moving at {float(v.norm()):.3g} m/s"
                    break
        return faults


def place_arrangement(rng: np.random.Generator, layout, workspace: WorkspaceSpec, offset: float = 0.02) -> list[sapien.Pose]:
    """The poses of ``layout`` (``(ObjectSpec, pose)`` each) turned as one rigid piece by a random yaw about its
    centre (the mean of its objects' xy), the centre moved to within ``offset`` (m) of the workspace centre."""
    xy = np.array([pose.p[:2] for _, pose in layout], dtype=np.float64)
    yaw = float(rng.uniform(-np.pi, np.pi))
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    centre = np.asarray(workspace.center, dtype=np.float64) + rng.uniform(-offset, offset, size=2)
    turn = sapien.Pose(q=[np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    mid = xy.mean(axis=0)
    poses = []
    for (_, pose), p in zip(layout, xy):
        q = (turn * sapien.Pose(q=pose.q)).q
        poses.append(sapien.Pose(p=[*(centre + rot @ (p - mid)), float(pose.p[2])], q=q))
    return poses


def shared_pool(layouts) -> tuple[list[ObjectSpec], list[list[int]]]:
    """One pool for several layouts: each distinct spec as many times as the layout that uses it most.

    Returns:
        The pool's specs and, per layout, the pool index of each of its entries.
    """
    pool: list[ObjectSpec] = []
    slots = []
    for layout in layouts:
        used: dict[ObjectSpec, int] = {}
        indices = []
        for spec, _ in layout:
            copies = [i for i, s in enumerate(pool) if s == spec]
            k = used.get(spec, 0)
            if k == len(copies):
                pool.append(spec)
                copies.append(len(pool) - 1)
            indices.append(copies[k])
            used[spec] = k + 1
        slots.append(indices)
    return pool, slots
