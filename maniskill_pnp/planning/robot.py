"""The robot the planners know about: ManiSkill's Panda, described from the assets ManiSkill ships.

Everything here is read from ManiSkill's own agent (URDF/SRDF paths, joint limits, controller ranges), so
the planner and the simulator agree on one model of the arm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
import xml.etree.ElementTree as ET

import numpy as np


@dataclass(frozen=True)
class ArmSpec:
    """Kinematic and gripper facts of a parallel-jaw arm, as the planning layer needs them.

    Attributes:
        urdf: Path of the robot URDF (collision meshes are resolved relative to it).
        srdf: Path of the SRDF listing link pairs that never collide (for self-collision filtering).
        tcp_link: Link whose pose a grasp pose specifies (the point between the fingertips).
        arm_joints: Number of actuated arm joints (planning dimension).
        lower: Lower joint limits of the arm joints (rad).
        upper: Upper joint limits of the arm joints (rad).
        gripper_open: Finger joint position when open (m, per finger).
        gripper_closed: Finger joint position commanded to close (m, per finger; may be below 0 to squeeze).
        home: A collision-free rest configuration of the arm joints, above the workspace.
        max_velocity: Joint velocity limit (rad/s) of the straight-line moves, which touch or may touch objects (a
            grasp's descent and lift, a slide's lowering, push and retract): slow enough that a guarded move stops
            on the first contact.
        max_acceleration: Joint acceleration limit (rad/s^2) of the straight-line moves.
        free_velocity: Joint velocity limit (rad/s) of the planned motions through free space (to a pre-grasp or
            pre-slide pose, carrying a held object to its release pose, home). The default is the Panda's rated
            limit of joints 1-4, the lowest of its seven.
        free_acceleration: Joint acceleration limit (rad/s^2) of the planned motions, below the Panda's rated
            7.5-20 rad/s^2.
    """

    urdf: Path
    srdf: Path
    tcp_link: str
    arm_joints: int
    lower: np.ndarray
    upper: np.ndarray
    gripper_open: float
    gripper_closed: float
    home: np.ndarray
    max_velocity: float = 1.5
    max_acceleration: float = 2.0
    free_velocity: float = 2.175
    free_acceleration: float = 6.0
    finger_links: tuple[str, ...] = field(default=("panda_leftfinger", "panda_rightfinger"))

    def limits(self, free: bool) -> tuple[float, float]:
        """(velocity, acceleration) limits of a planned motion through free space (``free``) or of a straight-line
        move."""
        return (self.free_velocity, self.free_acceleration) if free else (self.max_velocity, self.max_acceleration)

    def clip(self, q: np.ndarray) -> np.ndarray:
        """Clip arm joint values into the joint limits."""
        return np.clip(q, self.lower, self.upper)

    def within_limits(self, q: np.ndarray, tol: float = 1e-6) -> bool:
        """True when every arm joint lies within its limits (with a small tolerance)."""
        return bool(np.all(q >= self.lower - tol) and np.all(q <= self.upper + tol))


def panda_spec() -> ArmSpec:
    """The Panda of ManiSkill 3 (``panda_v2.urdf``) with the TCP between the fingertips.

    Joint limits come from the URDF and the home configuration from ManiSkill's ``rest`` keyframe, so
    the planner uses exactly the arm the simulator loads.
    """
    from mani_skill.agents.robots.panda.panda import Panda

    urdf = Path(Panda.urdf_path)
    names = [f"panda_joint{i}" for i in range(1, 8)]
    lower, upper = urdf_joint_limits(urdf, names)
    return ArmSpec(
        urdf=urdf,
        srdf=urdf.with_suffix(".srdf"),
        tcp_link="panda_hand_tcp",
        arm_joints=len(names),
        lower=lower,
        upper=upper,
        gripper_open=0.04,
        gripper_closed=-0.01,
        home=np.asarray(Panda.keyframes["rest"].qpos[: len(names)], dtype=np.float64),
    )


def urdf_joint_limits(urdf: Path, joint_names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper position limits of the named joints, read from a URDF file."""
    root = ET.parse(urdf).getroot()
    limits = {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if limit is not None and "lower" in limit.attrib:
            limits[joint.attrib["name"]] = (float(limit.attrib["lower"]), float(limit.attrib["upper"]))
    missing = [n for n in joint_names if n not in limits]
    if missing:
        raise ValueError(f"{urdf} has no position limits for joints {missing}")
    lo, hi = zip(*(limits[n] for n in joint_names))
    return np.array(lo), np.array(hi)


@dataclass(frozen=True)
class LinkBound:
    """A ball that holds a link's collision geometry, and how far joint motions can move it.

    Attributes:
        center: The ball's centre in the link's frame (m).
        radius: Its radius (m).
        lever: Per joint name of the chain from the root to the link: a bound on the distance from that joint's origin
            to any point of the link in any configuration (m): the joint origins' offsets in between, the largest
            travel of prismatic joints in between, and the ball. A rotation of that joint by ``d`` rad moves no point
            of the link farther than ``lever * |d|``.
        depth: The distance bound from the root link's origin to the link's frame origin (m).
        balls: Smaller balls ``(center, radius)`` in the link's frame that together hold its collision geometry (see
            :func:`covering_balls`); empty for a link without any.
    """

    center: np.ndarray
    radius: float
    lever: dict[str, float]
    depth: float
    balls: tuple[tuple[np.ndarray, float], ...] = ()


def covering_balls(points: np.ndarray, parts: int = 3) -> tuple[tuple[np.ndarray, float], ...]:
    """``parts`` balls that together hold the convex hull of ``points`` (N×3): the hull cut into slabs of equal
    thickness across its principal axis, each slab's piece held by a ball about the middle of its bounding box.

    A piece of the hull between two planes is the hull of the points between them and of where the segments between
    points cross the planes (every edge of the hull is such a segment), so a ball that holds those holds the piece.
    """
    points = np.unique(np.asarray(points, dtype=np.float64), axis=0)
    if len(points) < 4 or parts < 2:
        return (_ball_about_box(points),)
    axis = np.linalg.svd(points - points.mean(0), full_matrices=False)[2][0]
    s = points @ axis
    cuts = np.linspace(s.min(), s.max(), parts + 1)[1:-1]
    i, j = np.triu_indices(len(points), k=1)
    crossings = []
    for t in cuts:  # where the segments between points on either side of the plane s = t cross it
        k = (s[i] - t) * (s[j] - t) < 0
        w = ((t - s[i][k]) / (s[j][k] - s[i][k]))[:, None]
        crossings.append(points[i[k]] + w * (points[j[k]] - points[i[k]]))
    bounds = [-np.inf, *cuts, np.inf]
    balls = []
    for n in range(parts):
        piece = [points[(s >= bounds[n]) & (s <= bounds[n + 1])]]
        piece += [crossings[m] for m in (n - 1, n) if 0 <= m < len(cuts)]
        balls.append(_ball_about_box(np.concatenate(piece)))
    return tuple(balls)


def _ball_about_box(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The ball about the middle of the bounding box of ``points`` (N×3) that holds them all."""
    lo, hi = points.min(0), points.max(0)
    center = (lo + hi) / 2
    return center, float(np.linalg.norm(points - center, axis=1).max())


@lru_cache(maxsize=8)
def urdf_link_bounds(urdf: Path) -> dict[str, LinkBound]:
    """A :class:`LinkBound` for every link of ``urdf`` (links without collision geometry: a zero ball at the frame
    origin), from its collision geometry (meshes loaded with trimesh) and the kinematic chain."""
    import trimesh
    from scipy.spatial.transform import Rotation

    urdf = Path(urdf)
    root = ET.parse(urdf).getroot()

    def origin_of(element) -> tuple[np.ndarray, np.ndarray]:
        origin = element.find("origin")
        attrib = {} if origin is None else origin.attrib
        xyz = np.array([float(v) for v in attrib.get("xyz", "0 0 0").split()])
        rpy = [float(v) for v in attrib.get("rpy", "0 0 0").split()]
        return xyz, Rotation.from_euler("xyz", rpy).as_matrix()

    parent_joint = {}
    for joint in root.iter("joint"):
        xyz, _ = origin_of(joint)
        travel = 0.0
        if joint.attrib.get("type") == "prismatic":
            limit = joint.find("limit")
            travel = max(abs(float(limit.attrib["lower"])), abs(float(limit.attrib["upper"])))
        parent_joint[joint.find("child").attrib["link"]] = (joint.attrib["name"], joint.find("parent").attrib["link"],
                                                            float(np.linalg.norm(xyz)), travel)

    def points(link) -> np.ndarray:
        out = []
        for collision in link.findall("collision"):
            xyz, rot = origin_of(collision)
            geom = collision.find("geometry")[0]
            if geom.tag == "box":
                half = np.array([float(v) for v in geom.attrib["size"].split()]) / 2
                local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
            elif geom.tag == "sphere":
                r = float(geom.attrib["radius"])
                local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * r  # its cube
            elif geom.tag in ("cylinder", "capsule"):
                r, h = float(geom.attrib["radius"]), float(geom.attrib["length"]) / 2 + (float(geom.attrib["radius"]) if geom.tag == "capsule" else 0.0)
                local = np.array([[x, y, z] for x in (-r, r) for y in (-r, r) for z in (-h, h)])
            elif geom.tag == "mesh":
                mesh = trimesh.load(urdf.parent / geom.attrib["filename"], force="mesh")
                scale = np.array([float(v) for v in geom.attrib.get("scale", "1 1 1").split()])
                local = np.asarray(mesh.vertices, dtype=np.float64) * scale
            else:
                raise ValueError(f"{urdf}: unsupported collision geometry {geom.tag!r}")
            out.append(local @ rot.T + xyz)
        return np.concatenate(out) if out else np.zeros((1, 3))

    bounds = {}
    for link in root.iter("link"):
        name = link.attrib["name"]
        pts = points(link)
        center = (pts.min(0) + pts.max(0)) / 2
        radius = float(np.linalg.norm(pts - center, axis=1).max()) if link.findall("collision") else 0.0
        reach = float(np.linalg.norm(center)) + radius
        lever, length, node = {}, 0.0, name
        while node in parent_joint:  # walk to the root: each joint's lever is what lies beyond its origin
            joint, node, offset, travel = parent_joint[node]
            length += travel
            lever[joint] = length + reach
            length += offset
        bounds[name] = LinkBound(center, radius, lever, length, covering_balls(pts) if link.findall("collision") else ())
    return bounds


def urdf_reach(urdf: Path, link: str | None = None) -> float:
    """A radius about the root link's origin that holds every collision shape of the robot in every configuration
    (m); with ``link``, the radius that holds that link's frame origin.

    By the triangle inequality along the kinematic chain (:func:`urdf_link_bounds`): the lengths of the joint origins'
    translations from the root, each prismatic joint's largest travel, and the farthest point of the link's collision
    geometry from its frame. No configuration of the arm puts any part of it farther away.
    """
    bounds = urdf_link_bounds(Path(urdf))
    if link is not None:
        if link not in bounds:
            raise ValueError(f"{urdf} has no link {link!r}")
        return bounds[link].depth
    return max(b.depth + float(np.linalg.norm(b.center)) + b.radius for b in bounds.values())
