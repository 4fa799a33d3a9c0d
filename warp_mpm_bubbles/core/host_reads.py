"""Counting the host's reads of device data (docs/host_syncs.md).

On a GPU every read of a device array (``.numpy()``, ``.list()``) and every ``wp.synchronize*``
waits for the device to drain: a host round trip. `HostReads` counts them while it is active,
by the module and function of the project code that asked (the first frame outside Warp and
outside `Simulation.read_host`). It patches Warp's entry points only inside its ``with`` block,
so it costs nothing when not counting. On the CPU device the same calls are counted, though
there they cost nothing but a view: the count is what a GPU would pay. Not seen: a `wp.copy`
into a CPU array (the step makes none) and the GPU's own implicit syncs (allocation, uploads).
"""

from __future__ import annotations

import sys
from collections import Counter

import warp as wp

_PATCHED = ("synchronize", "synchronize_device", "synchronize_stream")
_SKIP = ("read_host",)  # Simulation.read_host: charge its caller


def _caller() -> tuple[str, str]:
    frame = sys._getframe(2)
    while frame is not None:
        module = frame.f_globals.get("__name__", "")
        in_warp = module == "warp" or module.startswith("warp.")
        if not in_warp and frame.f_code.co_name not in _SKIP and module != __name__:
            return module.removeprefix("warp_mpm_bubbles."), frame.f_code.co_name
        frame = frame.f_back
    return "?", "?"


class HostReads:
    """``with HostReads() as reads: ...`` then ``reads.by_module`` ({"core.simulation": 2, ...}),
    ``reads.by_function`` ({("effects.subgrid", "convert"): 1, ...}), ``reads.total``, and
    ``reads.elements`` (array elements read, by module: what a read carries)."""

    def __init__(self):
        self.by_function: Counter[tuple[str, str]] = Counter()
        self.elements: Counter[str] = Counter()
        self._saved = {}

    @property
    def by_module(self) -> Counter[str]:
        out: Counter[str] = Counter()
        for (module, _), n in self.by_function.items():
            out[module] += n
        return out

    @property
    def total(self) -> int:
        return sum(self.by_function.values())

    def _count(self, size: int = 0):
        where = _caller()
        self.by_function[where] += 1
        self.elements[where[0]] += size

    def __enter__(self):
        array = wp.array  # the class: patched for every instance
        numpy, to_list = array.numpy, array.list
        reads = self

        def counted_numpy(arr, *args, **kwargs):
            if not reads._in_list:
                reads._count(arr.size)
            return numpy(arr, *args, **kwargs)

        def counted_list(arr, *args, **kwargs):
            reads._count(arr.size)
            reads._in_list = True  # list() reads through numpy(): one read, not two
            try:
                return to_list(arr, *args, **kwargs)
            finally:
                reads._in_list = False

        self._in_list = False
        self._saved = {"numpy": numpy, "list": to_list}
        array.numpy, array.list = counted_numpy, counted_list
        for name in _PATCHED:
            original = getattr(wp, name)
            self._saved[name] = original

            def counted(*args, _original=original, **kwargs):
                reads._count()
                return _original(*args, **kwargs)

            setattr(wp, name, counted)
        return self

    def __exit__(self, *exc):
        array = wp.array  # the class: patched for every instance
        array.numpy, array.list = self._saved.pop("numpy"), self._saved.pop("list")
        for name, original in self._saved.items():
            setattr(wp, name, original)
        self._saved = {}
        return False
