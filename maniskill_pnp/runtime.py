"""Where things run: simulation and rendering backends for this machine."""

from __future__ import annotations

import torch


def default_backends() -> dict[str, str]:
    """ManiSkill backends: GPU physics and rendering when CUDA is present, PhysX CPU and lavapipe otherwise."""
    if torch.cuda.is_available():
        return {"sim_backend": "physx_cuda", "render_backend": "sapien_cuda"}
    return {"sim_backend": "physx_cpu", "render_backend": "cpu"}
