"""Where things run: simulation and rendering backends for this machine."""

from __future__ import annotations

import atexit
import gc

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


_frozen = False


def freeze_long_lived_objects() -> None:
    """Once per process: take every object alive now out of the cyclic garbage collector's sweeps (``gc.freeze``).

    A one-env clutter task builds a new PhysX scene at every reset, and ManiSkill then runs a full garbage collection,
    which walks every object of the process: about 0.3 s per reset once torch, ManiSkill and a network are loaded.
    Frozen, the libraries' objects are skipped and the collection walks only what was made since (the old scenes it
    frees). Called by the agents' env factory; later calls do nothing, so a process that builds many envs (a test run)
    freezes only the first. The frozen objects are released to the collector again at exit.
    """
    global _frozen
    if _frozen:
        return
    _frozen = True
    gc.collect()
    gc.freeze()
    atexit.register(gc.unfreeze)
