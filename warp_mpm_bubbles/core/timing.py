"""Wall-clock seconds per timed phase of the step (the core's and each stage's timer line), and the
list of those that ran.

On CUDA, launches are asynchronous, so each phase synchronizes at its end to charge its own time;
on the CPU, launches are synchronous and the synchronization is skipped.
"""

from __future__ import annotations

import os
import platform
import time
from contextlib import contextmanager

import warp as wp


class PhaseTimer:
    def __init__(self, device):
        self.device = device
        self.seconds: dict[str, float] = {}  # insertion order = order of first run

    @contextmanager
    def __call__(self, phase: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            if self.device.is_cuda:
                wp.synchronize_device(self.device)
            self.seconds[phase] = self.seconds.get(phase, 0.0) + time.perf_counter() - start

    @property
    def phases_run(self) -> list[str]:
        return list(self.seconds)

    @property
    def total(self) -> float:
        return sum(self.seconds.values())


def describe_device(dev) -> str:
    """A Warp device as benchmark notes name it: the GPU's name, or the CPU model and core count."""
    if dev.is_cuda:
        return f"{dev.alias} ({dev.name})"
    model = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{dev.alias} ({model}, {os.cpu_count()} cores)"
