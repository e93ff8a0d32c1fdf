"""ClutterGraspSlide-v1: grasp and slide ("G&S") in any clutter, tightly packed allowed (thesis part III).

ClutterGrasp-v1 with two more primitives. The action is one flat index over (primitive, rotation, row, col),
primitives ``grasp``, ``left_slide`` and ``right_slide`` (:class:`~maniskill_pnp.cell.pixel_action.PixelActionLayout`
with 3 primitives). A grasp is ClutterGrasp-v1's grasp-and-place. A slide lowers the closed fingertips at the
pixel's 3-D point (:meth:`WorkspaceSpec.slide_tip_height`: the highest surface within ``slide_clearance`` of the
pixel, so the tip comes down beside objects) and pushes ``slide_length`` (8 cm) straight to the left or right of
the rotation's jaw direction (:meth:`WorkspaceSpec.slide_direction`: left is the jaw direction turned +90° about
world z; rotation 0 pushes left along +y, right along -y). The closed fingers face the push, a flat pusher.

A slide succeeds when it changed the scene: VPG's heightmap test, more than :data:`CHANGE_PIXELS` pixels of a
:data:`CHANGE_REFERENCE_SIZE`² heightmap (VPG's 300 of 224×224) whose height changed by more than
:data:`CHANGE_MIN_DELTA` and less than :data:`CHANGE_MAX_DELTA` metres. For another heightmap size the pixel count
scales with the heightmap's pixel count, so the same share of the heightmap must change (with the default 0.448 m
workspace, the same area of table: about 24.5 pixels of a 64×64 heightmap); see :func:`heightmap_changed`.
A slide that knocks an object out of the workspace is a failure whatever it changed (reward 0; ``info["knocked_out"]``
counts the objects, ``info["reason"]`` says so): otherwise clearing the table by pushing would pay.

Reward schemes (:data:`REWARD_SCHEMES`): ``"default"`` pays a slide for any change, as VPG does;
``"no_slide_reward"`` never; ``"unlock"`` pays it by its effect: only when it changed the scene *and* made an
object graspable that was not (``info["slide_unlocked"]``: objects near the ones it moved that were *locked*
before it and are not after, by :func:`~maniskill_pnp.scenes.grasp_feasibility.grasp_feasibility` on the objects'
collision shapes at their poses, on the grid of :data:`UNLOCK_CHECK`). A slide that merely shuffles objects that a
grasp could take anyway, or pushes a locked block as a whole, then earns nothing. ``"unlock_each"`` counts what
``"unlock"`` judges: 0.5 per object the slide made graspable, for at most two objects (a slide never pays more than
a placement), so one slide that frees two objects earns what two slides that free one each earn,
in one action fewer. ``"fit_gain"`` pays a slide as ``"unlock"`` does, but judged from the heightmaps alone, as a real
cell could: the slide must add a graspable region (``info["slide_fit_gain"]``: the connected regions of material in
the heightmap where some grasp fits, :func:`~maniskill_pnp.scenes.heightmap_fit.graspable_regions`, after the slide
less before it; about one per object a grasp can take). No simulator shape or pose enters it.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import torch

from maniskill_pnp.scenes.clutter import validate_layout
from maniskill_pnp.tasks.clutter_grasp import ClutterGraspEnv
from maniskill_pnp.scenes.complicated_layouts import COMPLICATED_LAYOUT_NAMES, complicated_layouts
from maniskill_pnp.scenes.grasp_feasibility import grasp_feasibility
from maniskill_pnp.scenes.heightmap_fit import HeightmapGraspFit, graspable_regions
from maniskill_pnp.tasks.primitive_env import Judgement
from maniskill_pnp.tasks.registration import register_task

#: Rewards per scheme: object placed in the bin, grasped but not placed, slide that changed the scene; and how a
#: slide is judged: with ``freed_paid`` > 0 by the objects it made graspable in the simulator (``info["slide_unlocked"]``),
#: with ``fit_paid`` > 0 by the graspable regions it added to the heightmap (``info["slide_fit_gain"]``), paying
#: ``slide`` per such object or region, for at most that many (both 0: a slide pays for any change).
REWARD_SCHEMES = {
    "default": dict(place=1.0, grasp=0.8, slide=0.5, freed_paid=0, fit_paid=0),
    "no_slide_reward": dict(place=1.0, grasp=0.8, slide=0.0, freed_paid=0, fit_paid=0),
    "unlock": dict(place=1.0, grasp=0.8, slide=0.5, freed_paid=1, fit_paid=0),
    "unlock_each": dict(place=1.0, grasp=0.8, slide=0.5, freed_paid=2, fit_paid=0),
    "fit_gain": dict(place=1.0, grasp=0.8, slide=0.5, freed_paid=0, fit_paid=1),
}
#: A heightmap pixel holds material above this height (m), for the graspable regions of ``"fit_gain"`` (the agents'
#: material test).
MATERIAL_HEIGHT = 0.01
#: The grasp-feasibility grid of the unlock schemes: the agent's 8 jaw lines, a coarser grid than
#: ``check-scene``'s (a check of the objects around a slide takes about 0.1-0.3 s on one core).
UNLOCK_CHECK = dict(yaw_step_deg=22.5, position_step=0.004, resolution=0.001, first_only=True)
#: Objects moved by more than this (m) count as moved by a slide; objects within UNLOCK_REACH (m, centre to
#: centre) of a moved one are checked before and after it.
MOVED = 0.005
UNLOCK_REACH = 0.15

#: VPG's scene-change test: more than CHANGE_PIXELS pixels of a CHANGE_REFERENCE_SIZE² heightmap changed by a
#: height in (CHANGE_MIN_DELTA, CHANGE_MAX_DELTA) metres.
CHANGE_PIXELS = 300
CHANGE_REFERENCE_SIZE = 224
CHANGE_MIN_DELTA = 0.01
CHANGE_MAX_DELTA = 0.3


def changed_pixels(before: np.ndarray, after: np.ndarray) -> int:
    """Pixels whose height (m) changed by more than ``CHANGE_MIN_DELTA`` and less than ``CHANGE_MAX_DELTA``."""
    d = np.abs(np.asarray(after, np.float64) - np.asarray(before, np.float64))
    return int(np.count_nonzero((d > CHANGE_MIN_DELTA) & (d < CHANGE_MAX_DELTA)))


def change_threshold(height: int, width: int) -> float:
    """Changed pixels a ``height``×``width`` heightmap needs: ``CHANGE_PIXELS`` scaled by its share of a 224×224 map."""
    return CHANGE_PIXELS * height * width / CHANGE_REFERENCE_SIZE**2


def heightmap_changed(before: np.ndarray, after: np.ndarray) -> bool:
    """VPG's "the scene changed" test on two heightmaps of the same shape (see the module docstring)."""
    if np.shape(before) != np.shape(after):
        raise ValueError(f"heightmaps must have the same shape, got {np.shape(before)} and {np.shape(after)}")
    return changed_pixels(before, after) > change_threshold(*np.shape(before)[-2:])


@register_task("ClutterGraspSlide-v1", max_episode_steps=None)
class ClutterGraspSlideEnv(ClutterGraspEnv):
    """**Task Description:**
    Any clutter of regular and irregular objects, tightly packed allowed, lies in the workspace in front of the
    Panda; a bin stands beside it. Each step the agent picks one flat index over (primitive, rotation, row, col)
    of the heightmap, primitives ``grasp``, ``left_slide``, ``right_slide``. A grasp is ClutterGrasp-v1's
    (top-down at the pixel's 3-D point, the rotation's yaw, then into the bin); a slide pushes the closed
    fingertips 8 cm from the pixel's 3-D point to the left or right of the rotation's jaw direction, to pull
    apart objects that no grasp fits. Observations as ClutterGrasp-v1's.
    Reward (``reward_scheme="default"``): 1 placed in the bin, 0.8 grasped but not placed, 0.5 a slide that
    changed the heightmap without knocking an object out of the workspace, 0 otherwise; ``"no_slide_reward"`` gives
    slides 0, ``"unlock"`` 0.5 only to a slide that made a locked object graspable, ``"unlock_each"`` 0.5 per
    object so freed (at most 1), ``"fit_gain"`` 0.5 only to a slide that added a graspable region to the heightmap; with ``loss_cost=c``, c less per object the action lost off the workspace (a
    slide's or a grasp's).

    **Randomizations:**
    - random clutters as ClutterGrasp-v1's: ``num_objects`` (10 by default; presets ``"min"`` 6–10,
      ``"medium"`` 15–20, ``"max"`` 25–30), dropped at random orientations that may pile up
      (``loosely_packed=False`` by default); ``packed_fraction`` packs that share of them into tight clusters
    - or ``layout="complicated"`` (or ``num_objects="complicated"``): one of the hand-designed locking layouts
      of :mod:`~maniskill_pnp.scenes.complicated_layouts` per episode, a seeded draw unless
      ``complicated_index`` (or ``reset(options={"layout_index": k})``) fixes it
    - or ClutterGrasp-v1's explicit ``layout=`` list, or ``layout_file=`` scene files

    **Success Conditions:**
    - the workspace is clear (episode terminates); it is truncated after ``max_consecutive_failures`` failures
      in a row (a grasp that held nothing or a slide that changed nothing) or ``max_actions`` actions.
      ``info`` is ClutterGrasp-v1's plus ``primitive`` (name), ``primitive_index``, ``slide_changed``,
      ``changed_pixels``, ``knocked_out`` (objects the slide pushed out of the workspace) and ``slide_unlocked``
      (objects the slide made graspable; counted by the ``"unlock"`` and ``"unlock_each"`` reward schemes only, 0
      otherwise) and ``slide_fit_gain`` (graspable regions of the heightmap the slide added; counted by the
      ``"fit_gain"`` scheme only, 0 otherwise).
    """

    PRIMITIVES = ("grasp", "left_slide", "right_slide")

    def __init__(
        self,
        *args,
        num_objects: int | tuple[int, int] | str = 10,
        loosely_packed: bool = False,
        layout=None,
        layout_file=None,
        complicated_index: int | None = None,
        reward_scheme: str = "default",
        **kwargs,
    ):
        """Args beyond ClutterGrasp-v1's: ``layout`` also takes ``"complicated"`` (the hand-designed layouts;
        ``num_objects="complicated"`` says the same), ``complicated_index`` (always that one of them; implies
        ``layout="complicated"``), and ``reward_scheme`` (a key of :data:`REWARD_SCHEMES`)."""
        if reward_scheme not in REWARD_SCHEMES:
            raise ValueError(f"unknown reward scheme {reward_scheme!r}; valid schemes: {list(REWARD_SCHEMES)}")
        if num_objects == "complicated" or complicated_index is not None:
            if layout_file is not None or (layout is not None and not (isinstance(layout, str) and layout == "complicated")):
                raise ValueError("num_objects='complicated' and complicated_index select the hand-designed layouts: pass no other layout")
            layout = "complicated"
        n = len(COMPLICATED_LAYOUT_NAMES)
        if complicated_index is not None and (
            isinstance(complicated_index, bool) or not isinstance(complicated_index, (int, np.integer)) or not 0 <= complicated_index < n
        ):
            raise ValueError(f"complicated_index must be an int in 0..{n - 1} ({list(COMPLICATED_LAYOUT_NAMES)}), got {complicated_index!r}")
        self.reward_scheme = reward_scheme
        self.complicated_index = None if complicated_index is None else int(complicated_index)
        super().__init__(*args, num_objects=num_objects, loosely_packed=loosely_packed, layout=layout,
                         layout_file=layout_file, **kwargs)

    @property
    def rewards(self) -> dict[str, float]:
        """Reward per outcome of the reward scheme: ``place``, ``grasp`` and ``slide`` (a slide that changed the scene),
        and ``freed_paid`` (see :data:`REWARD_SCHEMES`)."""
        return REWARD_SCHEMES[self.reward_scheme]

    # ------------------------------------------------------------------ layouts
    def _resolve_layouts(self, layout):
        if isinstance(layout, str):
            if layout != "complicated":
                raise ValueError(f"unknown layout {layout!r}; valid: 'complicated' or a list of (ObjectSpec, pose)")
            return [validate_layout(entries, self.workspace) for entries in complicated_layouts(self.workspace)]
        return super()._resolve_layouts(layout)

    def _choose_layout(self, rng, options):
        if options.get("layout_index") is None and self.complicated_index is not None:
            return self.complicated_index
        return super()._choose_layout(rng, options)

    # ------------------------------------------------------------------ primitives and judgement
    @property
    def primitive_programs(self):
        return {"grasp": self._grasp_program, "left_slide": self._slide_program("left"),
                "right_slide": self._slide_program("right")}

    def _slide_program(self, side: str):
        """The program of a slide to ``side``: ``program(env, rot, row, col)``."""

        def program(env: int, rot: int, row: int, col: int):
            """Push env ``env``'s closed fingertips ``slide_length`` from pixel ``(row, col)`` to ``side`` of
            rotation ``rot``."""
            ws = self.workspace
            start = ws.pixel_to_world(row, col, 0.0)
            start[2] = ws.slide_tip_height(self._height[env], row, col)
            direction = ws.slide_direction(rot, side)
            res = yield from self.prims[env].program("slide", start, direction, ws.slide_length)
            return dict(
                grasp_success=False, place_success=False, stage=res.stage, reason=res.reason, place_stage="",
                place_reason="", slide_start=[float(v) for v in start], slide_direction=[float(v) for v in direction],
                planning_time=res.planning_time,
            )

        return program

    def _initial_last(self):
        return dict(super()._initial_last(), changed_pixels=0, slide_unlocked=0, slide_fit_gain=0)

    def _snapshot(self, env):
        snap = super()._snapshot(env)
        if self.rewards["freed_paid"]:
            snap["objects"] = self.clutter.workspace_objects(env)
        if self.rewards["fit_paid"]:
            snap["fit"] = self._fit_of(env)
        return snap

    @cached_property
    def _fit_test(self) -> HeightmapGraspFit:
        return HeightmapGraspFit.for_workspace(self.workspace)

    def _fit_of(self, env: int) -> torch.Tensor | None:
        """Env ``env``'s current fit heightmap, where the task makes one."""
        return None if self._fit_height is None else self._fit_height[env]

    def _graspable_regions(self, height: np.ndarray, fit: torch.Tensor | None) -> int:
        """Graspable regions of one heightmap (read on its fit heightmap, where there is one)."""
        h = torch.as_tensor(height, dtype=torch.float32)[None]
        f = None if fit is None else fit[None].to(device=h.device, dtype=torch.float32)
        occupied = h > MATERIAL_HEIGHT
        return graspable_regions(self._fit_test(h, occupied, f)[0].any(dim=0), occupied[0])

    def _unlocked(self, env, before) -> int:
        """Objects near those the slide moved that were locked before it and are graspable after it."""
        after = self.clutter.workspace_objects(env)
        moved = [i for i, (_, pose) in before.items()
                 if i not in after or np.linalg.norm(after[i][1].p - pose.p) > MOVED]
        if not moved:
            return 0
        centres = np.array([before[i][1].p[:2] for i in moved])

        def near(objects):
            return [i for i, (_, pose) in objects.items() if np.min(np.linalg.norm(centres - pose.p[:2], axis=1)) <= UNLOCK_REACH]

        def locked(objects, indices):
            keys = near(objects)
            checked = [keys.index(i) for i in indices if i in keys]
            if not checked:
                return {}
            grasps = grasp_feasibility([objects[i] for i in keys], self.workspace, objects=checked, **UNLOCK_CHECK)
            return {keys[g.index]: g.locked for g in grasps}

        candidates = [i for i in near(before) if i in after]
        was = locked(before, candidates)
        now = locked(after, [i for i in candidates if was.get(i)])
        return sum(1 for i, is_locked in now.items() if not is_locked)

    def _judge_action(self, env, decision, result, before):
        if decision.primitive == "grasp":
            return super()._judge_action(env, decision, result, before)
        n = changed_pixels(before["height"], self._height[env])
        changed = n > change_threshold(*before["height"].shape)
        moves = self._object_moves(env, before, decision.primitive, result)
        knocked_out = moves["knocked_out"]
        outcome = dict(result, slide_changed=changed, changed_pixels=n, **moves)
        if knocked_out > 0:  # pushing objects off the workspace is no progress: no reward, and it counts as a failure
            outcome["reason"] = f"the slide knocked {knocked_out} object(s) out of the workspace"
            return Judgement(0.0, False, outcome)
        pays = int(changed)  # the number of slide rewards this slide earns
        if self.rewards["freed_paid"] and changed:
            outcome["slide_unlocked"] = self._unlocked(env, before["objects"])
            pays = min(outcome["slide_unlocked"], self.rewards["freed_paid"])
        if self.rewards["fit_paid"] and changed:
            gain = (self._graspable_regions(self._height[env], self._fit_of(env))
                    - self._graspable_regions(before["height"], before["fit"]))
            outcome["slide_fit_gain"] = gain
            pays = min(max(gain, 0), self.rewards["fit_paid"])
        return Judgement(self.rewards["slide"] * pays, changed, outcome)
