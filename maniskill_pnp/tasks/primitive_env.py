"""What every task whose one step is a whole motion primitive shares: a Discrete action space, action parsing, the
one step pipeline, and outcomes in ``info``.

ManiSkill tasks take one low-level control action per step; the tasks of this package take one decision (a
coordinate, a pixel) and execute a planned primitive inside ``step``. They subclass :class:`PrimitiveStepEnv`.

The action contract (gymnasium's): every element of ``action_space`` is a legal action. One that is impossible in
the current state (a conveyor coordinate index beyond the current phase's set) is executed as a failed attempt:
the failure reward, ``info["invalid_action"]`` True, and the episode goes on or ends as that failure would. A task
whose legal actions depend on the state offers them as ``info["action_mask"]`` (bool, ``(num_envs, n)``), which
``env.action_space.sample(mask=...)`` takes. Actions outside the space (negative, ``>= n``, NaN, floats, a wrong
shape or dtype) raise a ValueError that names the valid range, before anything moves.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import torch
from gymnasium import spaces

from mani_skill.envs.sapien_env import BaseEnv

from maniskill_pnp.planning.lockstep import LockstepExecutor, Program, drive
from maniskill_pnp.tasks.registration import SeededNpRandom

#: The outcome of each env's last action, in ``info`` after every reset and step as tensors of shape
#: ``(num_envs,)`` (also for one env): what the gripper sensed, whether the held object landed in the bin, how many
#: objects came to rest in the bin (a grasp that carries two places two), whether a slide changed the scene, how
#: many objects the action pushed or dropped out of the workspace, whether the action was impossible in that state
#: (executed as a failed attempt), whether the episode cannot go on (``info["fault_reason"]`` says why), and which
#: primitive ran (-1 after a reset or an invalid action).
OUTCOME_KEYS = ("grasp_success", "place_success", "placed_objects", "slide_changed", "knocked_out", "invalid_action",
                "fault", "primitive_index")


def no_outcome() -> dict:
    """The outcome entries of an env that has not acted yet (after a reset)."""
    return dict(grasp_success=False, place_success=False, placed_objects=0, slide_changed=False, knocked_out=0,
                invalid_action=False, fault=False, fault_reason="", primitive_index=-1, primitive="")


def batch_infos(infos: list[dict], device) -> dict:
    """One ``info`` from the per-env ones. For any number of envs (one included) numbers and bools become tensors of
    shape ``(num_envs,)``, arrays and tensors are stacked to ``(num_envs, ...)``; other values (text, lists, dicts)
    are kept as they are for one env and listed per env for several."""
    out = {}
    for key in infos[0]:
        values = [info.get(key) for info in infos]
        if all(isinstance(v, (bool, int, float, np.bool_, np.integer, np.floating)) for v in values):
            out[key] = torch.tensor(values, device=device)
        elif all(isinstance(v, (np.ndarray, torch.Tensor)) for v in values):
            out[key] = torch.stack([torch.as_tensor(v, device=device) for v in values])
        else:
            out[key] = values[0] if len(values) == 1 else values
    return out


def _as_numpy(x) -> np.ndarray:
    """A numpy view of an action or mask given as a torch tensor (any device), numpy array, list or scalar."""
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def parse_discrete_action(action, n: int, valid: str) -> int:
    """One integer index in ``0..n-1`` from an int, numpy or torch scalar (or shape-(1,) array).

    Raises:
        ValueError: naming ``valid`` (what a valid action is) for a wrong shape, a non-integer dtype (float, NaN,
            bool) or an index out of range; raised before anything moves.
    """
    a = _as_numpy(action)
    if a.size != 1 or a.ndim > 1:
        raise ValueError(f"action must be {valid} (shape () or (1,)), got shape {a.shape}")
    a = a.reshape(())
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"action must be {valid}, got {a.item()!r} of dtype {a.dtype}")
    index = int(a)
    if not 0 <= index < n:
        raise ValueError(f"action {index} out of range: must be {valid}")
    return index


def parse_discrete_actions(action, num_envs: int, n: int, valid: str) -> list[int]:
    """One integer index in ``0..n-1`` per env: as :func:`parse_discrete_action` for one env, else an array or
    tensor of shape ``(num_envs,)`` (or ``(num_envs, 1)``).

    Raises:
        ValueError: naming the env whose action is invalid, or the expected shape; raised before anything moves.
    """
    if num_envs == 1:
        return [parse_discrete_action(action, n, valid)]
    a = _as_numpy(action)
    if a.shape not in ((num_envs,), (num_envs, 1)):
        raise ValueError(f"action must be one index per env, shape ({num_envs},), each {valid}; got shape {a.shape}")
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"action must be integer indices, each {valid}; got dtype {a.dtype}")
    out = []
    for i, x in enumerate(a.reshape(num_envs)):
        try:
            out.append(parse_discrete_action(x, n, valid))
        except ValueError as e:
            raise ValueError(f"env {i}: {e}") from None
    return out


class MaskableDiscrete(spaces.Discrete):
    """``Discrete(n)`` whose ``sample(mask=...)`` also takes the tasks' ``info["action_mask"]`` as it is: a bool (or
    0/1) numpy array or torch tensor of shape ``(n,)`` or ``(1, n)`` (gymnasium's own ``Discrete`` wants int8
    numpy of shape ``(n,)``)."""

    def sample(self, mask=None, probability=None):
        if mask is not None:
            m = _as_numpy(mask)
            if m.ndim == 2 and m.shape[0] == 1:
                m = m[0]
            mask = m.astype(np.int8)
        return super().sample(mask=mask, probability=probability)


@dataclass(frozen=True)
class Decision:
    """One env's decoded action.

    Attributes:
        index: The flat action index.
        primitive: Name of the primitive it runs (a key of the task's ``primitive_programs``).
        args: The primitive program's arguments after the env index.
        valid: False when the action is impossible in the current state: it runs nothing and fails.
    """

    index: int
    primitive: str
    args: tuple = ()
    valid: bool = True


@dataclass(frozen=True)
class Judgement:
    """What one env's action earned: its ``reward``, whether it counts as a ``success`` (a failure extends a run of
    failures) and its ``outcome`` (``info`` fields: at least those of :data:`OUTCOME_KEYS` it sets)."""

    reward: float
    success: bool
    outcome: dict


class PrimitiveStepEnv(SeededNpRandom, BaseEnv):
    """A ManiSkill task whose step executes a whole primitive chosen by one Discrete action per env.

    :meth:`step` is one pipeline for every task: parse the actions (out-of-space input raises) → decode each into a
    :class:`Decision` (:meth:`_decode`) → run each env's program (:meth:`_step_program`, by default the task's
    declared primitive program) in lockstep → observe → judge each env's result (:meth:`_judge`) → episode ends
    (:meth:`_episode_end`) → ``info`` (:meth:`_env_info` per env, batched by :func:`batch_infos`, with the outcome
    of :data:`OUTCOME_KEYS`). Tasks declare :attr:`PRIMITIVES` (names in primitive-index order) and
    :attr:`primitive_programs` (name → program), and implement the hooks above.

    It runs in the ``pd_joint_pos`` control mode the primitives drive; other values raise a ValueError before the
    scene is built. A task whose step runs the primitives of all envs in lockstep sets :attr:`BATCHED`; the others
    run one env.
    """

    #: Whether the task runs ``num_envs > 1`` (ManiSkill's GPU simulation; its CPU simulation has one env).
    BATCHED = False
    #: Primitive names, in the order of ``info["primitive_index"]`` (and of the action's primitive index where the
    #: action chooses the primitive).
    PRIMITIVES: tuple[str, ...] = ()

    def __init__(self, *args, **kwargs):
        name = type(self).__name__
        num_envs = kwargs.get("num_envs", 1)
        if num_envs != 1 and not self.BATCHED:
            raise ValueError(f"{name} runs one env (one whole primitive per step); got num_envs={num_envs}")
        if num_envs != 1:
            backend = kwargs.get("sim_backend", "auto")
            if backend in ("cpu", "physx_cpu") or (backend == "auto" and not torch.cuda.is_available()):
                raise ValueError(
                    f"{name} with num_envs={num_envs} needs ManiSkill's GPU simulation (sim_backend='physx_cuda' on a "
                    f"CUDA GPU; its CPU simulation runs one env); got sim_backend={backend!r}"
                    + ("" if torch.cuda.is_available() else " and no CUDA GPU")
                )
        kwargs.setdefault("control_mode", "pd_joint_pos")
        if kwargs["control_mode"] != "pd_joint_pos":
            raise ValueError(f"{name} needs control_mode='pd_joint_pos', got {kwargs['control_mode']!r}")
        n = int(num_envs)  # ManiSkill's __init__ resets the envs, so the per-env state comes first
        #: Per env: what its last action did (the outcome and the other per-action ``info`` fields).
        self.last: list[dict] = [self._initial_last() for _ in range(n)]
        self._episode_ready = False
        # ManiSkill defines this after the first reset of its __init__, but a control step (BaseEnv._step_action,
        # which the primitives' executor takes) reads it, and a task may step inside that reset (a settling
        # clutter). The executor's actions are always batched, so a shape-() space is right until then; after it,
        # _use_discrete_actions sets the same.
        self._orig_single_action_space = spaces.Discrete(1)
        super().__init__(*args, **kwargs)
        if set(self.primitive_programs) != set(self.PRIMITIVES):
            raise TypeError(f"{name}: primitive_programs {sorted(self.primitive_programs)} must match PRIMITIVES {self.PRIMITIVES}")

    @property
    def primitive_names(self) -> tuple[str, ...]:
        """The task's primitive names, in primitive-index order."""
        return tuple(self.PRIMITIVES)

    @property
    def primitive_programs(self) -> dict[str, Callable[..., Program]]:
        """Primitive name → its program, called as ``program(env_idx, *decision.args)``."""
        raise NotImplementedError

    _control_step_callback = None

    def set_control_step_callback(self, callback) -> None:
        """Call ``callback()`` after every control step the primitives execute (e.g. to film the arm's motion);
        ``None`` removes it. Takes effect at once, also in the middle of an episode."""
        if callback is not None and not callable(callback):
            raise ValueError(f"callback must be callable or None, got {type(callback).__name__}")
        self._control_step_callback = callback

    def _on_control_step(self) -> None:
        """The hook the task's :class:`~maniskill_pnp.planning.MotionPrimitives` call after every control step."""
        if self._control_step_callback is not None:
            self._control_step_callback()

    def _use_discrete_actions(self, n: int) -> None:
        """Replace the agent's low-level action space by ``Discrete(n)``; call after ``super().__init__``."""
        self.single_action_space = MaskableDiscrete(n)
        self.action_space = MaskableDiscrete(n)
        self._orig_single_action_space = self.single_action_space

    # ------------------------------------------------------------------ the step pipeline
    def step(self, action):
        if not self._episode_ready:
            raise RuntimeError("call reset() before step()")
        self._check_can_step()
        n = self.single_action_space.n
        indices = parse_discrete_actions(action, self.num_envs, n, self._action_description())
        decisions = [self._decode(e, index) for e, index in enumerate(indices)]
        before = [self._snapshot(e) for e in range(self.num_envs)]
        lockstep = self._lockstep
        t0, sim0 = time.perf_counter(), lockstep.sim_steps
        results = drive(lockstep, [self._step_program(e, d) if d.valid else None for e, d in enumerate(decisions)])
        motion_time, sim_steps = time.perf_counter() - t0, lockstep.sim_steps - sim0
        for e, decision in enumerate(decisions):
            if not decision.valid:
                self._on_invalid(e, decision)
        self._after_programs()
        obs = self.get_obs()
        planning_time = 0.0
        faults = self.detect_faults()
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        for e, (decision, result) in enumerate(zip(decisions, results)):
            if decision.valid:
                judged = self._judge(e, decision, result, before[e])
            else:
                judged = Judgement(self._failure_reward(e), False, dict(
                    invalid_action=True, reason=f"action {decision.index} is not possible now ({self._why_invalid(e)})"))
            rewards[e] = judged.reward
            last = self._initial_last()
            if decision.valid:
                last.update(primitive=decision.primitive, primitive_index=self.PRIMITIVES.index(decision.primitive))
            last.update(judged.outcome)
            planning_time += float(last.pop("planning_time", 0.0))
            last.update(action=decision.index, fault=bool(faults[e]), fault_reason=faults[e], sim_steps=sim_steps)
            self.last[e] = last
            self._record(e, decision, judged)
        self._step_timings = dict(self._observation_timing(), planning=planning_time, motion=motion_time, sim_steps=sim_steps)
        terminated, truncated = self._episode_end(np.array([bool(f) for f in faults]))
        info = self.get_info()
        self._commit_step(obs)
        return (obs, torch.as_tensor(rewards, device=self.device), torch.as_tensor(terminated, device=self.device),
                torch.as_tensor(truncated, device=self.device), info)

    def _initial_last(self) -> dict:
        """The ``last`` entry of an env before its first action: every per-action ``info`` field at its default."""
        return dict(no_outcome(), action=-1, sim_steps=0)

    def _observation_timing(self) -> dict:
        """Seconds the observation just taken cost, by part (e.g. ``render``, ``heightmap``); none by default."""
        return {}

    _step_timings: dict = {}

    @property
    def step_timings(self) -> dict:
        """Where the last step's wall-clock time went, in seconds (kept out of ``info``, which is deterministic):
        ``planning`` (IK, RRT-Connect, time parameterization, summed over the envs, which plan one after another),
        ``motion`` (every env's program, planning included), the parts of the closing observation
        (:meth:`_observation_timing`), and the step's ``sim_steps`` (physics steps, shared by the envs)."""
        return dict(self._step_timings)

    def _action_description(self) -> str:
        """What a valid action is, for the error of an out-of-space action."""
        n = self.single_action_space.n
        return f"one integer index in 0..{n - 1}"

    def _check_can_step(self) -> None:
        """Raise when the task cannot take a step now (e.g. its episode is over); nothing by default."""

    def _decode(self, env: int, index: int) -> Decision:
        """Env ``env``'s action ``index`` as a :class:`Decision`."""
        raise NotImplementedError

    def _snapshot(self, env: int):
        """What :meth:`_judge` compares against, taken before env ``env`` acts (None by default)."""
        return None

    def _step_program(self, env: int, decision: Decision) -> Program:
        """Env ``env``'s whole step as one program: the declared primitive program by default."""
        return self.primitive_programs[decision.primitive](env, *decision.args)

    def _judge(self, env: int, decision: Decision, result, before) -> Judgement:
        """Reward, success and outcome of env ``env``'s valid action from its program's ``result`` and the state
        ``before`` it (:meth:`_snapshot`); called after the observation of the new state."""
        raise NotImplementedError

    def _after_programs(self) -> None:
        """What the task does once every env's program is done, before the observation; nothing by default."""

    def _on_invalid(self, env: int, decision: Decision) -> None:
        """What an impossible action of env ``env`` does to the task's state, before the observation (a failed
        attempt: e.g. the conveyor's episode ends); nothing by default."""

    def _failure_reward(self, env: int) -> float:
        """The reward of a failed attempt (what an impossible action earns)."""
        return 0.0

    def _why_invalid(self, env: int) -> str:
        """Why an action of env ``env`` is impossible now, for ``info["reason"]``."""
        return "outside the current action mask"

    def _record(self, env: int, decision: Decision, judged: Judgement) -> None:
        """Update the task's episode state after env ``env``'s action was judged (counters, phases); nothing by
        default."""

    def _episode_end(self, faults: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per env ``(terminated, truncated)`` after the step; ``faults`` is True where :meth:`detect_faults` found one."""
        raise NotImplementedError

    def detect_faults(self) -> list[str]:
        """Per env, why its episode cannot go on ("" when it can), checked after every action; none by default."""
        return [""] * self.num_envs

    @property
    def _lockstep(self) -> LockstepExecutor:
        """The executor that drives every env's programs."""
        raise NotImplementedError

    # ------------------------------------------------------------------ info
    def evaluate(self):
        if not self._episode_ready:
            return {}
        return batch_infos([dict(self._env_info(e), **self.last[e]) for e in range(self.num_envs)], self.device)

    def _env_info(self, env: int) -> dict:
        """Env ``env``'s ``info`` fields about its episode (``success`` among them); the outcome of its last action
        is added to them."""
        raise NotImplementedError

    def compute_dense_reward(self, obs, action, info):
        return info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info)

    # ------------------------------------------------------------------ ManiSkill's private state
    # ``step`` replaces ManiSkill's ``BaseEnv.step`` (one decision is many control steps) and a settling reset steps
    # the scene; ManiSkill keeps what those must update in private fields. These two methods are the one place in
    # the package that writes them.
    def _commit_step(self, obs) -> None:
        """What ManiSkill's own ``step`` records: one more elapsed step, and the observation it returns."""
        self._elapsed_steps += 1
        self._last_obs = obs

    @contextmanager
    def _all_envs_live(self):
        """Step the whole scene, or set every env's rows of an actor, inside ``_initialize_episode`` or between a
        step's programs and its observation: the poses set so far are applied (GPU simulation) and ManiSkill's reset
        mask, which limits setters to the envs of the last reset, is lifted meanwhile."""
        mask = self.scene._reset_mask
        self.scene._reset_mask = torch.ones(self.num_envs, dtype=torch.bool, device=self.device)
        if self.gpu_sim_enabled:
            self.scene._gpu_apply_all()
            self.scene.px.gpu_update_articulation_kinematics()
            self.scene._gpu_fetch_all()
        try:
            yield
        finally:
            self.scene._reset_mask = mask
