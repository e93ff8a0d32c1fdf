"""Scene files: a clutter layout (objects and their poses) as a YAML or JSON file, to replay, share or hand-edit.

The file's extension chooses the syntax (``.yaml`` / ``.yml``: YAML, ``.json``: JSON); both hold the same schema::

    format: 1                    # version of this schema (FORMAT_VERSION); required
    frame: workspace             # "workspace" or "world"; required
    name: two_bars               # optional text
    description: two bars side by side   # optional text
    objects:                     # one entry per object, at least one
      - kind: cuboid             # one of the procedural kinds of objects.KINDS, or mesh
        size: [0.02, 0.045, 0.02]    # the kind's size values, metres (objects.SIZE_PARAMS)
        color: [0.15, 0.35, 0.85]    # optional RGB in 0..1 (default ObjectSpec's 0.8, 0.3, 0.2)
        position: [-0.0205, 0.0, 0.02]   # metres, of the centre of the object's bounding box
        quaternion: [1.0, 0.0, 0.0, 0.0]  # w, x, y, z
      - kind: hull
        size: [0.05, 0.04, 0.03]
        seed: 7                  # optional int >= 0: the random points of a hull (ignored by the other kinds)
        position: [0.05, 0.0, 0.015]
        euler: {convention: xyz, angles: [0, 0, 30], degrees: true}

Frames. ``workspace``: x and y from the workspace centre (:attr:`WorkspaceSpec.center`), z above the table top
(:attr:`WorkspaceSpec.table_z`); the axes are the world's, so orientations are the same in both frames. A
workspace-frame file fits any workspace whose square holds it (the heightmap size does not matter). ``world``: the
simulation's world coordinates. An upright object resting on the table has z = half its height in the workspace
frame.

Orientation: exactly one of

* ``quaternion: [w, x, y, z]`` (scalar first, as SAPIEN); its norm must be within 1 % of 1, and it is normalised;
* ``euler: {convention: C, angles: [a, b, c], degrees: D}``: three rotations, ``angles[k]`` about the axis named by
  letter ``k`` of ``convention``, in radians, or degrees with ``degrees: true`` (default false). A lowercase
  convention is extrinsic (about the fixed axes of the frame, applied first letter first), an uppercase one is
  intrinsic (about the object's axes as they turn); no two consecutive letters may be the same. ``"xyz"`` is
  roll-pitch-yaw: roll ``a`` about x, then pitch ``b`` about the fixed y, then yaw ``c`` about the fixed z,
  ``R = Rz(c) @ Ry(b) @ Rx(a)``, the same rotation as intrinsic ``"ZYX"`` with angles ``[c, b, a]``. The conventions
  are those of scipy's ``Rotation.from_euler``.

Mesh objects (``kind: mesh``, :mod:`~maniskill_pnp.scenes.meshes`) take no ``size`` and no ``seed`` but::

      - kind: mesh
        file: parts/bracket.stl  # required: OBJ, STL, GLB or PLY; relative to the scene file's folder, or absolute
        scale: 0.001             # optional: one factor or [sx, sy, sz] (default 1); here millimetres to metres
        color: [0.6, 0.6, 0.65]  # optional, as above
        texture: false           # optional: true shows the file's own materials and textures instead of color
        density: 1000            # optional kg/m³ (default 1000)
        collision: parts/bracket_parts.obj  # optional: ready-made convex parts (else computed and cached)
        position: [0.0, 0.0, 0.02]   # the centre of the scaled mesh's bounding box
        quaternion: [1.0, 0.0, 0.0, 0.0]

:func:`save_scene` writes a mesh's path relative to the scene file's folder when the mesh lies in it (or below it),
else absolute.

Loading (:func:`load_scene`) checks the schema first, with errors that name the file, the object (``objects[i]``)
and the field, then builds the :class:`~maniskill_pnp.scenes.objects.ObjectSpec` of every entry and runs
:func:`~maniskill_pnp.scenes.clutter.validate_layout` on the objects' collision shapes: centres over the workspace
square, nothing below the table, no two interpenetrating by more than 1 mm, and objects that touch others (stacked,
leaning, lying in a cradle) at rest in a short physics settle. The poses of objects at rest in a simulation (what
:meth:`ClutterGraspEnv.export_scene <maniskill_pnp.tasks.clutter_grasp.ClutterGraspEnv.export_scene>` writes) pass it
as they are. Files of earlier versions may carry ``settled: true`` (then needed for exported scenes); the key is
still read and ignored. :func:`save_scene` writes a layout. YAML files accept exponents without a dot (``5e-3``), unlike
plain YAML 1.1.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sapien
import yaml

from maniskill_pnp.scenes.clutter import as_pose, validate_layout
from maniskill_pnp.scenes.objects import ALL_KINDS, DEFAULT_DENSITY, MESH_KIND, SIZE_PARAMS, ObjectSpec
from maniskill_pnp.cell.workspace import WorkspaceSpec

#: Version of the schema this module reads and writes (the file's ``format``).
FORMAT_VERSION = 1
#: Frames positions can be given in.
FRAMES = ("workspace", "world")
#: Extensions of the two syntaxes.
YAML_SUFFIXES = (".yaml", ".yml")
JSON_SUFFIXES = (".json",)
#: Keys of the top level and of an object entry (``settled`` is read and ignored: files of earlier versions have it).
TOP_KEYS = ("format", "frame", "name", "description", "settled", "objects")
OBJECT_KEYS = ("kind", "size", "color", "seed", "file", "scale", "texture", "density", "collision", "position", "quaternion",
               "euler")
#: Keys of the procedural kinds only, and of mesh objects only.
PROCEDURAL_KEYS = ("size", "seed")
MESH_KEYS = ("file", "scale", "texture", "density", "collision")
EULER_KEYS = ("convention", "angles", "degrees")
#: Decimals written by :func:`save_scene`: positions and colours (1 µm), quaternions and radians, degrees.
POSITION_DECIMALS, QUATERNION_DECIMALS, DEGREE_DECIMALS = 6, 9, 6


class SceneFileError(ValueError):
    """A scene file that does not follow the schema; the message names the file, the object and the field."""


@dataclass(frozen=True)
class SceneObject:
    """One object of a scene file: its spec and its pose in the file's frame (position, quaternion w, x, y, z)."""

    spec: ObjectSpec
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


@dataclass(frozen=True)
class Scene:
    """A scene file's contents, checked against the schema (not yet against a workspace)."""

    objects: tuple[SceneObject, ...]
    frame: str
    name: str | None = None
    description: str | None = None
    source: str = "<scene>"
    """Where it came from (the file's path), for error messages."""

    def layout(self, workspace: WorkspaceSpec) -> list[tuple[ObjectSpec, sapien.Pose]]:
        """The scene as a layout in ``workspace`` (world poses), validated by
        :func:`~maniskill_pnp.scenes.clutter.validate_layout`.

        Raises:
            SceneFileError: the layout does not fit ``workspace`` (the message names the file and the object).
        """
        origin = frame_origin(self.frame, workspace)
        layout = [(o.spec, sapien.Pose(p=np.asarray(o.position) + origin, q=np.asarray(o.quaternion))) for o in self.objects]
        try:
            return validate_layout(layout, workspace)
        except ValueError as e:  # validate_layout's "[layout] object(s) i (kind)" and "and j (kind)" are the file's objects[i]
            msg = re.sub(r"(?:layout )?\bobjects? (\d+) \(", r"objects[\1] (", str(e))
            msg = re.sub(r"\band (\d+) \(", r"and objects[\1] (", msg)
            raise SceneFileError(f"{self.source}: {msg}") from None


# ----------------------------------------------------------------------------- rotations
def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (w, x, y, z)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def check_convention(convention) -> str:
    """``convention`` if it is a valid Euler convention (see the module docstring), else a ValueError saying why."""
    if not (isinstance(convention, str) and len(convention) == 3 and (convention.islower() or convention.isupper())
            and set(convention.lower()) <= set("xyz") and all(a != b for a, b in zip(convention, convention[1:]))):
        raise ValueError(
            f"unknown convention {convention!r}: three axis letters of x, y, z, all lowercase (extrinsic, e.g. 'xyz' "
            "roll-pitch-yaw) or all uppercase (intrinsic, e.g. 'ZYX'), no two consecutive letters the same"
        )
    return convention


def euler_to_quat(angles: Sequence[float], convention: str, degrees: bool = False) -> np.ndarray:
    """Quaternion (w, x, y, z) of Euler ``angles`` in ``convention`` (see the module docstring)."""
    check_convention(convention)
    a = np.radians(np.asarray(angles, dtype=np.float64)) if degrees else np.asarray(angles, dtype=np.float64)
    if a.shape != (3,):
        raise ValueError(f"euler angles are three numbers, got {angles!r}")
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for axis, angle in zip(convention.lower(), a):
        e = np.zeros(4)
        e[0], e[1 + "xyz".index(axis)] = math.cos(angle / 2), math.sin(angle / 2)
        # extrinsic: each rotation about the fixed axes comes on the left; intrinsic: about the turned axes, on the right
        q = _quat_mul(e, q) if convention.islower() else _quat_mul(q, e)
    return q / np.linalg.norm(q)


def quat_to_matrix(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix of the unit quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def quat_to_euler_xyz(q: Sequence[float], degrees: bool = False) -> np.ndarray:
    """Extrinsic ``"xyz"`` angles (roll, pitch, yaw) of the quaternion (w, x, y, z): pitch in [-90°, 90°], roll and
    yaw in (-180°, 180°]; at pitch ±90° (gimbal lock) roll is 0."""
    r = quat_to_matrix(q)
    cos_pitch = math.hypot(r[0, 0], r[1, 0])
    pitch = math.atan2(-r[2, 0], cos_pitch)
    if cos_pitch > 1e-9:
        roll, yaw = math.atan2(r[2, 1], r[2, 2]), math.atan2(r[1, 0], r[0, 0])
    else:
        roll, yaw = 0.0, math.atan2(-r[0, 1], r[1, 1])
    a = np.array([roll, pitch, yaw])
    return np.degrees(a) if degrees else a


# ----------------------------------------------------------------------------- frames
def frame_origin(frame: str, workspace: WorkspaceSpec) -> np.ndarray:
    """World position of the origin of ``frame`` (see :data:`FRAMES`)."""
    if frame == "workspace":
        return np.array([*workspace.center, workspace.table_z], dtype=np.float64)
    if frame == "world":
        return np.zeros(3)
    raise ValueError(f"unknown frame {frame!r}; valid: {list(FRAMES)}")


# ----------------------------------------------------------------------------- reading
class _Loader(yaml.SafeLoader):
    """YAML with exponents without a dot (``5e-3``) read as floats."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _numbers(value, n: int, where: str, what: str) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != n or not all(_is_number(v) for v in value):
        raise SceneFileError(f"{where}: must be {what} ({n} finite numbers), got {value!r}")
    return tuple(float(v) for v in value)


def _check_keys(data: dict, allowed: Sequence[str], where: str) -> None:
    unknown = [k for k in data if k not in allowed]
    if unknown:
        raise SceneFileError(f"{where}: unknown key(s) {unknown}; valid keys: {list(allowed)}")


def _orientation(entry: dict, where: str) -> tuple[float, float, float, float]:
    given = [k for k in ("quaternion", "euler") if k in entry]
    if len(given) != 1:
        what = "both" if given else "neither"
        raise SceneFileError(f"{where}: give exactly one orientation, 'quaternion' or 'euler' (got {what})")
    if given[0] == "quaternion":
        q = np.array(_numbers(entry["quaternion"], 4, f"{where}.quaternion", "[w, x, y, z]"))
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 0.01:
            raise SceneFileError(f"{where}.quaternion: must be a unit quaternion [w, x, y, z], got norm {norm:.4g}")
        return tuple(float(v) for v in q / norm)
    euler = entry["euler"]
    ew = f"{where}.euler"
    if not isinstance(euler, dict):
        raise SceneFileError(f"{ew}: must be a mapping {{convention: xyz, angles: [roll, pitch, yaw], degrees: false}}, "
                             f"got {euler!r}")
    _check_keys(euler, EULER_KEYS, ew)
    if "convention" not in euler:
        raise SceneFileError(f"{ew}.convention: missing; name the convention explicitly (e.g. 'xyz', extrinsic "
                             "roll-pitch-yaw)")
    try:
        convention = check_convention(euler["convention"])
    except ValueError as e:
        raise SceneFileError(f"{ew}.convention: {e}") from None
    if "angles" not in euler:
        raise SceneFileError(f"{ew}.angles: missing (three angles, in the order of the convention)")
    angles = _numbers(euler["angles"], 3, f"{ew}.angles", f"three angles in the order of {convention!r}")
    degrees = euler.get("degrees", False)
    if not isinstance(degrees, bool):
        raise SceneFileError(f"{ew}.degrees: must be true or false, got {degrees!r}")
    return tuple(float(v) for v in euler_to_quat(angles, convention, degrees))


def _path(value, where: str, base_dir: Path) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise SceneFileError(f"{where}: must be a path (text) to an OBJ, STL, GLB or PLY file, relative to the scene file's "
                             f"folder or absolute, got {value!r}")
    path = Path(os.path.expanduser(value))
    return path if path.is_absolute() else base_dir / path


def _mesh_spec(entry: dict, where: str, base_dir: Path, color) -> ObjectSpec:
    """The spec of a ``kind: mesh`` entry (see the module docstring)."""
    from maniskill_pnp.scenes.meshes import resolve_mesh_path

    for key in PROCEDURAL_KEYS:
        if key in entry:
            raise SceneFileError(f"{where}.{key}: mesh objects take file and scale (and optionally texture, density, "
                                 f"collision), not {key}")
    if "file" not in entry:
        raise SceneFileError(f"{where}.file: missing (path of an OBJ, STL, GLB or PLY file, relative to the scene file's "
                             "folder or absolute)")
    files = {}
    for key in ("file", "collision"):
        if key in entry:
            try:
                files[key] = str(resolve_mesh_path(_path(entry[key], f"{where}.{key}", base_dir)))
            except ValueError as e:
                raise SceneFileError(e if isinstance(e, SceneFileError) else f"{where}.{key}: {e}") from None
    scale = entry.get("scale", 1.0)
    if _is_number(scale):
        scale = (float(scale),) * 3
    else:
        scale = _numbers(scale, 3, f"{where}.scale", "one factor or [sx, sy, sz]")
    if min(scale) <= 0:
        raise SceneFileError(f"{where}.scale: must be positive, got {list(scale)}")
    texture = entry.get("texture", False)
    if not isinstance(texture, bool):
        raise SceneFileError(f"{where}.texture: must be true or false, got {texture!r}")
    density = entry.get("density", DEFAULT_DENSITY)
    if not _is_number(density) or density <= 0:
        raise SceneFileError(f"{where}.density: must be a positive number (kg/m³), got {density!r}")
    try:
        return ObjectSpec(MESH_KIND, (), color, file=files["file"], scale=scale, texture=texture, density=float(density),
                          collision=files.get("collision"))
    except ValueError as e:
        raise SceneFileError(f"{where} ({MESH_KIND}): {e}") from None


def _object(entry, i: int, source: str, base_dir: Path) -> SceneObject:
    where = f"{source}: objects[{i}]"
    if not isinstance(entry, dict):
        raise SceneFileError(f"{where}: must be a mapping with kind, size, position and an orientation, got {entry!r}")
    _check_keys(entry, OBJECT_KEYS, where)
    if "kind" not in entry:
        raise SceneFileError(f"{where}.kind: missing; valid kinds: {list(ALL_KINDS)}")
    kind = entry["kind"]
    if kind not in ALL_KINDS:
        raise SceneFileError(f"{where}.kind: unknown kind {kind!r}; valid kinds: {list(ALL_KINDS)}")
    color = ObjectSpec.color if "color" not in entry else _numbers(entry["color"], 3, f"{where}.color", "RGB in 0..1")
    if not all(0.0 <= c <= 1.0 for c in color):
        raise SceneFileError(f"{where}.color: must be RGB in 0..1, got {list(color)}")
    if kind == MESH_KIND:
        spec = _mesh_spec(entry, where, base_dir, color)
    else:
        spec = _procedural_spec(entry, where, kind, color)
    if "position" not in entry:
        raise SceneFileError(f"{where}.position: missing ([x, y, z] in metres)")
    position = _numbers(entry["position"], 3, f"{where}.position", "[x, y, z] in metres")
    quaternion = _orientation(entry, where)
    return SceneObject(spec, position, quaternion)


def _procedural_spec(entry: dict, where: str, kind: str, color) -> ObjectSpec:
    for key in MESH_KEYS:
        if key in entry:
            raise SceneFileError(f"{where}.{key}: only mesh objects take {key} ({kind} objects take size)")
    params = SIZE_PARAMS[kind]
    if "size" not in entry:
        raise SceneFileError(f"{where}.size: missing; {kind} takes {len(params)} values {list(params)} (metres)")
    size = entry["size"]
    if not isinstance(size, (list, tuple)) or len(size) != len(params):
        got = f"{len(size)} values" if isinstance(size, (list, tuple)) else repr(size)
        raise SceneFileError(f"{where}.size: {kind} takes {len(params)} values {list(params)} (metres), got {got}")
    size = _numbers(size, len(params), f"{where}.size", f"{list(params)} in metres")
    seed = entry.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SceneFileError(f"{where}.seed: must be an int >= 0, got {seed!r}")
    try:
        return ObjectSpec(kind, size, color, seed)
    except ValueError as e:
        raise SceneFileError(f"{where} ({kind}): {e}") from None


def parse_scene(data, source: str = "<scene>", base_dir=None) -> Scene:
    """A :class:`Scene` from the parsed contents of a scene file (a dict), checked against the schema.

    Args:
        base_dir: The folder relative mesh paths start from (the scene file's; default the working directory).

    Raises:
        SceneFileError: the first problem found, naming ``source``, the object and the field.
    """
    if not isinstance(data, dict):
        raise SceneFileError(f"{source}: a scene file holds a mapping (format, frame, objects, ...), got {type(data).__name__}")
    _check_keys(data, TOP_KEYS, source)
    if "format" not in data:
        raise SceneFileError(f"{source}: format: missing; this version reads format {FORMAT_VERSION}")
    if isinstance(data["format"], bool) or data["format"] != FORMAT_VERSION:
        raise SceneFileError(f"{source}: format: unsupported version {data['format']!r}; this version reads format "
                             f"{FORMAT_VERSION}")
    frame = data.get("frame")
    if frame not in FRAMES:
        raise SceneFileError(f"{source}: frame: {'missing' if frame is None else f'unknown frame {frame!r}'}; valid "
                             f"frames: {list(FRAMES)}")
    for key in ("name", "description"):
        if data.get(key) is not None and not isinstance(data[key], str):
            raise SceneFileError(f"{source}: {key}: must be text, got {data[key]!r}")
    # "settled" (files of earlier versions) is ignored: every layout is checked by its shapes
    objects = data.get("objects")
    if not isinstance(objects, list) or not objects:
        raise SceneFileError(f"{source}: objects: must be a non-empty list of objects, got {objects!r}")
    base = Path.cwd() if base_dir is None else Path(base_dir)
    return Scene(tuple(_object(entry, i, source, base) for i, entry in enumerate(objects)), frame, data.get("name"),
                 data.get("description"), source)


def _syntax(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in YAML_SUFFIXES:
        return "yaml"
    if suffix in JSON_SUFFIXES:
        return "json"
    raise SceneFileError(f"{path}: a scene file ends in {', '.join(YAML_SUFFIXES + JSON_SUFFIXES)}, got {suffix or 'no extension'!r}")


def read_scene(path) -> Scene:
    """The scene file ``path`` read and checked against the schema (not against a workspace: see :meth:`Scene.layout`).

    Raises:
        FileNotFoundError: no such file.
        SceneFileError: a bad extension, syntax or schema (the message names the file, the object and the field).
    """
    path = Path(path)
    syntax = _syntax(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene file {path} does not exist")
    text = path.read_text(encoding="utf-8")
    try:
        data = json.loads(text) if syntax == "json" else yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader)
    except (json.JSONDecodeError, yaml.YAMLError) as e:
        raise SceneFileError(f"{path}: not valid {syntax.upper()}: {e}") from None
    return parse_scene(data, str(path), base_dir=path.resolve().parent)


def load_scene(path, workspace: WorkspaceSpec) -> list[tuple[ObjectSpec, sapien.Pose]]:
    """The layout of the scene file ``path`` in ``workspace``: ``(ObjectSpec, world pose)`` per object, validated.

    Raises:
        FileNotFoundError: no such file.
        SceneFileError: see :func:`read_scene` and :meth:`Scene.layout`.
    """
    return read_scene(path).layout(workspace)


# ----------------------------------------------------------------------------- writing
class _FlowDict(dict):
    """A mapping written on one line in YAML (an object's ``euler``)."""


class _Dumper(yaml.SafeDumper):
    pass


_Dumper.add_representer(_FlowDict, lambda dumper, d: dumper.represent_mapping("tag:yaml.org,2002:map", d, flow_style=True))


def _round(values, decimals: int) -> list[float]:
    return [float(round(float(v), decimals)) + 0.0 for v in values]  # + 0.0: no "-0.0"


def _mesh_path(file: str, base_dir: Path | None) -> str:
    """A mesh's path as a scene file in ``base_dir`` writes it: relative when it lies in that folder, else absolute."""
    path = Path(file)
    if base_dir is not None:
        try:
            return path.relative_to(Path(base_dir).resolve()).as_posix()
        except ValueError:
            pass
    return str(path)


def scene_data(layout, workspace: WorkspaceSpec, frame: str = "workspace", name: str | None = None,
               description: str | None = None, orientation: str = "quaternion", base_dir=None) -> dict:
    """The contents of a scene file of ``layout`` (``(ObjectSpec, pose)`` entries, world poses as for
    :func:`~maniskill_pnp.scenes.clutter.as_pose`), positions in ``frame``.

    Args:
        orientation: ``"quaternion"`` (exact, w >= 0) or ``"euler"`` (extrinsic ``"xyz"`` in degrees, easy to edit).
        base_dir: The scene file's folder: mesh files inside it are written relative to it (others, and all without
            ``base_dir``, as absolute paths).
    """
    if orientation not in ("quaternion", "euler"):
        raise ValueError(f"orientation must be 'quaternion' or 'euler', got {orientation!r}")
    origin = frame_origin(frame, workspace)
    data: dict = dict(format=FORMAT_VERSION, frame=frame)
    if name is not None:
        data["name"] = str(name)
    if description is not None:
        data["description"] = str(description)
    objects = []
    for i, entry in enumerate(layout):
        if not isinstance(entry, (tuple, list)) or len(entry) != 2 or not isinstance(entry[0], ObjectSpec):
            raise ValueError(f"layout entry {i} must be (ObjectSpec, pose), got {entry!r}")
        spec, pose = entry[0], as_pose(entry[1])
        if spec.kind == MESH_KIND:
            scale = spec.scale[0] if len(set(spec.scale)) == 1 else list(spec.scale)
            obj: dict = dict(kind=spec.kind, file=_mesh_path(spec.file, base_dir), scale=scale,
                             color=_round(spec.color, POSITION_DECIMALS))
            if spec.texture:
                obj["texture"] = True
            if spec.density != DEFAULT_DENSITY:
                obj["density"] = spec.density
            if spec.collision is not None:
                obj["collision"] = _mesh_path(spec.collision, base_dir)
        else:
            obj = dict(kind=spec.kind, size=list(spec.size), color=_round(spec.color, POSITION_DECIMALS))
        if spec.kind == "hull":
            obj["seed"] = int(spec.seed)
        obj["position"] = _round(np.asarray(pose.p, dtype=np.float64) - origin, POSITION_DECIMALS)
        q = np.asarray(pose.q, dtype=np.float64)
        q = q / np.linalg.norm(q) * (1.0 if q[0] >= 0 else -1.0)
        if orientation == "quaternion":
            obj["quaternion"] = _round(q, QUATERNION_DECIMALS)
        else:
            obj["euler"] = _FlowDict(convention="xyz", angles=_round(quat_to_euler_xyz(q, degrees=True), DEGREE_DECIMALS),
                                degrees=True)
        objects.append(obj)
    data["objects"] = objects
    return data


def save_scene(path, layout, workspace: WorkspaceSpec, frame: str = "workspace", name: str | None = None,
               description: str | None = None, orientation: str = "quaternion", validate: bool = True) -> Path:
    """Write ``layout`` (``(ObjectSpec, world pose)`` entries) as the scene file ``path`` (YAML or JSON by its
    extension); see :func:`scene_data` for the arguments. Sizes and scales are written exactly; positions and colours
    to 1 µm, quaternions to 1e-9, Euler angles to 1e-6 degrees; mesh files relative to ``path``'s folder when they lie
    in it, else as absolute paths.

    Args:
        validate: First check the layout with :func:`~maniskill_pnp.scenes.clutter.validate_layout`, so no file is
            written that would not load.

    Returns:
        ``path``.

    Raises:
        ValueError: a bad layout, frame, orientation or extension.
    """
    path = Path(path)
    syntax = _syntax(path)
    if validate:
        validate_layout(layout, workspace)
    data = scene_data(layout, workspace, frame, name, description, orientation, base_dir=path.resolve().parent)
    if syntax == "json":
        text = json.dumps(data, indent=2) + "\n"
    else:
        header = (f"# maniskill_pnp scene file (format {FORMAT_VERSION}): metres, colours RGB 0..1, quaternion [w, x, y, z],\n"
                  "# euler convention 'xyz' = extrinsic roll-pitch-yaw.\n")
        if frame == "workspace":
            header += "# frame workspace: x, y from the workspace centre, z above the table top.\n"
        text = header + yaml.dump(data, Dumper=_Dumper, sort_keys=False, default_flow_style=None, width=120)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
    return path


__all__ = ["FORMAT_VERSION", "FRAMES", "Scene", "SceneFileError", "SceneObject", "check_convention", "euler_to_quat",
           "frame_origin", "load_scene", "parse_scene", "quat_to_euler_xyz", "quat_to_matrix", "read_scene", "save_scene",
           "scene_data"]
