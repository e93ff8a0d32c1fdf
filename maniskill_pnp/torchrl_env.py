"""TorchRL environment wrapper for ManiSkill 3.

TorchRL ships no ManiSkill integration, and its generic ``GymWrapper`` does
not fit ManiSkill 3: ManiSkill envs are *always* batched (every tensor has a
leading ``num_envs`` dimension, even for ``num_envs=1``) and return torch
tensors that already live on the simulation device, while ``GymWrapper``
builds unbatched specs from ``env.observation_space`` and round-trips data
through numpy. This module provides :class:`ManiSkillTorchRLEnv`, a thin
:class:`torchrl.envs.EnvBase` that keeps ManiSkill's batched tensors as they
are, derives its specs from ManiSkill's *single* (per-env) gymnasium spaces,
and supports TorchRL's partial resets through ManiSkill's ``env_idx`` option.

Spec layout (``B = num_envs``; the env's ``batch_size`` is ``[B]``):

* A non-dict observation is stored under ``"observation"``; a dict
  observation keeps its (nested) keys, e.g.
  ``("sensor_data", "base_camera", "rgb")``.
* ``"reward"``: float32, shape ``[B, 1]``.
* ``"done"``, ``"terminated"``, ``"truncated"``: bool, shape ``[B, 1]``.
* A non-dict action is read from ``"action"``.
* Selected ManiSkill ``info`` entries (by default ``"success"``, when the task
  reports it) are exposed as extra observation entries, shape ``[B, 1]`` for
  per-env scalars.

Example:
    >>> from torchrl.envs.utils import check_env_specs
    >>> from maniskill_pnp.torchrl_env import make_torchrl_env
    >>> env = make_torchrl_env("PickCube-v1", obs_mode="state")
    >>> check_env_specs(env)
    >>> env.set_seed(0)
    >>> rollout = env.rollout(10)  # random actions drawn from env.action_spec
    >>> rollout["next", "reward"].shape
    torch.Size([1, 10, 1])
    >>> env.close()
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict, TensorDictBase
from torchrl.data import (
    Binary,
    Bounded,
    Categorical,
    Composite,
    MultiCategorical,
    TensorSpec,
    Unbounded,
)
from torchrl.envs import EnvBase

from maniskill_pnp.runtime import with_default_backends
from maniskill_pnp.tasks.primitive_env import OUTCOME_KEYS

__all__ = [
    "ManiSkillTorchRLEnv",
    "make_torchrl_env",
    "space_to_spec",
]

_DONE_KEYS = ("done", "terminated", "truncated")
#: The ``info`` entries exposed by default (those the task reports): success, the outcome of each env's last
#: action, and the action mask of a task whose legal actions depend on the state.
DEFAULT_INFO_KEYS = ("success", *OUTCOME_KEYS, "action_mask")


def _torch_dtype(np_dtype: Any) -> torch.dtype:
    """Maps a numpy dtype to the torch dtype torch itself would use for it."""
    return torch.from_numpy(np.empty(0, dtype=np_dtype)).dtype


def space_to_spec(
    space: gym.Space, device: torch.device | str | None = None
) -> TensorSpec:
    """Converts an *unbatched* gymnasium space into a TorchRL spec.

    The mapping is:

    * ``Box`` with a bool dtype -> ``Categorical(2, dtype=torch.bool)`` (that is
      how ManiSkill describes boolean flags such as ``extra/is_grasped``).
    * ``Box`` with finite bounds everywhere -> ``Bounded``; otherwise
      ``Unbounded``. The dtype is the box's dtype.
    * ``Discrete`` -> ``Categorical(n)``.
    * ``MultiDiscrete`` -> ``MultiCategorical(nvec)``.
    * ``MultiBinary`` -> ``Binary``.
    * ``Dict`` (arbitrarily nested) -> ``Composite`` with the same keys.

    Args:
        space: The gymnasium space describing a single (unbatched) sample.
        device: Device of the resulting spec.

    Returns:
        A spec whose shape is the space's shape (no batch dimension). Use
        ``spec.expand(batch_size + spec.shape)`` to batch it.

    Raises:
        TypeError: If ``space`` is not a gymnasium space, or is a space type
            that has no TorchRL counterpart here (e.g. ``Tuple``, ``Text``).
        ValueError: If the space is of a supported type but uses a feature
            that cannot be represented, e.g. ``Discrete`` with ``start != 0``.
    """
    if isinstance(space, spaces.Dict):
        return Composite(
            {key: space_to_spec(sub, device) for key, sub in space.spaces.items()},
            shape=(),
            device=device,
        )
    if isinstance(space, spaces.Box):
        shape = torch.Size(space.shape)
        dtype = _torch_dtype(space.dtype)
        if dtype == torch.bool:
            return Categorical(2, shape=shape, device=device, dtype=torch.bool)
        if np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high)):
            return Bounded(
                low=torch.as_tensor(space.low),
                high=torch.as_tensor(space.high),
                shape=shape,
                device=device,
                dtype=dtype,
            )
        return Unbounded(shape=shape, device=device, dtype=dtype)
    if isinstance(space, spaces.Discrete):
        if int(space.start) != 0:
            raise ValueError(
                f"Cannot convert {space!r}: Discrete spaces with start != 0 "
                "have no TorchRL Categorical equivalent (Categorical values "
                "always start at 0)."
            )
        return Categorical(
            int(space.n), shape=(), device=device, dtype=_torch_dtype(space.dtype)
        )
    if isinstance(space, spaces.MultiDiscrete):
        if np.any(space.start != 0):
            raise ValueError(
                f"Cannot convert {space!r}: MultiDiscrete spaces with a non-zero "
                "start have no TorchRL MultiCategorical equivalent."
            )
        return MultiCategorical(
            torch.as_tensor(space.nvec, dtype=torch.long),
            shape=torch.Size(space.shape),
            device=device,
            dtype=_torch_dtype(space.dtype),
        )
    if isinstance(space, spaces.MultiBinary):
        return Binary(
            shape=torch.Size(space.shape),
            device=device,
            dtype=_torch_dtype(space.dtype),
        )
    if isinstance(space, gym.Space):
        raise TypeError(
            f"Unsupported gymnasium space {space!r} (type {type(space).__name__}); "
            "supported: Box, Discrete, MultiDiscrete, MultiBinary and Dict."
        )
    raise TypeError(
        f"Expected a gymnasium.Space, got {space!r} (type {type(space).__name__})."
    )


def _batched(spec: TensorSpec, batch_size: torch.Size) -> TensorSpec:
    """Prepends ``batch_size`` to a spec's shape (recursively for composites)."""
    return spec.expand(batch_size + spec.shape)


class ManiSkillTorchRLEnv(EnvBase):
    """TorchRL view of an already-made ManiSkill 3 environment.

    The wrapper is deliberately thin: ManiSkill already batches everything
    over ``num_envs`` and returns torch tensors on its simulation device, so
    the wrapper's ``batch_size`` is ``[num_envs]``, its ``device`` is
    ManiSkill's ``env.unwrapped.device``, and data is never copied to numpy.

    Specs are built from ``env.unwrapped.single_observation_space`` and
    ``env.unwrapped.single_action_space`` (see :func:`space_to_spec`) and then
    expanded to ``[num_envs]``. ManiSkill generates the observation space from
    the observation of a real reset performed while the env is made
    (``BaseEnv._init_raw_obs``); the wrapper cross-checks every observation
    leaf against that sample and, if dtype or shape disagree, trusts the
    sampled tensor (the space is only a description; the tensor is what
    :meth:`step` will actually return).

    Partial resets: when :meth:`reset` receives a tensordict with a
    ``"_reset"`` mask of shape ``[num_envs, 1]``, only the selected envs are
    reset, via ``env.reset(options={"env_idx": idx})``. The wrapper returns
    full-batch outputs and lets :meth:`EnvBase.reset` merge them, keeping the
    input tensordict's values for the envs that were not reset. If no env is
    selected, ManiSkill is not called at all. ManiSkill forbids combining a
    partial reset with a reconfiguration, so tasks that reconfigure on reset
    (``reconfiguration_freq`` > 0) only support full resets.

    Seeding: :meth:`set_seed` stores the seed and the next :meth:`reset`
    passes it to ManiSkill as ``seed=``. ManiSkill then re-seeds its main RNG,
    so the subsequent unseeded resets are reproducible too.

    Args:
        env: The object returned by ``gymnasium.make`` for a ManiSkill task
            (possibly wrapped); ``env.unwrapped`` must be a
            ``mani_skill.envs.sapien_env.BaseEnv``. It must not auto-reset
            (e.g. do not pass a ``ManiSkillVectorEnv``): TorchRL drives resets.
        info_keys: Names of ManiSkill ``info`` entries to expose as extra
            observation entries. An entry is only exposed if the task reports
            it as a tensor with a leading ``num_envs`` dimension; per-env
            scalars get shape ``[num_envs, 1]``. Defaults to
            :data:`DEFAULT_INFO_KEYS`: ``success``, the outcome keys of this
            package's tasks (``grasp_success``, ``place_success``...), and
            ``action_mask`` (``[num_envs, n]``, a ``Binary`` spec that TorchRL's
            ``ActionMask`` transform reads) where the task offers one.
        **kwargs: Forwarded to :class:`torchrl.envs.EnvBase` (e.g.
            ``allow_done_after_reset``).

    Raises:
        TypeError: If ``env`` is not a ManiSkill environment, or a space
            cannot be converted.
        ValueError: If an info key collides with an observation key.
    """

    def __init__(
        self,
        env: gym.Env,
        *,
        info_keys: Sequence[str] | None = None,
        **kwargs: Any,
    ) -> None:
        from mani_skill.envs.sapien_env import BaseEnv

        base = getattr(env, "unwrapped", None)
        if not isinstance(base, BaseEnv):
            raise TypeError(
                "ManiSkillTorchRLEnv expects a gymnasium env whose `.unwrapped` is "
                f"a mani_skill BaseEnv, got {type(env).__name__} "
                f"(unwrapped: {type(base).__name__})."
            )
        self._env = env
        self._pending_seed: int | None = None
        self._last_obs_td: TensorDictBase | None = None
        num_envs = int(base.num_envs)
        super().__init__(
            device=base.device, batch_size=torch.Size([num_envs]), **kwargs
        )
        self._make_specs(base, DEFAULT_INFO_KEYS if info_keys is None else tuple(info_keys))
        self.is_closed = False

    # ------------------------------------------------------------------ #
    # Properties
    # ------------------------------------------------------------------ #
    @property
    def maniskill_env(self) -> gym.Env:
        """The wrapped gymnasium env (with its wrappers, e.g. the time limit)."""
        return self._env

    @property
    def base_env(self):
        """The underlying ``mani_skill`` ``BaseEnv`` (``env.unwrapped``)."""
        return self._env.unwrapped

    @property
    def num_envs(self) -> int:
        """Number of parallel ManiSkill sub-environments (the batch size)."""
        return int(self.batch_size[0])

    # ------------------------------------------------------------------ #
    # Specs
    # ------------------------------------------------------------------ #
    def _make_specs(self, base: Any, info_keys: tuple[str, ...]) -> None:
        """Builds all specs from ManiSkill's single-env spaces."""
        batch = self.batch_size
        device = self.device

        obs_space = base.single_observation_space
        self._dict_obs = isinstance(obs_space, spaces.Dict)
        obs_spec = space_to_spec(obs_space, device)
        if self._dict_obs:
            obs_spec = _batched(obs_spec, batch)
        else:
            obs_spec = Composite(
                observation=_batched(obs_spec, batch), shape=batch, device=device
            )
        sample = getattr(base, "_init_raw_obs", None)
        if sample is not None:
            if not self._dict_obs:
                sample = {"observation": sample}
            self._align_with_sample(obs_spec, sample)

        # Info entries (e.g. "success"), probed with a side-effect-free evaluate.
        self._info_keys: tuple[str, ...] = ()
        if info_keys:
            info = base.get_info()
            exposed = []
            for key in info_keys:
                value = info.get(key)
                if not (
                    isinstance(value, torch.Tensor)
                    and value.ndim >= 1
                    and value.shape[0] == batch[0]
                ):
                    continue
                if key in obs_spec.keys():
                    raise ValueError(
                        f"info key {key!r} collides with an observation key; "
                        "pass a different `info_keys`."
                    )
                shape = batch + (value.shape[1:] if value.ndim > 1 else (1,))
                if key == "action_mask":
                    spec = Binary(n=shape[-1], shape=shape, device=device, dtype=torch.bool)
                elif value.dtype == torch.bool:
                    spec = Categorical(2, shape=shape, device=device, dtype=torch.bool)
                else:
                    spec = Unbounded(shape=shape, device=device, dtype=value.dtype)
                obs_spec[key] = spec
                exposed.append(key)
            self._info_keys = tuple(exposed)
        self.full_observation_spec = obs_spec

        act_space = base.single_action_space
        self._dict_action = isinstance(act_space, spaces.Dict)
        self.full_action_spec = Composite(
            action=_batched(space_to_spec(act_space, device), batch),
            shape=batch,
            device=device,
        )
        self.full_reward_spec = Composite(
            reward=Unbounded(shape=batch + (1,), device=device, dtype=torch.float32),
            shape=batch,
            device=device,
        )
        self.full_done_spec = Composite(
            {
                key: Categorical(2, shape=batch + (1,), device=device, dtype=torch.bool)
                for key in _DONE_KEYS
            },
            shape=batch,
            device=device,
        )

    @staticmethod
    def _align_with_sample(spec: Composite, sample: Mapping[str, Any]) -> None:
        """Makes leaf specs agree in dtype/shape with a real observation sample."""
        for key, value in sample.items():
            if key not in spec.keys():
                continue
            sub = spec[key]
            if isinstance(value, Mapping):
                if isinstance(sub, Composite):
                    ManiSkillTorchRLEnv._align_with_sample(sub, value)
                continue
            if not isinstance(value, torch.Tensor) or isinstance(sub, Composite):
                continue
            if value.shape != sub.shape:
                spec[key] = Unbounded(
                    shape=value.shape, device=sub.device, dtype=value.dtype
                )
            elif value.dtype != sub.dtype:
                spec[key] = sub.to(value.dtype)

    # ------------------------------------------------------------------ #
    # Data conversion
    # ------------------------------------------------------------------ #
    def _to_flag(self, value: Any) -> torch.Tensor:
        """Converts a ManiSkill per-env flag to a bool tensor of shape [B, 1]."""
        return torch.as_tensor(value, device=self.device).to(torch.bool).reshape(
            self.num_envs, 1
        )

    def _obs_to_td(self, obs: Any, info: Mapping[str, Any]) -> TensorDictBase:
        """Packs a ManiSkill observation (and exposed info entries) into a TensorDict."""
        if self._dict_obs:
            td = TensorDict(obs, batch_size=self.batch_size, device=self.device)
        else:
            td = TensorDict(
                {"observation": obs}, batch_size=self.batch_size, device=self.device
            )
        for key in self._info_keys:
            value = info[key]
            if value.ndim == 1:
                value = value.reshape(self.num_envs, 1)
            td.set(key, value)
        return td

    # ------------------------------------------------------------------ #
    # EnvBase API
    # ------------------------------------------------------------------ #
    def _reset(
        self, tensordict: TensorDictBase | None = None, **kwargs: Any
    ) -> TensorDictBase:
        """Resets all envs, or only those selected by the ``"_reset"`` mask.

        Args:
            tensordict: Optional input; only its ``"_reset"`` entry is read.
            **kwargs: ``options`` (dict) is merged into ManiSkill's reset
                options (e.g. ``{"reconfigure": True}``).

        Returns:
            A new full-batch tensordict with observations and all-False done
            flags. For envs that were not reset, :meth:`EnvBase.reset` keeps
            the values from the input tensordict.
        """
        options = dict(kwargs.pop("options", None) or {})
        if kwargs:
            raise TypeError(f"Unexpected reset kwargs: {sorted(kwargs)}")
        reset_mask = None
        if tensordict is not None:
            reset_mask = tensordict.get("_reset", None)
        if reset_mask is not None:
            mask = reset_mask.reshape(self.num_envs).to(torch.bool)
            if not bool(mask.any()):
                return self._no_reset_output()
            if not bool(mask.all()):
                options["env_idx"] = mask.nonzero().squeeze(-1).to(self.device)

        seed, self._pending_seed = self._pending_seed, None
        obs, info = self._env.reset(seed=seed, options=options)
        td = self._obs_to_td(obs, info)
        self._last_obs_td = td
        out = td.clone(recurse=False)
        for key in _DONE_KEYS:
            out.set(
                key,
                torch.zeros(
                    (self.num_envs, 1), dtype=torch.bool, device=self.device
                ),
            )
        return out

    def _no_reset_output(self) -> TensorDictBase:
        """Output for a ``"_reset"`` mask that selects no env: the current data."""
        if self._last_obs_td is not None:
            out = self._last_obs_td.clone(recurse=False)
        else:
            out = self.full_observation_spec.zero()
        out.update(self.full_done_spec.zero())
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Applies ``tensordict["action"]`` to all envs and returns the transition."""
        action = tensordict.get("action")
        if self._dict_action:
            action = action.to_dict()
        obs, reward, terminated, truncated, info = self._env.step(action)
        td = self._obs_to_td(obs, info)
        self._last_obs_td = td
        out = td.clone(recurse=False)
        out.set(
            "reward",
            torch.as_tensor(reward, device=self.device)
            .to(torch.float32)
            .reshape(self.num_envs, 1),
        )
        terminated = self._to_flag(terminated)
        truncated = self._to_flag(truncated)
        out.set("terminated", terminated)
        out.set("truncated", truncated)
        out.set("done", terminated | truncated)
        return out

    def _set_seed(self, seed: int | None) -> None:
        """Stores ``seed``; the next :meth:`reset` passes it to ManiSkill."""
        self._pending_seed = None if seed is None else int(seed)

    def _close(self) -> None:
        """Closes the wrapped ManiSkill env (releases the SAPIEN scene/renderer)."""
        self._env.close()

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Closes the wrapper and the ManiSkill env; safe to call twice.

        Args:
            raise_if_closed: Accepted for API compatibility with
                :meth:`EnvBase.close`; closing twice is a no-op.
        """
        if not self.__dict__.get("is_closed", True):
            self._close()
        super().close(raise_if_closed=raise_if_closed)


def _sim_backend_for(device: torch.device) -> str:
    """ManiSkill ``sim_backend`` string that simulates on ``device``."""
    if device.type == "cpu":
        return "physx_cpu"
    if device.type == "cuda":
        return "physx_cuda" if device.index is None else f"physx_cuda:{device.index}"
    raise ValueError(f"ManiSkill cannot simulate on device {device!s}.")


def make_torchrl_env(
    env_id: str,
    *,
    device: torch.device | str | None = None,
    info_keys: Sequence[str] | None = None,
    **make_kwargs: Any,
) -> ManiSkillTorchRLEnv:
    """Makes a ManiSkill env with ``gymnasium.make`` and wraps it for TorchRL.

    Backends not given default to :func:`maniskill_pnp.runtime.default_backends`:
    PhysX on the CPU for one env (GPU for several, with CUDA); rendering on the GPU with CUDA, else lavapipe.

    Args:
        env_id: Gymnasium id, e.g. ``"PickCube-v1"`` or one of this project's
            task ids.
        device: Where the simulation (and therefore every tensor of the env)
            should live. If given and ``sim_backend`` is not, the matching
            ``sim_backend`` is chosen. Data is never moved afterwards, so a
            mismatch with an explicit ``sim_backend`` is an error.
        info_keys: See :class:`ManiSkillTorchRLEnv`.
        **make_kwargs: Forwarded to ``gymnasium.make`` (``obs_mode``,
            ``num_envs``, ``control_mode``, ``max_episode_steps``...).

    Returns:
        The wrapped environment.

    Raises:
        ValueError: If the env's device differs from ``device``.
    """
    import mani_skill.envs  # noqa: F401  (ManiSkill's own ids; ours register on `import maniskill_pnp`)

    requested = None if device is None else torch.device(device)
    if requested is not None:
        make_kwargs.setdefault("sim_backend", _sim_backend_for(requested))
    make_kwargs = with_default_backends(make_kwargs)
    env = gym.make(env_id, **make_kwargs)
    wrapped = ManiSkillTorchRLEnv(env, info_keys=info_keys)
    actual = wrapped.device
    if requested is not None and (
        actual.type != requested.type
        or (
            requested.index is not None
            and actual.index is not None
            and actual.index != requested.index
        )
    ):
        wrapped.close()
        raise ValueError(
            f"{env_id} simulates on {actual}, but device={requested} was requested "
            f"(sim_backend={make_kwargs.get('sim_backend')!r})."
        )
    return wrapped
