"""ManiSkill's YCB models as clutter objects (``kind="mesh"`` specs), read from ManiSkill's asset folder.

ManiSkill's ``ycb`` data source (``mani_skill.utils.assets.DATA_SOURCES["ycb"]``: ``<MS_ASSET_DIR or ~/.maniskill>/
data/assets/mani_skill2_ycb``) holds ``info_pick_v0.json`` (per model id: its bounding box ``bbox``, ``scales`` and
optionally ``density``) and ``models/<id>/textured.obj`` (the visual mesh, with its texture) and
``models/<id>/collision.ply`` (ready-made convex parts), the files ManiSkill's own YCB builder reads. Nothing is
downloaded here: without the assets the functions raise a ``FileNotFoundError`` naming ManiSkill's download command,
:data:`DOWNLOAD_COMMAND`.

Each model becomes ``ObjectSpec("mesh", file=textured.obj, scale=scales[0], texture=True, density=...,
collision=collision.ply)`` (:func:`ycb_spec`). Models the Panda's jaws cannot take (wider than
:data:`~maniskill_pnp.scenes.objects.MAX_GRASP_WIDTH` everywhere, a side over
:data:`~maniskill_pnp.scenes.objects.MAX_SIDE`, lower than :data:`~maniskill_pnp.scenes.objects.MIN_HEIGHT`) are
skipped with a reason by :func:`ycb_specs` when it lists them all, and raise when named explicitly.

Example:
    >>> specs, skipped = ycb_specs()                 # every model that fits the gripper, and why the others do not
    >>> env = gym.make("ClutterGrasp-v1", objects="ycb")                       # random clutters of those
    >>> env = gym.make("ClutterGrasp-v1", objects=["005_tomato_soup_can", "077_rubiks_cube"])
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from maniskill_pnp.scenes.objects import DEFAULT_DENSITY, MAX_GRASP_WIDTH, MAX_SIDE, MESH_KIND, MIN_HEIGHT, ObjectSpec

#: The source name of ``objects="ycb"``.
YCB_SOURCE = "ycb"
#: ManiSkill's data source id of the YCB models, and the command that downloads them.
DATA_SOURCE_ID = "ycb"
DOWNLOAD_COMMAND = f"python -m mani_skill.utils.download_asset {DATA_SOURCE_ID}"
INFO_FILE = "info_pick_v0.json"


def ycb_dir() -> Path:
    """The folder of ManiSkill's YCB assets, as ManiSkill's data source says (whether or not it exists)."""
    from mani_skill.utils.assets import DATA_SOURCES

    source = DATA_SOURCES[DATA_SOURCE_ID]
    return Path(source.output_dir) / source.target_path


def _info() -> dict:
    root = ycb_dir()
    path = root / INFO_FILE
    if not path.is_file():
        raise FileNotFoundError(f"ManiSkill's YCB assets are not in {root} (no {INFO_FILE}); download them with "
                                f"`{DOWNLOAD_COMMAND}`")
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ValueError(f"cannot read {path}: {e}") from None
    if not isinstance(info, dict):
        raise ValueError(f"{path}: expected a mapping of model ids, got {type(info).__name__}")
    return info


def ycb_model_ids() -> list[str]:
    """Every YCB model id of ManiSkill's assets (sorted), whether or not it fits the gripper.

    Raises:
        FileNotFoundError: the assets are not downloaded (the message gives :data:`DOWNLOAD_COMMAND`).
    """
    return sorted(_info())


def _too_large(model_id: str, meta: dict, scale: float) -> str:
    """Why the model's bounding box (from its info) rules it out, or ""."""
    try:
        lo, hi = (meta["bbox"][k] for k in ("min", "max"))
        ext = [(b - a) * scale for a, b in zip(lo, hi)]
    except (KeyError, TypeError, ValueError):
        return ""  # no usable box: the spec's own check decides
    if ext[2] < MIN_HEIGHT:
        return f"{ext[2]:.3f} m high, under {MIN_HEIGHT} m"
    if min(ext[0], ext[1]) > MAX_GRASP_WIDTH:
        return f"footprint {ext[0]:.3f} x {ext[1]:.3f} m, wider than the jaws' {MAX_GRASP_WIDTH} m both ways"
    if max(ext[0], ext[1]) > MAX_SIDE:
        return f"footprint {ext[0]:.3f} x {ext[1]:.3f} m, a side over {MAX_SIDE} m"
    return ""


def ycb_spec(model_id: str, color=(0.8, 0.3, 0.2)) -> ObjectSpec:
    """The mesh spec of YCB model ``model_id`` (its textured mesh, ManiSkill's scale, density and convex parts).

    Raises:
        FileNotFoundError: the assets are not downloaded.
        ValueError: an unknown id, missing model files, or a model the gripper cannot take (the message says why).
    """
    info = _info()
    if model_id not in info:
        ids = sorted(info)
        raise ValueError(f"unknown YCB model {model_id!r}; {len(ids)} models in {ycb_dir()}, e.g. {ids[:5]}")
    meta = info[model_id] if isinstance(info[model_id], dict) else {}
    scales = meta.get("scales", [1.0])
    scale = float(scales[0] if isinstance(scales, (list, tuple)) and scales else scales)
    reason = _too_large(model_id, meta, scale)
    if reason:
        raise ValueError(f"YCB model {model_id} does not fit the gripper: {reason}")
    model_dir = ycb_dir() / "models" / model_id
    visual = model_dir / "textured.obj"
    if not visual.is_file():
        raise ValueError(f"YCB model {model_id}: {visual} is missing (re-download with `{DOWNLOAD_COMMAND}`)")
    collision = model_dir / "collision.ply"
    try:
        return ObjectSpec(MESH_KIND, (), tuple(color), file=str(visual), scale=scale, texture=True,
                          density=float(meta.get("density", DEFAULT_DENSITY)),
                          collision=str(collision) if collision.is_file() else None)
    except ValueError as e:
        raise ValueError(f"YCB model {model_id}: {e}") from None


def ycb_specs(model_ids: Sequence[str] | None = None) -> tuple[list[ObjectSpec], dict[str, str]]:
    """Specs of YCB models: of ``model_ids`` (each must fit the gripper), or of every model that fits.

    Returns:
        The specs, and for every model left out (only when listing all) the reason.

    Raises:
        FileNotFoundError: the assets are not downloaded (the message gives :data:`DOWNLOAD_COMMAND`).
        ValueError: a named model that is unknown or does not fit the gripper.
    """
    if model_ids is not None:
        if isinstance(model_ids, str) or not all(isinstance(m, str) for m in model_ids):
            raise ValueError(f"model_ids must be a list of YCB model ids, got {model_ids!r}")
        return [ycb_spec(m) for m in model_ids], {}
    specs, skipped = [], {}
    for model_id in ycb_model_ids():
        try:
            specs.append(ycb_spec(model_id))
        except ValueError as e:
            skipped[model_id] = str(e)
    return specs, skipped
