"""The Warp device a run asks for, and whether the scene fits in its memory, checked before any work.

    device = check_device("cuda:0")   # DeviceError naming the devices there are, if it is not one
    check_memory(scene, device)       # MemoryLimitError (a SceneError) with the figures and the fix
"""
from __future__ import annotations

import warp as wp

from ..core.simulation import SimulationError
from ..core.threads import cpu_threads
from ..scene.limits import check_memory as _check_scene_memory

GPU_NEEDS = ("a GPU run needs an NVIDIA CUDA-capable GPU, its NVIDIA driver (`nvidia-smi` lists the GPU) and "
             "the warp-lang wheel from PyPI (it bundles the CUDA runtime); without one, use --device cpu")


class DeviceError(SimulationError):
    """The device asked for does not exist here; the message lists those that do."""

    exit_code = 2  # a refusal before any work, like a bad scene


def _available() -> list[str]:
    try:
        return [str(d) for d in wp.get_devices()]
    except Exception:  # noqa: BLE001 (a broken driver must not hide the real answer)
        return ["cpu"]


def check_device(name=None):
    """The Warp device called `name` (None: Warp's default), or DeviceError listing the devices
    Warp sees and what a GPU run needs (or what is wrong with WARP_MPM_CPU_THREADS)."""
    try:
        cpu_threads()
    except ValueError as err:
        raise DeviceError(str(err)) from None
    there = _available()
    if name is not None:
        name = str(name)
        has_cuda = any(d.startswith("cuda") for d in there)
        if (name not in there) if name != "cuda" else not has_cuda:  # "cuda": Warp's current CUDA device
            gpu = name.startswith(("cuda", "gpu"))
            raise DeviceError(f"device {name!r} is not available: Warp sees {', '.join(there)}"
                              + (f"; {GPU_NEEDS}" if gpu and not has_cuda else "; give one of those to --device"))
    try:
        return wp.get_device(name)
    except (ValueError, RuntimeError) as err:  # "cuda" with no CUDA: a RuntimeError from Warp
        raise DeviceError(f"device {name!r} is not available ({err}): Warp sees {', '.join(there)}; "
                          f"{GPU_NEEDS}") from None


def device_memory(device) -> int | None:
    """Bytes free on a CUDA device (total when free is unknown), None for the CPU (host memory)."""
    if device is None or not getattr(device, "is_cuda", False):
        return None
    free = getattr(device, "free_memory", None)
    return int(free if free else device.total_memory)


def check_memory(scene, device=None):
    """Refuse a scene the host or `device` (a name or a Warp device) cannot hold; returns the estimate."""
    dev = check_device(device) if device is None or isinstance(device, str) else device
    return _check_scene_memory(scene, device_bytes=device_memory(dev), device_name=str(dev))
