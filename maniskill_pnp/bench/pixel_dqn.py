"""Benchmarks of the pixelwise Q networks: training-step memory and the cost of one greedy decision.

**pixel-memory** — peak memory of ONE training step of a :class:`~maniskill_pnp.agents.pixel.fcn.MultiPrimitiveQNetwork`
(defaults: the thesis' G&S network, 3 primitives x 16 rotations x 224 px heightmap, batch 1, DenseNet-121 trunks):
forward, a Huber loss on one pixel of every primitive's maps (the executed-pixel loss of the thesis, with a random
pixel and target), backward. It compares torchvision's DenseNet ``memory_efficient=True`` (gradient checkpointing
inside every dense layer; what :data:`~maniskill_pnp.agents.pixel.fcn.BACKBONES` builds) with ``False`` (the flag of
every ``_DenseLayer`` switched off after construction). Each variant runs in its own fresh Python process, so that
neither sees the other's allocator state; the process reports

* ``rss_growth_bytes``: peak resident set size during the step(s) minus the resident set size after the model and
  its input were built, i.e. the memory the step itself added on the CPU (activations, gradients, workspace). The
  peak is the kernel's high-water mark (``VmHWM``), reset after construction (``/proc/self/clear_refs``) so that
  transients of the construction do not hide it; where that reset is refused, ``ru_maxrss`` (the process's peak
  since it started) is used and ``peak_reset`` is false;
* ``cuda_peak_bytes`` (CUDA only): ``torch.cuda.max_memory_allocated`` during the step minus the allocation before it;
* ``step_s``: wall time of each step (s).

A parent watchdog kills a variant whose resident memory passes ``max_rss_gb`` (default: 90% of the memory available
at the start) and reports it as exceeded, instead of letting the machine run out of memory.

**decision-cost** — the time of one greedy decision (what
:class:`~maniskill_pnp.agents.pixel.policy.GreedyPixelActor` does: heightmap conversion, padding, ``R`` rotations,
both trunks, head, upsampling, rotation back, crop, for every primitive, then the argmax over all flat maps) divided
by the time of the bare trunk forwards on the same batch (the ``B*R`` rotated padded images, captured from the
decision itself, through the colour and depth trunks of every primitive). Everything runs under
``torch.inference_mode`` after warm-up; decisions and trunk passes alternate, and the medians of ``repeats``
of each are compared. The target of the issue is a ratio <= 1.3.
One more decision, under ``torch.profiler`` with timing hooks on the trunks and heads, tells where the rest goes
(``breakdown_s``: trunks, heads, everything else; ``ops_extra_self_s``: the operators whose self time grows most from
a profiled bare trunk pass to a profiled decision).

Run ``maniskill-pnp bench pixel-memory`` and ``maniskill-pnp bench decision-cost`` (see ``--help`` for sizes).
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F

from maniskill_pnp.bench.common import print_machine, write_report
from maniskill_pnp.runtime import resolve_device
from maniskill_pnp.tasks.clutter_grasp_slide import ClutterGraspSlideEnv

#: Primitive names of the grasp & slide network, in action-index order; a benchmark with ``n`` primitives uses the first n.
PRIMITIVES = ClutterGraspSlideEnv.PRIMITIVES
#: Ratio decision / bare trunks the issue asks for.
DECISION_COST_TARGET = 1.3
#: Operators listed in the decision-cost profile (those whose time grows most from the bare trunks to the decision).
TOP_OPS = 8
_GIB = 1024**3



def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _check_sizes(backbone: str, num_rotations: int, heightmap_size: int, counts: tuple[int, ...], device: str,
                 threads: int | None) -> None:
    from maniskill_pnp.agents.pixel.fcn import BACKBONES

    if threads is not None and threads < 1:
        raise ValueError(f"threads must be >= 1 (or None for torch's default), got {threads}")
    if backbone == "equivariant":
        raise ValueError("the pixel benchmarks measure the rotated-trunk networks; the equivariant backbone has no trunk "
                         f"(choose one of {sorted(BACKBONES)})")
    if backbone not in BACKBONES:
        raise ValueError(f"backbone must be one of {sorted(BACKBONES)}, got {backbone!r}")
    if num_rotations < 1 or heightmap_size < 1:
        raise ValueError(f"num_rotations and heightmap_size must be >= 1, got {num_rotations}, {heightmap_size}")
    if not counts or any(not 1 <= n <= len(PRIMITIVES) for n in counts):
        raise ValueError(f"num_primitives must be in 1..{len(PRIMITIVES)} ({', '.join(PRIMITIVES)}), got {counts}")
    if device != "auto":
        try:
            torch.device(device)
        except RuntimeError as e:
            raise ValueError(f"device must be 'auto' or a torch device such as 'cpu' or 'cuda:0', got {device!r}") from e


def _build(backbone: str, num_rotations: int, num_primitives: int):
    from maniskill_pnp.agents.pixel.fcn import MultiPrimitiveQNetwork

    return MultiPrimitiveQNetwork(PRIMITIVES[:num_primitives], num_rotations=num_rotations, backbone=backbone)


def _heightmaps(batch: int, size: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Random colour (uint8 ``(B, H, W, 3)``) and height (m, ``(B, H, W)``, up to 5 cm) heightmaps."""
    g = torch.Generator().manual_seed(0)
    color = torch.randint(0, 256, (batch, size, size, 3), dtype=torch.uint8, generator=g)
    depth = 0.05 * torch.rand(batch, size, size, generator=g)
    return color.to(device), depth.to(device)


# ============================================================================= pixel-memory
@dataclass(frozen=True)
class PixelMemoryBenchConfig:
    """Settings of the training-step memory benchmark (defaults: the thesis' G&S network).

    Attributes:
        backbone: Trunk of every Q network; the memory-efficient switch only exists for "densenet121".
        num_rotations: Rotations per primitive.
        heightmap_size: Heightmap pixels per side.
        num_primitives: The first n of grasp, left slide, right slide.
        repeats: Training steps per variant (memory is the peak over all; times are reported per step).
        device: "auto" (CUDA when available), "cpu" or a CUDA device.
        threads: CPU threads of torch (None: torch's default); 1 keeps timings steady while other jobs share the cores.
        max_rss_gb: Kill a variant whose resident memory passes this (GiB); None: 90% of the memory available now.
        timeout_s: Wall-clock limit of one variant's process (s).
        out: JSON report path.
    """

    backbone: str = "densenet121"
    num_rotations: int = 16
    heightmap_size: int = 224
    num_primitives: int = 3
    repeats: int = 1
    device: str = "auto"
    threads: int | None = None
    max_rss_gb: float | None = None
    timeout_s: float = 3600.0
    out: Path = Path("runs/bench/pixel_memory.json")

    def __post_init__(self):
        _check_sizes(self.backbone, self.num_rotations, self.heightmap_size, (self.num_primitives,), self.device,
                     self.threads)
        if self.backbone != "densenet121":
            raise ValueError(f"the memory-efficient switch exists for densenet121 only, got backbone {self.backbone!r}")
        if self.repeats < 1:
            raise ValueError(f"repeats must be >= 1, got {self.repeats}")
        if self.max_rss_gb is not None and not self.max_rss_gb > 0:
            raise ValueError(f"max_rss_gb must be > 0 (or None for 90% of the available memory), got {self.max_rss_gb}")
        if not self.timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0, got {self.timeout_s}")


def set_memory_efficient(model: torch.nn.Module, enabled: bool) -> int:
    """Set ``memory_efficient`` on every torchvision DenseNet ``_DenseLayer`` of ``model``; returns how many.

    With the flag on, a dense layer recomputes its concatenation + BN + ReLU + 1x1 conv in the backward pass
    (``torch.utils.checkpoint``) instead of keeping their outputs.
    """
    from torchvision.models.densenet import _DenseLayer

    layers = [m for m in model.modules() if isinstance(m, _DenseLayer)]
    for layer in layers:
        layer.memory_efficient = enabled
    return len(layers)


def _rss_bytes() -> int:
    """Current resident set size of this process (bytes)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _reset_peak_rss() -> bool:
    """Reset this process's resident-set high-water mark (Linux >= 4.0); False where that is refused."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak_rss_bytes(reset: bool) -> int:
    """Peak resident set size (bytes): since the last reset (``VmHWM``), else since the start (``ru_maxrss``, KiB)."""
    if reset:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def measure_training_step(settings: dict, memory_efficient: bool) -> dict:
    """Build the network in this process, then time and measure ``settings["repeats"]`` training steps.

    Meant to run in a fresh process (see :func:`run_pixel_memory`): the peak resident set size is per process, and
    nothing else the process did may have left memory to reuse.
    Returns the measurements described in the module docstring (bytes, seconds).
    """
    import gc

    from maniskill_pnp.agents.pixel.policy import heightmap_input

    device = resolve_device(settings["device"])
    if settings["threads"] is not None:
        torch.set_num_threads(settings["threads"])
    torch.manual_seed(0)
    model = _build(settings["backbone"], settings["num_rotations"], settings["num_primitives"]).to(device).train()
    layers = set_memory_efficient(model, memory_efficient)
    color, depth = _heightmaps(1, settings["heightmap_size"], device)
    x = heightmap_input(color, depth)
    P = settings["num_primitives"]
    pixels = torch.randint(0, settings["num_rotations"] * settings["heightmap_size"] ** 2, (P,), device=device)
    targets = torch.rand(P, device=device)
    gc.collect()
    rss_built = _rss_bytes()
    reset = _reset_peak_rss()
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    cuda_before = torch.cuda.memory_allocated(device) if device.type == "cuda" else None

    step_s = []
    for _ in range(settings["repeats"]):
        model.zero_grad(set_to_none=True)
        _sync(device)
        t0 = time.perf_counter()
        maps = model(x)  # (1, P, R, H, W)
        q = maps.reshape(P, -1).gather(1, pixels.unsqueeze(1)).squeeze(1)
        loss = F.smooth_l1_loss(q, targets)
        loss.backward()
        _sync(device)
        step_s.append(time.perf_counter() - t0)
        del maps, q, loss
    peak = _peak_rss_bytes(reset)
    return dict(
        memory_efficient=memory_efficient, dense_layers=layers, step_s=step_s,
        rss_after_build_bytes=rss_built, peak_reset=reset, peak_rss_bytes=peak,
        rss_growth_bytes=peak - rss_built,
        cuda_peak_bytes=(torch.cuda.max_memory_allocated(device) - cuda_before) if device.type == "cuda" else None,
        device=str(device), torch_threads=torch.get_num_threads(),
    )


def _available_bytes() -> int:
    with open("/proc/meminfo") as f:
        fields = dict(line.split(":", 1) for line in f)
    return int(fields["MemAvailable"].split()[0]) * 1024


def _process_rss_bytes(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except FileNotFoundError:
        pass
    return 0


def _run_variant(settings: dict, memory_efficient: bool, limit_bytes: int, timeout_s: float) -> dict:
    """One variant in a fresh ``python -m maniskill_pnp.bench.pixel_dqn memory-child`` process, under a watchdog."""
    cmd = [sys.executable, "-m", "maniskill_pnp.bench.pixel_dqn", "memory-child",
           json.dumps(dict(settings, memory_efficient=memory_efficient))]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0, seen, reason = time.monotonic(), 0, None
    while True:
        try:
            stdout, stderr = proc.communicate(timeout=0.2)
            break
        except subprocess.TimeoutExpired:
            seen = max(seen, _process_rss_bytes(proc.pid))
            if seen > limit_bytes:
                reason = f"resident memory passed the limit of {limit_bytes / _GIB:.1f} GiB"
            elif time.monotonic() - t0 > timeout_s:
                reason = f"still running after the time limit of {timeout_s:.0f} s"
            if reason:
                proc.kill()
                stdout, stderr = proc.communicate()
                break
    if reason:
        return dict(memory_efficient=memory_efficient, exceeded=reason, rss_at_kill_bytes=seen)
    if proc.returncode != 0:
        raise RuntimeError(f"memory-child (memory_efficient={memory_efficient}) failed with exit code "
                           f"{proc.returncode}:\n{stderr[-3000:]}")
    result = json.loads(stdout.strip().splitlines()[-1])
    result["watchdog_max_rss_bytes"] = seen
    return result


def run_pixel_memory(cfg: PixelMemoryBenchConfig) -> dict:
    """Measure both variants (memory-efficient first), print them and their ratio, write the JSON report."""
    settings = dict(backbone=cfg.backbone, num_rotations=cfg.num_rotations, heightmap_size=cfg.heightmap_size,
                    num_primitives=cfg.num_primitives, repeats=cfg.repeats, device=cfg.device, threads=cfg.threads)
    limit = int(cfg.max_rss_gb * _GIB) if cfg.max_rss_gb is not None else int(0.9 * _available_bytes())
    load_at_start = os.getloadavg()
    variants = {
        "efficient": _run_variant(settings, True, limit, cfg.timeout_s),
        "non_efficient": _run_variant(settings, False, limit, cfg.timeout_s),
    }

    def ratio(key: str) -> float | None:
        a, b = variants["efficient"].get(key), variants["non_efficient"].get(key)
        return a / b if a and b else None

    results = dict(variants, rss_limit_bytes=limit, load_average_at_start=load_at_start, load_average_at_end=os.getloadavg(),
                   ratio_rss_efficient_over_non_efficient=ratio("rss_growth_bytes"),
                   ratio_cuda_efficient_over_non_efficient=ratio("cuda_peak_bytes"))
    path = write_report(cfg.out, "pixel_memory", {k: str(v) for k, v in asdict(cfg).items()}, results)

    print_machine(load_at_start)
    print(f"one training step (forward + Huber loss on one pixel per primitive + backward), batch 1, "
          f"{cfg.backbone}, {cfg.num_primitives} primitive(s) x {cfg.num_rotations} rotations x {cfg.heightmap_size} px")
    for name, v in variants.items():
        if "exceeded" in v:
            print(f"  {name:<14} not measured: {v['exceeded']} (killed at {v['rss_at_kill_bytes'] / _GIB:.2f} GiB resident)")
            continue
        cuda = f", CUDA peak {v['cuda_peak_bytes'] / _GIB:.3f} GiB" if v["cuda_peak_bytes"] is not None else ""
        steps = ", ".join(f"{s:.2f}" for s in v["step_s"])
        print(f"  {name:<14} CPU peak RSS growth {v['rss_growth_bytes'] / _GIB:.3f} GiB{cuda}; step time {steps} s "
              f"({v['dense_layers']} dense layers, device {v['device']}, {v['torch_threads']} threads)")
    for key in ("rss", "cuda"):
        r = results[f"ratio_{key}_efficient_over_non_efficient"]
        if r is not None:
            print(f"  ratio efficient / non-efficient ({'CPU RSS growth' if key == 'rss' else 'CUDA peak'}): {r:.3f}")
    print(f"report: {path}")
    return results


# ============================================================================= decision-cost
@dataclass(frozen=True)
class DecisionCostBenchConfig:
    """Settings of the decision-cost benchmark.

    Attributes:
        backbone: Trunk of every Q network.
        num_rotations: Rotations per primitive.
        heightmap_size: Heightmap pixels per side.
        num_primitives: Network sizes to measure: the first n of grasp, left slide, right slide, for each n.
        batch: Heightmaps per decision.
        warmup: Untimed rounds (one decision and one trunk pass each) before timing.
        repeats: Timed rounds; decisions and trunk passes alternate, and their medians are compared.
        device: "auto" (CUDA when available), "cpu" or a CUDA device.
        threads: CPU threads of torch (None: torch's default); 1 keeps timings steady while other jobs share the cores.
        out: JSON report path.
    """

    backbone: str = "densenet121"
    num_rotations: int = 16
    heightmap_size: int = 224
    num_primitives: tuple[int, ...] = (1, 3)
    batch: int = 1
    warmup: int = 1
    repeats: int = 3
    device: str = "auto"
    threads: int | None = None
    out: Path = Path("runs/bench/decision_cost.json")

    def __post_init__(self):
        object.__setattr__(self, "num_primitives", tuple(self.num_primitives))
        _check_sizes(self.backbone, self.num_rotations, self.heightmap_size, self.num_primitives, self.device,
                     self.threads)
        if self.batch < 1 or self.warmup < 0 or self.repeats < 1:
            raise ValueError(f"need batch >= 1, warmup >= 0, repeats >= 1; got {self.batch}, {self.warmup}, {self.repeats}")


class _TrunkInputs:
    """Forward hooks that keep the inputs every trunk receives (the rotated, padded, normalised images)."""

    def __init__(self, model):
        self.inputs: list[tuple[torch.nn.Module, torch.Tensor]] = []
        self.handles = [
            trunk.register_forward_pre_hook(lambda m, args: self.inputs.append((m, args[0])))
            for net in model.nets.values() for trunk in (net.color_trunk, net.depth_trunk) if trunk is not None
        ]

    def remove(self) -> None:
        for h in self.handles:
            h.remove()


class _ModuleTimer:
    """Forward pre/post hooks that add up the wall time spent inside the trunks and heads (s)."""

    def __init__(self, model, device: torch.device):
        self.totals: dict[str, float] = defaultdict(float)
        self._started: dict[int, float] = {}
        self.handles = []
        for net in model.nets.values():
            parts = {"trunks": [net.color_trunk, net.depth_trunk], "heads": [net.head]}
            for kind, modules in parts.items():
                for m in modules:
                    if m is None:
                        continue
                    self.handles.append(m.register_forward_pre_hook(self._start(device)))
                    self.handles.append(m.register_forward_hook(self._stop(kind, device)))

    def _start(self, device):
        def hook(m, args):
            _sync(device)
            self._started[id(m)] = time.perf_counter()
        return hook

    def _stop(self, kind, device):
        def hook(m, args, out):
            _sync(device)
            self.totals[kind] += time.perf_counter() - self._started.pop(id(m))
        return hook

    def remove(self) -> None:
        for h in self.handles:
            h.remove()


def _interleaved_times(fns: dict, warmup: int, repeats: int, device: torch.device) -> dict[str, list[float]]:
    """Wall times (s) of ``repeats`` calls of every function in ``fns``, after ``warmup`` untimed rounds.

    The functions take turns (a, b, a, b, ...), so that a load change on a shared machine hits all of them alike.
    """
    times = {name: [] for name in fns}
    for i in range(warmup + repeats):
        for name, fn in fns.items():
            _sync(device)
            t0 = time.perf_counter()
            fn()
            _sync(device)
            if i >= warmup:
                times[name].append(time.perf_counter() - t0)
    return times


def _profile(fn, device: torch.device) -> tuple[dict[str, float], float]:
    """Self time (s) of every operator of one call of ``fn`` under ``torch.profiler``, and the call's wall time (s)."""
    activities = [torch.profiler.ProfilerActivity.CPU]
    if device.type == "cuda":
        activities.append(torch.profiler.ProfilerActivity.CUDA)
    with torch.profiler.profile(activities=activities) as prof:
        _sync(device)
        t0 = time.perf_counter()
        fn()
        _sync(device)
        wall = time.perf_counter() - t0
    attr = "self_device_time_total" if device.type == "cuda" else "self_cpu_time_total"
    return {e.key: getattr(e, attr) / 1e6 for e in prof.key_averages()}, wall


@torch.inference_mode()
def measure_decision(cfg: DecisionCostBenchConfig, num_primitives: int) -> dict:
    """Times of one decision and of its bare trunk passes (s), their ratio, and where the difference goes."""
    from maniskill_pnp.agents.pixel.policy import GreedyPixelActor

    device = resolve_device(cfg.device)
    torch.manual_seed(0)
    model = _build(cfg.backbone, cfg.num_rotations, num_primitives).to(device).eval()
    actor = GreedyPixelActor(model)
    color, depth = _heightmaps(cfg.batch, cfg.heightmap_size, device)

    # the exact trunk inputs of a decision (B*R rotated padded images per trunk)
    capture = _TrunkInputs(model)
    actor(color, depth)
    capture.remove()
    trunk_calls = capture.inputs

    def decision():
        return actor(color, depth)

    def bare_trunks():
        for trunk, images in trunk_calls:
            trunk(images)

    times = _interleaved_times(dict(decision=decision, trunks=bare_trunks), cfg.warmup, cfg.repeats, device)
    decision_s, trunks_s = times["decision"], times["trunks"]

    # one more decision and trunk pass, profiled: hooks time the trunks and heads inside the decision, and the
    # operators' self times of the decision minus those of the bare trunks show what the decision adds
    timer = _ModuleTimer(model, device)
    decision_ops, profiled_total = _profile(decision, device)
    timer.remove()
    trunk_ops, _ = _profile(bare_trunks, device)
    extra = {k: v - trunk_ops.get(k, 0.0) for k, v in decision_ops.items()}
    extra = dict(sorted(((k, v) for k, v in extra.items() if v > 0), key=lambda kv: -kv[1])[:TOP_OPS])

    d, t = statistics.median(decision_s), statistics.median(trunks_s)
    return dict(
        num_primitives=num_primitives, primitives=list(PRIMITIVES[:num_primitives]),
        trunk_batch=[list(images.shape) for _, images in trunk_calls],
        decision_s_median=d, trunks_s_median=t, ratio=d / t, target=DECISION_COST_TARGET,
        meets_target=d / t <= DECISION_COST_TARGET, decision_s=decision_s, trunks_s=trunks_s,
        breakdown_s=dict(profiled_decision=profiled_total, trunks=timer.totals["trunks"], heads=timer.totals["heads"],
                         other=profiled_total - timer.totals["trunks"] - timer.totals["heads"]),
        ops_extra_self_s=extra, ops_time_kind="device" if device.type == "cuda" else "cpu", device=str(device),
        torch_threads=torch.get_num_threads(),
    )


def run_decision_cost(cfg: DecisionCostBenchConfig) -> dict:
    """Measure every network size of ``cfg.num_primitives``; print the ratios and breakdowns; write the JSON report."""
    load_at_start = os.getloadavg()
    threads = torch.get_num_threads()
    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    try:
        results = {f"primitives_{n}": measure_decision(cfg, n) for n in cfg.num_primitives}
    finally:
        torch.set_num_threads(threads)
    results.update(load_average_at_start=load_at_start, load_average_at_end=os.getloadavg())
    path = write_report(cfg.out, "decision_cost", {k: str(v) for k, v in asdict(cfg).items()}, results)

    print_machine(load_at_start)
    print(f"one greedy decision vs its bare trunk forwards: {cfg.backbone}, {cfg.num_rotations} rotations, "
          f"{cfg.heightmap_size} px, batch {cfg.batch}; median of {cfg.repeats} after {cfg.warmup} warm-up, "
          f"{results[f'primitives_{cfg.num_primitives[0]}']['torch_threads']} torch threads")
    for r in (results[f"primitives_{n}"] for n in cfg.num_primitives):
        verdict = "meets" if r["meets_target"] else "ABOVE"
        print(f"  {r['num_primitives']} primitive(s) {'+'.join(r['primitives'])}: decision {r['decision_s_median']:.4f} s, "
              f"trunks {r['trunks_s_median']:.4f} s ({len(r['trunk_batch'])} trunk calls on {r['trunk_batch'][0]}), "
              f"ratio {r['ratio']:.3f} ({verdict} the target {DECISION_COST_TARGET})")
        b = r["breakdown_s"]
        print(f"    profiled decision {b['profiled_decision']:.4f} s = trunks {b['trunks']:.4f} + heads {b['heads']:.4f} "
              f"+ other {b['other']:.4f} (rotation, padding, normalisation, upsampling, crop, argmax)")
        top = ", ".join(f"{k.removeprefix('aten::')} {v * 1e3:.2f}" for k, v in r["ops_extra_self_s"].items())
        print(f"    operators the decision adds to the trunks (self {r['ops_time_kind']} time, ms): {top}")
    print(f"report: {path}")
    return results


def _main(argv: list[str]) -> None:
    """Entry point of the fresh process of one pixel-memory variant: ``memory-child '<settings JSON>'``."""
    if len(argv) != 2 or argv[0] != "memory-child":
        raise SystemExit("usage: python -m maniskill_pnp.bench.pixel_dqn memory-child '<settings JSON>' "
                         "(internal; use `maniskill-pnp bench pixel-memory`)")
    settings = json.loads(argv[1])
    result = measure_training_step(settings, bool(settings.pop("memory_efficient")))
    print(json.dumps(result))


if __name__ == "__main__":
    _main(sys.argv[1:])
