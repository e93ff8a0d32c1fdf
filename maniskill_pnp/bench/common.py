"""What every benchmark prints and saves beside its numbers: machine, versions, settings."""

from __future__ import annotations

import json
import os
import platform
from importlib import metadata
from pathlib import Path

import torch

PACKAGES = ("maniskill_pnp", "mani-skill", "sapien", "torch", "torchrl", "tensordict", "ompl", "mplib", "numpy")


def machine_info() -> dict:
    """CPU count, platform, GPU (if any) and the versions of the stack."""
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "versions": versions,
    }


def print_machine(load: tuple[float, float, float] | None = None) -> None:
    """One line of machine info: platform, CPUs, GPU, the versions of torch, torchrl, mani-skill, sapien and ompl, and
    the load average (1, 5, 15 min) when given: other processes on the same cores slow both sides of a comparison,
    but not always alike."""
    m = machine_info()
    v = m["versions"]
    line = (f"machine: {m['platform']}, {m['cpus']} cpus, gpu={m['gpu']}; torch {v['torch']}, torchrl {v['torchrl']}, "
            f"mani-skill {v['mani-skill']}, sapien {v['sapien']}, ompl {v['ompl']}")
    if load is not None:
        line += f"; load average at start {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
    print(line)


def write_report(path: Path, name: str, settings: dict, results: dict) -> Path:
    """Write ``{"benchmark", "machine", "settings", "results"}`` as JSON and return the path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    report = {"benchmark": name, "machine": machine_info(), "settings": settings, "results": results}
    path.write_text(json.dumps(report, indent=2, default=str))
    return path
