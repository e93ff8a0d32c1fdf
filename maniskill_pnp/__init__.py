"""maniskill_pnp: learned industrial pick-and-place on ManiSkill, with TorchRL agents and OMPL motion planning.

Importing the package registers its tasks with ManiSkill and gymnasium (``gym.make("CubeToBin-v1")``...).
"""

from maniskill_pnp import tasks  # noqa: F401  (registers the task ids)
from maniskill_pnp.gym_env import make_gym_env  # noqa: F401

# TorchRL integration, exported lazily so that importing `maniskill_pnp` (e.g. for
# planning) does not pay for importing torchrl.
_LAZY_TORCHRL_EXPORTS = ("make_torchrl_env", "ManiSkillTorchRLEnv")


def __getattr__(name: str):
    if name in _LAZY_TORCHRL_EXPORTS:
        from maniskill_pnp import torchrl_env

        return getattr(torchrl_env, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
