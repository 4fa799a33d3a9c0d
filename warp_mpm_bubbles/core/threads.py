"""The CPU's cores: Warp runs a CPU launch on one thread, so the step's large launches are split into
parts that run at once, one launch per thread (Warp releases Python's lock while a CPU kernel runs).
The parts are chosen so that the results do not depend on how many there are:
- g2p, and the per-particle kernels that write only their own particles (Simulation.launch_particles:
  the gas's J update, the films' retraction): ranges of particles, which are independent (only their
  largest speed is combined, exactly);
- p2g and the gas's splat (Simulation.launch_splat): disjoint slabs of grid nodes along x, each part
  visiting the particles in the same order, so every node sums its contributions in particle order
  whatever the split;
- the grid phases, the V-cycle's smoothing, restriction, prolongation and coarse operators, and the
  CG's vector kernels over a large box (lines of cells, core/lines.py): slabs of lines, for kernels
  that write only the cells they walk. The CG's dot products are summed per plane of the box (a
  plane is one slab's) and then over the planes in order (core/pressure.py), so they too are the
  same for any number of slabs; the pressure system's assembly counts its fluid and pinned cells per
  slab (integers, added on the host);
- the particles' bounding box (core/active_box.py): ranges of particles, each with its own minima
  and maxima, combined exactly.
Counters and extrema that every part updates lie CACHE_LINE_FLOATS apart (below).

Threads: `WARP_MPM_CPU_THREADS` if set (1: one launch, as before), else the cores this process may
use, at most MAX_THREADS. On a GPU there is one launch.
"""

from __future__ import annotations

import math
import os
import threading
import weakref

from .lines import slab_planes, split_lines

MAX_THREADS = 8  # p2g's parts each scan every particle's position: the scan's share grows with the count
# A launch over a box this large (cells or faces) runs in slabs, one a thread: smaller ones cost less
# than the hand-off (about 30 us a launch; a 40^3 box's red-black half-sweep takes about 500 us).
SPLIT_CELLS = 16384
SPLIT_PARTICLES = 16384  # the same for a per-particle kernel's launch (core/simulation.py launch_particles)
# Values that parts update for every particle (their fastest speed, their bounds) lie this many 4-byte
# words apart, a cache line: side by side, two cores writing them would pass the line back and forth.
CACHE_LINE_FLOATS = 16


def cpu_threads() -> int:
    """Threads for CPU transfers: WARP_MPM_CPU_THREADS, else the usable cores (at most MAX_THREADS)."""
    value = os.environ.get("WARP_MPM_CPU_THREADS")
    if value is not None:
        try:
            n = int(value)
        except ValueError:
            raise ValueError(f"WARP_MPM_CPU_THREADS={value!r} is not a whole number: set it to 1 or more, "
                             f"or unset it to use every core") from None
        if n < 1:
            raise ValueError(f"WARP_MPM_CPU_THREADS={n}: set it to 1 or more, or unset it to use every core")
        return n
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_THREADS))


class _Worker:
    """A thread that runs one call at a time, handed over with two locks (`go`, `done`) rather than a
    queue and a future: a step hands over hundreds of launches, and a ThreadPoolExecutor's hand-off
    took about 1.7 times as long as these locks' (docs/performance.md#threads)."""

    def __init__(self):
        self.go, self.done = threading.Lock(), threading.Lock()
        self.go.acquire()
        self.done.acquire()
        self.call, self.error = None, None
        threading.Thread(target=self._loop, name="warp_mpm_cpu", daemon=True).start()

    def _loop(self):
        while True:
            self.go.acquire()
            if self.call is None:  # stop()
                return
            try:
                self.call()
            except BaseException as error:  # noqa: BLE001 (raised again on the calling thread, by wait)
                self.error = error
            self.done.release()

    def start(self, call):
        self.call = call
        self.go.release()

    def wait(self):
        self.done.acquire()
        error, self.error, self.call = self.error, None, None
        if error is not None:
            raise error

    def stop(self):
        self.call = None
        self.go.release()


def _stop(workers):
    for w in workers:
        w.stop()


class Parallel:
    """Runs a list of calls (each one kernel launch) at once on `threads` threads, the first on the
    calling thread (with any calls past one a thread); one thread: one after the other. The worker
    threads end when the Parallel is collected."""

    def __init__(self, threads: int):
        self.threads = threads
        self._workers = [_Worker() for _ in range(threads - 1)]
        weakref.finalize(self, _stop, self._workers)

    def run(self, calls):
        if not self._workers or len(calls) <= 1:  # nothing to launch (an empty box), or one call
            for call in calls:
                call()
            return
        started = self._workers[:len(calls) - 1]
        for w, call in zip(started, calls[1:]):
            w.start(call)
        try:
            calls[0]()
            for call in calls[1 + len(started):]:
                call()
        finally:
            errors = []
            for w in started:
                try:
                    w.wait()
                except BaseException as error:  # noqa: BLE001
                    errors.append(error)
        if errors:
            raise errors[0]


def line_slabs(box, dims, threads: int) -> list:
    """A box of lines (core/lines.py: its Lines struct and launch dims) as the slabs of one launch on
    the CPU's threads: one a thread when it holds SPLIT_CELLS or more cells or faces, else itself."""
    if line_slab_count(box, dims, threads) > 1:
        return split_lines(box, dims, threads)
    return [(box, dims)]


def line_slab_count(box, dims, threads: int) -> int:
    """How many slabs line_slabs cuts the box into."""
    if threads > 1 and math.prod(dims) * box.length >= SPLIT_CELLS:
        return len(slab_planes(dims[0], threads))
    return 1


def split(lo: int, hi: int, parts: int) -> list[int]:
    """parts + 1 boundaries from lo to hi, as even as whole numbers allow."""
    return [lo + (hi - lo) * q // parts for q in range(parts + 1)]
