"""Where things run: simulation and rendering backends for this machine."""

from __future__ import annotations

import torch


def default_backends(num_envs: int = 1) -> dict[str, str]:
    """ManiSkill backends: rendering on the GPU when CUDA is present (else lavapipe); PhysX on the CPU for one env.

    A single env steps faster on PhysX CPU than through the GPU pipeline; several parallel envs need the GPU
    simulation (ManiSkill's CPU simulation holds one env per process).
    """
    cuda = torch.cuda.is_available()
    return {
        "sim_backend": "physx_cuda" if cuda and num_envs > 1 else "physx_cpu",
        "render_backend": "sapien_cuda" if cuda else "cpu",
    }


def resolve_device(name: str) -> torch.device:
    """A torch device from a name; ``"auto"`` is CUDA when available, else the CPU."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def with_default_backends(make_kwargs: dict) -> dict:
    """``gym.make`` keyword arguments with the :func:`default_backends` of their ``num_envs`` for the backends not
    given."""
    return {**default_backends(make_kwargs.get("num_envs", 1)), **make_kwargs}
