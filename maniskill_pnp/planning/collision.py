"""Collision checking for the arm against itself and the current ManiSkill scene (FCL through mplib).

The obstacles are read from the simulator's own collision shapes (boxes, spheres, capsules, cylinders,
convex and triangle meshes, planes) at their current poses, never copied by hand, so a plan checked here
is checked against the scene the simulator steps. Everything is expressed in the robot base frame.

Example:
    >>> world = CollisionWorld(panda_spec(), base_pose=env.agent.robot.pose.raw_pose[0].numpy())
    >>> world.sync_scene(env.scene, ignore={"cube"})   # the object being approached may be touched
    >>> world.is_valid(q)                                # no self- and no scene collision at q
"""

from __future__ import annotations

import hashlib
import os
import xml.etree.ElementTree as ET
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sapien

from maniskill_pnp.cache import cache_dir
from maniskill_pnp.planning.robot import ArmSpec, urdf_link_bounds, urdf_reach

# A PhysX capsule or cylinder lies along its local x axis; FCL's lie along z. This turns z onto x.
_Z_TO_X = sapien.Pose(q=[np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])
# Half-thickness of the slab that stands in for an infinite plane (FCL's plane-vs-mesh support is patchy).
_PLANE_SLAB_HALF = np.array([0.5, 20.0, 20.0])


@dataclass(frozen=True)
class Obstacle:
    """One collision shape of the scene, in the robot base frame.

    Attributes:
        actor: Name of the ManiSkill actor the shape belongs to.
        kind: Shape kind (``box``, ``sphere``, ``capsule``, ``cylinder``, ``convex``, ``mesh``, ``plane``).
        pose: Pose of the shape in the robot base frame (x, y, z, qw, qx, qy, qz).
        signature: Size parameters that identify the geometry (used for the scene fingerprint).
    """

    actor: str
    kind: str
    pose: np.ndarray
    signature: tuple[float, ...]


class CollisionWorld:
    """FCL collision world of one arm and the obstacles of one ManiSkill sub-scene.

    Args:
        arm: The arm's description (URDF/SRDF, TCP link, limits).
        base_pose: Pose of the robot base in the world frame (x, y, z, qw, qx, qy, qz).
    """

    #: Stretches of a segment (in checked configurations) whose clearance :meth:`segment_valid` certifies, coarse first.
    SWEEP_BLOCKS = (32, 8)
    #: Distance (m) from the TCP within which a held object lies entirely (:meth:`attach_box` checks it): with it,
    #: the arm's reach (:attr:`reach`) bounds every point an arm carrying an object can touch.
    HELD_REACH = 0.3

    def __init__(self, arm: ArmSpec, base_pose: np.ndarray | None = None):
        import mplib  # mplib segfaults with numpy 2; the package pins numpy<2

        self.arm = arm
        # The base link stands on the table: in the arm's own model it would collide with the table in every
        # configuration. It is fixed, so it has no collision geometry here, and a plain collide() answers.
        urdf = planning_urdf(arm.urdf)
        self._planner = mplib.Planner(urdf=str(urdf), srdf=str(arm.srdf), move_group=arm.tcp_link)
        self._world = self._planner.planning_world
        self._robot = self._planner.robot
        self._fcl = mplib.pymp.collision_detection.fcl
        self._mplib = mplib.pymp
        self._finger_qpos = np.full(len(self._planner.user_joint_names) - arm.arm_joints, arm.gripper_open)
        self.base_pose = sapien.Pose() if base_pose is None else _pose(base_pose)
        self._base_inv = self.base_pose.inv()
        self.obstacles: dict[str, list[Obstacle]] = {}
        self._attached = False
        self.margin = 0.0
        # Shapes no configuration of the arm can reach stay out of the FCL world (every check would test them in
        # vain: the pool's parked objects); they still count in the scene's fingerprint.
        self.reach = max(urdf_reach(arm.urdf), urdf_reach(arm.urdf, arm.tcp_link) + self.HELD_REACH)
        self._out_of_reach: dict[str, object] = {}
        self._shapes: dict[tuple[str, int], _ShapeGeometry] = {}
        self._sweep = _SweptBalls(arm, self._planner)
        self._boxes = np.zeros((0, 2, 3))  # the FCL world's obstacles as base-frame AABBs (grown by the margin)
        self._box_objects: list[tuple[str, object]] = []  # the name and FCL object of each box's obstacle
        self._placed: dict[tuple[str, float], tuple[tuple, list]] = {}  # (actor, margin) -> (its pose, its shapes placed)

    # ------------------------------------------------------------------ scene
    def sync_scene(
        self, scene, *, ignore: Collection[str] = (), env_idx: int = 0, skip: Collection[str] = (), margin: float = 0.0
    ) -> None:
        """Replace the obstacles by the collision shapes of every actor in ``scene`` (a ManiSkillScene).

        Args:
            scene: The ManiSkill scene (``env.unwrapped.scene``).
            ignore: Actor names to leave out: the object being approached or held.
            env_idx: Which parallel sub-scene to read.
            skip: Further actor names that are never obstacles (e.g. visual-only markers).
            margin: Grow every obstacle by this clearance (m). Free-space motions use a margin so that the
                joint controller's tracking error cannot turn a grazing plan into a contact; straight segments
                near surfaces (descend, push) use the exact geometry.
        """
        if margin < 0:
            raise ValueError(f"collision margin must be >= 0, got {margin}")
        self.margin = float(margin)
        for name in list(self.obstacles):
            for i, _ in enumerate(self.obstacles[name]):
                if f"{name}#{i}" not in self._out_of_reach:
                    self._world.remove_normal_object(f"{name}#{i}")
        self.obstacles, self._out_of_reach = {}, {}
        boxes, self._box_objects = [], []
        for name, actor in scene.actors.items():
            if name in ignore or name in skip:
                continue
            for i, (ob, fcl_object, box) in enumerate(self._placed_shapes(name, actor, env_idx)):
                self.obstacles.setdefault(name, []).append(ob)
                if box is None:
                    self._out_of_reach[f"{name}#{i}"] = fcl_object
                else:
                    self._world.set_normal_object(f"{name}#{i}", fcl_object)
                    boxes.append(box)
                    self._box_objects.append((f"{name}#{i}", fcl_object))
        self._boxes = np.array(boxes).reshape(-1, 2, 3)

    def _placed_shapes(self, name: str, actor, env_idx: int) -> list[tuple[Obstacle, object, np.ndarray | None]]:
        """Per collision shape of actor ``name``: its :class:`Obstacle`, its FCL object and its box (None: out of
        reach), at the current margin. Built again only when the actor's pose, its shapes or the margin changed since
        the last sync (objects at rest, the table and the bin keep theirs)."""
        entity = actor._objs[env_idx]
        body = entity.find_component_by_type(sapien.physx.PhysxRigidBaseComponent)
        if body is None:
            return []
        pose = actor_pose(actor, env_idx)
        shapes = tuple(body.collision_shapes)
        key = (env_idx, tuple(pose.p), tuple(pose.q), shapes)
        cached = self._placed.get((name, self.margin))
        if cached is not None and cached[0] == key:
            return cached[1]
        placed = []
        for ob, shape in self._actor_obstacles(name, pose, shapes):
            geometry = self._geometry(name, len(placed), shape)
            fcl_object = self._fcl.CollisionObject(geometry.fcl(self.margin), ob.pose[:3], ob.pose[3:])
            far = ob.kind != "plane" and np.linalg.norm(ob.pose[:3]) - geometry.radius - self.margin > self.reach
            placed.append((ob, fcl_object, None if far else geometry.aabb(ob.pose, self.margin)))
        self._placed[(name, self.margin)] = (key, placed)
        return placed

    def _geometry(self, name: str, i: int, shape) -> _ShapeGeometry:
        """The FCL geometry of shape ``i`` of actor ``name``, built once per shape and margin."""
        cached = self._shapes.get((name, i))
        if cached is None or cached.shape is not shape:
            cached = self._shapes[(name, i)] = _ShapeGeometry(shape, self._fcl)
        return cached

    def _actor_obstacles(self, name: str, pose: sapien.Pose, shapes) -> Iterable[tuple[Obstacle, object]]:
        for i, shape in enumerate(shapes):
            world = pose * shape.local_pose
            geometry = self._geometry(name, i, shape)
            kind, signature = geometry.kind, geometry.signature
            if kind in ("capsule", "cylinder"):
                world = world * _Z_TO_X
            elif kind == "plane":
                world = world * sapien.Pose(p=[self.margin - _PLANE_SLAB_HALF[0], 0.0, 0.0])
            local = self._base_inv * world
            yield Obstacle(name, kind, np.concatenate([local.p, local.q]), signature), shape

    def fingerprint(self, decimals: int = 3) -> str:
        """A short hash of every obstacle's kind, size and pose (rounded): equal iff the scene is the same."""
        h = hashlib.sha1()
        for name in sorted(self.obstacles):
            for ob in self.obstacles[name]:
                h.update(name.encode())
                h.update(ob.kind.encode())
                h.update(np.round(np.asarray(ob.signature), decimals).tobytes())
                h.update(np.round(ob.pose, decimals).tobytes())
        h.update(np.float64(self.margin).tobytes())
        h.update(b"attached" if self._attached else b"-")
        return h.hexdigest()[:16]

    # ------------------------------------------------------------------ held objects
    def attach_box(self, half_size: np.ndarray, pose_in_tcp: np.ndarray) -> None:
        """Treat a box held by the gripper as part of the arm (pose relative to the TCP link)."""
        if np.linalg.norm(np.asarray(pose_in_tcp, np.float64)[:3]) + np.linalg.norm(half_size) > self.HELD_REACH:
            for key, fcl_object in self._out_of_reach.items():  # an object this large may reach them
                self._world.set_normal_object(key, fcl_object)
            self._out_of_reach = {}
        self._planner.update_attached_box(2 * np.asarray(half_size, dtype=np.float64), np.asarray(pose_in_tcp, np.float64))
        self._sweep.attach(np.asarray(pose_in_tcp, np.float64)[:3], float(np.linalg.norm(half_size)))
        self._world.set_use_attach(True)
        self._attached = True

    def detach(self) -> None:
        """Forget the held object."""
        self._sweep.attach(None)
        if self._attached:
            self._world.remove_attach()
            self._world.set_use_attach(False)
            self._attached = False

    def set_fingers(self, finger_qpos: float) -> None:
        """Set the finger opening used for collision checks (per finger, m)."""
        self._finger_qpos[:] = finger_qpos

    # ------------------------------------------------------------------ queries
    def _set(self, q: np.ndarray) -> None:
        self._robot.set_qpos(np.concatenate([np.asarray(q, dtype=np.float64), self._finger_qpos]), True)

    def collisions(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Colliding pairs at arm configuration ``q``: (robot link, other link or obstacle name)."""
        self._set(q)
        pairs = []
        for res in self._world.collide_full():
            other = res.link_name2 if res.collision_type == "self" else res.link_name2 or res.object_name2
            pairs.append((res.link_name1, (other or "").split("#")[0] or res.object_name2))
        return pairs

    def is_valid(self, q: np.ndarray) -> bool:
        """True when ``q`` is within the joint limits and collides with neither the arm itself nor the scene."""
        if not self.arm.within_limits(q):
            return False
        self._set(q)
        return not self._world.collide()

    def segment_valid(self, q0: np.ndarray, q1: np.ndarray, resolution: float = 0.005) -> bool:
        """True when every configuration on the straight joint-space segment q0→q1 is valid.

        ``resolution`` is the largest joint-space step (rad, max norm) between checked configurations. They are
        checked ends first, then in bisection order (as OMPL's motion validator does), so that a segment through
        an obstacle fails after a few checks; a valid one costs the same checks in any order.

        The answer is that of :meth:`is_valid` at every one of them, found faster: where a stretch of the segment
        keeps every link (and a held object) provably away from every obstacle (:class:`_SweptBalls`: a few balls per
        link, grown by how far the stretch's joint motion can move them), its configurations skip the scene test, where
        it keeps the links apart they skip the self test, and the scene test of the rest sees only the obstacles within
        reach (see :meth:`_states_valid`).
        """
        q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
        n = max(1, int(np.ceil(np.max(np.abs(q1 - q0)) / resolution)))
        if not (self.arm.within_limits(q0) and self.arm.within_limits(q1)):
            return False  # the limits are a box: with both ends inside it, so is every configuration between them
        return self._states_valid(q0, q1, n, bisection_order(n))

    def motion_valid(self, q0: np.ndarray, q1: np.ndarray, n: int) -> bool:
        """OMPL's discrete motion check, answered as :meth:`segment_valid` answers: True when ``q1`` and the ``n - 1``
        configurations ``q0 + (q1 - q0) * (i / n)`` between the two are valid; ``q0`` is taken as valid (an OMPL
        motion starts at a valid state). ``n`` is the motion's segment count in OMPL's state space (0 or 1: only
        ``q1`` is checked)."""
        q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
        if not self.is_valid(q1):
            return False
        if n < 2:
            return True
        between = bisection_order(n)[2:]
        if not self.arm.within_limits(q0):  # not an OMPL motion: the configurations between need their own limit test
            return all(self.is_valid(q0 + (q1 - q0) * (i / n)) for i in between)
        return self._states_valid(q0, q1, n, between)

    def _states_valid(self, q0: np.ndarray, q1: np.ndarray, n: int, indices: list[int]) -> bool:
        """True when the configurations ``q0 + (q1 - q0) * (i / n)`` (``i`` in ``indices``, both ends within the joint
        limits) collide with neither the arm itself nor the scene. Where the swept balls certify a stretch clear of
        every obstacle, its configurations skip the scene test; where they certify it clear of self-collision (no
        held object), they skip the self test; where both, they are not posed at all. Where some obstacles are within
        reach (nothing held), the scene test of the stretch is that of a world of those obstacles only: the others
        cannot touch the arm there, and mplib tests every link against every obstacle of its world."""
        blocks: dict[tuple[int, int], tuple[bool, bool, np.ndarray]] = {}
        worlds: dict[tuple[int, int], object] = {}
        own_too = not self._attached  # a held object's contacts with the arm are in mplib's self test

        def certified(i: int) -> tuple[bool, bool, tuple[int, int]]:
            """i's coarse stretch, else its fine one: (scene, self) clear, and the finest stretch looked at."""
            scene = own = False
            for size in self.SWEEP_BLOCKS:
                key = (size, i // size)
                if key not in blocks:
                    a, b = key[1] * size, min(key[1] * size + size, n)
                    blocks[key] = self._sweep.clear(q0 + (q1 - q0) * (a / n), q0 + (q1 - q0) * (b / n), self._finger_qpos,
                                                    self._boxes, own_too)
                scene, own = scene or blocks[key][0], own or blocks[key][1]
                if scene and own:
                    break
            return scene, own, key

        def near_world(key: tuple[int, int]):
            if self._attached:  # the held object is in the full world only
                return self._world
            if key not in worlds:
                near = [self._box_objects[k] for k in np.flatnonzero(blocks[key][2])]
                worlds[key] = self._mplib.PlanningWorld([self._robot], ["robot"], [o for _, o in near], [k for k, _ in near])
            return worlds[key]

        for i in indices:
            scene, own, key = certified(i)
            if scene and own:
                continue
            self._set(q0 + (q1 - q0) * (i / n))
            if scene:
                hit = self._world.self_collide()
            elif own:
                hit = near_world(key).collide_with_others()
            else:
                hit = near_world(key).collide()
            if hit:
                return False
        return True

    def path_valid(self, path: np.ndarray, resolution: float = 0.005) -> bool:
        """True when every segment of a waypoint path (N×dof) is valid."""
        return all(self.segment_valid(a, b, resolution) for a, b in zip(path[:-1], path[1:]))

    # ------------------------------------------------------------------ kinematics (mplib's pinocchio model)
    @property
    def mplib_planner(self):
        """The underlying ``mplib.Planner`` (its pinocchio model does IK and FK)."""
        return self._planner

    def world_to_base(self, pose: np.ndarray | sapien.Pose) -> sapien.Pose:
        """A world-frame pose expressed in the robot base frame."""
        return self._base_inv * _pose(pose)

    def base_to_world(self, pose: np.ndarray | sapien.Pose) -> sapien.Pose:
        """A base-frame pose expressed in the world frame."""
        return self.base_pose * _pose(pose)


def actor_pose(actor, env_idx: int = 0) -> sapien.Pose:
    """The pose of ManiSkill ``actor`` in sub-scene ``env_idx``: ``actor.pose``'s. On the CPU the entity's own pose is
    the one ManiSkill's tensor copies (float32 both), read without building tensors."""
    if actor.scene.gpu_sim_enabled:
        return _pose(actor.pose.raw_pose[env_idx].cpu().numpy())
    return actor._objs[env_idx].pose


def bisection_order(n: int) -> list[int]:
    """The indices 0..n: both ends, then the midpoints of ever finer halvings (each index once)."""
    if n < 1:
        raise ValueError(f"a segment has n >= 1 steps, got {n}")
    # The spans of a round split 0..n into intervals that share only their ends, so each midpoint is new.
    order, spans = [0, n], [(0, n)]
    while spans:
        nxt = []
        for a, b in spans:
            if b - a >= 2:
                m = (a + b) // 2
                order.append(m)
                nxt += [(a, m), (m, b)]
        spans = nxt
    return order


def planning_urdf(urdf: Path) -> Path:
    """A copy of ``urdf`` for collision checking: the root link (fixed to the world) without collision geometry, and
    mesh paths rewritten relative to the copy (mplib resolves every mesh path against the URDF's folder). Written
    once to the cache folder, named after the source's path and content."""
    urdf = Path(urdf).resolve()
    text = urdf.read_bytes()
    folder = cache_dir("planning")
    out = folder / f"{urdf.stem}_{hashlib.sha1(str(urdf).encode() + text).hexdigest()[:12]}.urdf"
    if out.exists():
        return out
    root = ET.fromstring(text)
    children = {j.find("child").attrib["link"] for j in root.iter("joint") if j.find("child") is not None}
    roots = [link for link in root.iter("link") if link.attrib["name"] not in children]
    if len(roots) != 1:
        raise ValueError(f"{urdf} has {len(roots)} root links; one is expected")
    for collision in roots[0].findall("collision"):
        roots[0].remove(collision)
    for mesh in root.iter("mesh"):
        name = mesh.attrib["filename"]
        if not name.startswith("package://"):
            mesh.attrib["filename"] = os.path.relpath(urdf.parent / name, folder)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    ET.ElementTree(root).write(tmp)
    tmp.replace(out)  # atomic: processes that build planners at once never read a half-written file
    return out


class _SweptBalls:
    """Certifies that a straight joint-space stretch keeps the arm away from a set of boxes.

    Each link with collision geometry is held by a few balls (:func:`~maniskill_pnp.planning.robot.covering_balls`); a
    held object by a ball about its box. Over the stretch ``qa -> qb`` no point of a link strays from where it is at
    the middle configuration by more than the sum over the arm joints of the joint's lever times half the joint's
    travel (a rotation by ``d`` moves a point at most its distance from the axis times ``d``). The stretch is clear
    of the scene when every link's ball, grown by that, misses every box, and clear of self-collision when the balls of
    every link pair that mplib's self test checks miss each other, grown by what the joints past the pair's last shared
    joint can move one link relative to the other (the shared ones move both together).
    """

    def __init__(self, arm: ArmSpec, planner):
        bounds = urdf_link_bounds(arm.urdf)
        joints = list(planner.user_joint_names[: arm.arm_joints])
        self._model = planner.pinocchio_model
        colliding = set(planner.robot.get_fcl_model().get_collision_link_names())
        links = [name for name in planner.link_name_2_idx if bounds[name].radius > 0 and name in colliding]
        self._index = [planner.link_name_2_idx[name] for name in links]
        # the balls of every link, each with its link's place in `links` and its lever
        self._owner = np.array([k for k, name in enumerate(links) for _ in bounds[name].balls], dtype=np.int64)
        self._center = np.array([c for name in links for c, _ in bounds[name].balls])
        self._radius = np.array([r for name in links for _, r in bounds[name].balls])
        link_lever = np.array([[bounds[name].lever.get(j, 0.0) for j in joints] for name in links])
        self._lever = link_lever[self._owner]
        self._tcp = planner.link_name_2_idx[arm.tcp_link]
        self._tcp_lever = np.array([bounds[arm.tcp_link].lever.get(j, 0.0) for j in joints])
        self._held: tuple[np.ndarray, float] | None = None
        # The link pairs mplib's self-collision test checks, as indices into the balls (None: a link of a pair has
        # no ball, so no stretch is certified free of self-collision).
        fcl = planner.robot.get_fcl_model()
        names = fcl.get_collision_link_names()
        pairs = sorted({tuple(sorted((names[i], names[j]))) for i, j in fcl.get_collision_pairs()})
        self._pairs = None
        if all(a in links and b in links for a, b in pairs):
            balls = [np.flatnonzero(self._owner == k) for k in range(len(links))]
            a, b = (np.array([x for la, lb in pairs for x in _pairs_of(balls[links.index(la)], balls[links.index(lb)])[k]],
                             dtype=np.int64) for k in (0, 1))
            # The joints that move both links of a pair move them together: only the joints past the last shared one
            # move one relative to the other.
            moved_by = (self._lever > 0).sum(axis=1)
            shared = np.minimum(moved_by[a], moved_by[b])
            past = np.arange(len(joints))[None, :] >= shared[:, None]
            self._pairs = (a, b, (self._lever[a] + self._lever[b]) * past, self._radius[a] + self._radius[b])

        self._boxes_of = None  # the boxes whose middles and half sizes are below

    def attach(self, center: np.ndarray | None, radius: float = 0.0) -> None:
        """A held object: a ball of ``radius`` about ``center`` in the TCP frame (None: nothing held)."""
        self._held = None if center is None else (np.asarray(center, dtype=np.float64), float(radius))

    def clear(self, qa: np.ndarray, qb: np.ndarray, fingers: np.ndarray, boxes: np.ndarray,
              own: bool = False) -> tuple[bool, bool, np.ndarray]:
        """Whether any configuration between arm joints ``qa`` and ``qb`` (fingers fixed) can bring a link or the held
        object within reach of any of ``boxes`` ((M, 2, 3) lower and upper corners, base frame), and, with ``own``,
        two links of a pair that mplib's self-collision test checks within reach of each other: (scene clear, self
        clear, which boxes may be reached); self clear is False without ``own``."""
        if len(boxes) == 0 and not own:
            return True, False, np.zeros(0, dtype=bool)
        mid = (qa + qb) / 2
        half = np.abs(qb - qa) / 2
        self._model.compute_forward_kinematics(np.concatenate([mid, fingers]))
        poses = np.array([self._model.get_link_pose(i) for i in self._index])[self._owner]
        centers = _rotate(poses[:, 3:], self._center) + poses[:, :3]
        radii = self._radius + self._lever @ half
        own_clear = False
        if own and self._pairs is not None:  # in the frame of each pair's last shared joint
            a, b, lever, radius = self._pairs
            d = centers[a] - centers[b]
            own_clear = bool((np.einsum("ij,ij->i", d, d) > (radius + lever @ half + 1e-6) ** 2).all())
        if len(boxes) == 0:
            return True, own_clear, np.zeros(0, dtype=bool)
        if self._held is not None:
            tcp = np.asarray(self._model.get_link_pose(self._tcp))[None]
            centers = np.vstack([centers, _rotate(tcp[:, 3:], self._held[0][None]) + tcp[:, :3]])
            lever = self._tcp_lever + np.linalg.norm(self._held[0]) + self._held[1]
            radii = np.append(radii, self._held[1] + lever @ half)
        # squared distance from each ball's centre to each box (0 inside it)
        if boxes is not self._boxes_of:
            self._boxes_of, self._box_mid, self._box_half = boxes, boxes.mean(axis=1), (boxes[:, 1] - boxes[:, 0]) / 2
        gap = np.abs(centers[:, None, :] - self._box_mid[None]) - self._box_half[None]
        np.maximum(gap, 0.0, out=gap)
        near = (np.einsum("ijk,ijk->ij", gap, gap) <= ((radii + 1e-6) ** 2)[:, None]).any(axis=0)
        return not near.any(), own_clear, near


def _pairs_of(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every pairing of an index of ``a`` with one of ``b``."""
    return np.repeat(a, len(b)), np.tile(b, len(a))


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` (N, 3) rotated by the rows of the unit quaternions ``q`` (N, 4: w, x, y, z)."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays (``np.cross``'s arithmetic, without its per-call overhead, which
    dominates for the few rows of a link-ball check)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


class _ShapeGeometry:
    """What the collision world needs of one PhysX collision shape, read once: its kind and size signature, the
    radius about its frame's origin that holds it, and its FCL geometry per margin (built on first use)."""

    def __init__(self, shape, fcl):
        self.shape, self._fcl = shape, fcl
        self.kind, self.signature = _shape_signature(shape)
        self._by_margin: dict[float, object] = {}
        if self.kind in ("convex", "mesh"):
            self.vertices = np.asarray(shape.vertices, dtype=np.float64) * np.asarray(shape.scale, dtype=np.float64)
            self.triangles = np.asarray(shape.triangles, dtype=np.int32)
            self.radius = float(np.linalg.norm(self.vertices, axis=1).max())
        elif self.kind == "box":
            self.radius = float(np.linalg.norm(shape.half_size))
        elif self.kind == "sphere":
            self.radius = float(shape.radius)
        elif self.kind in ("capsule", "cylinder"):
            self.radius = float(shape.radius) + float(shape.half_length)
        else:  # a plane: unbounded
            self.radius = np.inf

    def aabb(self, pose: np.ndarray, margin: float) -> np.ndarray:
        """(2, 3) lower and upper corners of a box that holds the shape grown by ``margin`` at ``pose`` (x, y, z, qw,
        qx, qy, qz; for capsules and cylinders the pose of the FCL shape, along z)."""
        rot = sapien.Pose(q=pose[3:]).to_transformation_matrix()[:3, :3]
        if self.kind == "box":
            half = np.abs(rot) @ (np.asarray(self.shape.half_size, dtype=np.float64) + margin)
        elif self.kind == "plane":
            half = np.abs(rot) @ _PLANE_SLAB_HALF
        elif self.kind in ("convex", "mesh"):
            v = _grown(self.vertices, margin) @ rot.T
            return np.stack([v.min(0), v.max(0)]) + pose[:3]
        else:  # sphere, capsule, cylinder: the ball about the centre (a grown cylinder reaches < radius + 2 margin)
            half = np.full(3, self.radius + 2 * margin)
        return np.stack([pose[:3] - half, pose[:3] + half])

    def fcl(self, margin: float):
        """The FCL geometry grown by ``margin`` (m)."""
        geom = self._by_margin.get(margin)
        if geom is None:
            geom = self._by_margin[margin] = self._build(margin)
        return geom

    def _build(self, m: float):
        fcl, shape = self._fcl, self.shape
        if self.kind == "box":
            return fcl.Box(*(2 * (np.asarray(shape.half_size, dtype=np.float64) + m)))
        if self.kind == "sphere":
            return fcl.Sphere(float(shape.radius) + m)
        if self.kind == "capsule":
            return fcl.Capsule(float(shape.radius) + m, 2 * float(shape.half_length))
        if self.kind == "cylinder":
            return fcl.Cylinder(float(shape.radius) + m, 2 * (float(shape.half_length) + m))
        if self.kind == "plane":
            return fcl.Box(*(2 * _PLANE_SLAB_HALF))
        verts = _grown(self.vertices, m)
        if self.kind == "convex":
            return fcl.Convex(verts, self.triangles)
        geom = fcl.BVHModel()  # triangle mesh
        geom.beginModel()
        geom.addSubModel(verts, self.triangles)
        geom.endModel()
        return geom


def _pose(p: np.ndarray | sapien.Pose) -> sapien.Pose:
    if isinstance(p, sapien.Pose):
        return p
    p = np.asarray(p, dtype=np.float64).reshape(-1)
    if p.shape != (7,):
        raise ValueError(f"a pose is 7 numbers (x, y, z, qw, qx, qy, qz), got shape {p.shape}")
    return sapien.Pose(p=p[:3], q=p[3:])


def _grown(verts: np.ndarray, margin: float) -> np.ndarray:
    """Mesh vertices pushed ``margin`` outward from their centroid: a convex shape grown by about ``margin``."""
    if margin == 0.0:
        return verts
    out = verts - verts.mean(0)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return verts + margin * out / np.maximum(norm, 1e-9)


def _shape_signature(shape) -> tuple[str, tuple[float, ...]]:
    physx = sapien.physx
    if isinstance(shape, physx.PhysxCollisionShapeBox):
        return "box", tuple(np.asarray(shape.half_size, dtype=float))
    if isinstance(shape, physx.PhysxCollisionShapeSphere):
        return "sphere", (float(shape.radius),)
    if isinstance(shape, physx.PhysxCollisionShapeCapsule):
        return "capsule", (float(shape.radius), float(shape.half_length))
    if isinstance(shape, physx.PhysxCollisionShapeCylinder):
        return "cylinder", (float(shape.radius), float(shape.half_length))
    if isinstance(shape, physx.PhysxCollisionShapeConvexMesh):
        v = np.asarray(shape.vertices) * np.asarray(shape.scale)
        return "convex", (len(v), *v.min(0), *v.max(0))
    if isinstance(shape, physx.PhysxCollisionShapeTriangleMesh):
        v = np.asarray(shape.vertices) * np.asarray(shape.scale)
        return "mesh", (len(v), *v.min(0), *v.max(0))
    if isinstance(shape, physx.PhysxCollisionShapePlane):
        return "plane", ()
    raise TypeError(f"unsupported PhysX collision shape {type(shape).__name__}")
