"""Kernel launches: every launch of the step goes through one `Launcher`, so `launches` proves what
ran, and the CPU's threads share the work where a kernel's result does not depend on the split
(core/threads.py). The simulation and the stages (through their step context) launch with it.
"""

from __future__ import annotations

import math
from collections import Counter

import warp as wp

from . import threads
from .lines import Lines, set_slab, slab_planes
from .threads import Parallel, line_slabs, split


def launch_key(value):
    """A hashable stand-in for a launch argument, equal for two arguments that pack the same: an
    array by its address, shape and type, a struct by its fields, a vector or scalar by its value."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if wp.types.is_array(value):
        return ("array", value.ptr, value.shape, value.dtype)
    if isinstance(value, (list, tuple)):
        return tuple(launch_key(v) for v in value)
    fields = getattr(getattr(value, "_cls", None), "vars", None)
    if fields is not None:  # a wp.struct
        return (type(value).__name__, *(launch_key(getattr(value, name)) for name in fields))
    if hasattr(value, "value"):  # a Warp scalar (wp.float64(...))
        return (type(value).__name__, value.value)
    return (type(value).__name__, tuple(value))  # a Warp vector


class Recorded:
    """Recorded launches (`wp.launch(..., record_cmd=True)`) kept while what they were recorded for
    stays the same, and replayed: recording packs every argument in Python, as costly as a launch
    (about 15 us against 2.5 us for a replay), and a solve whose arrays did not change since the last
    step would record the same launches again. `keep(key)` starts over when the key (the arrays, the
    settings the launches bake in) differs from the last one's. A batch recorded with a `move` is
    re-targeted by `move()` when the box it walks moved (the falling block of the peer benchmark
    moves the fluid's box every step): its launches walk the box through `Slabs`, whose structs move
    in place, and `move` sets what else depends on the box (a count of planes)."""

    def __init__(self):
        self.key, self.batches, self.movers = None, {}, []

    def keep(self, *context, box=None) -> bool:
        """Keep the batches if the key is the last one's (True), else drop them (False). `box`: the box
        the batches walk, part of the key only where moving in place does not reach recorded launches
        (a Warp whose recorded launch copies its struct arguments, `record`): then a moved box records
        them again, as it did before they could be moved."""
        if not _structs_by_reference and box is not None:
            context = (*context, box)
        key = launch_key(context)
        if key == self.key:
            return True
        self.key, self.batches, self.movers = key, {}, []
        return False

    def get(self, tag, record, move=None):
        """The batch recorded under `tag` since the last change of key, else `record()`'s; `move(batch)`
        is called by every later `move()`."""
        batch = self.batches.get(tag)
        if batch is None:
            batch = self.batches[tag] = record()
            if move is not None:
                self.movers.append((move, batch))
        return batch

    def move(self):
        """Re-target every kept batch that was recorded with a `move` to the box as it is now."""
        for move, batch in self.movers:
            move(batch)


class Slabs:
    """The slabs of a box that moves (`split_lines`), as `Lines` structs kept from solve to solve, and the
    recorded launches that walk them. Warp packs a struct argument of a recorded launch as a reference
    to the struct's ctypes (`record` checks it), and copies it into the kernel's arguments at every
    replay; so `move` re-targets every launch recorded here by writing the new slabs into the same
    structs, and sets the dims of the launches whose slab's extent changed (`Launch.set_dim`, about
    3 us, against about 15 us to record the launch again). The number of slabs is fixed: a box that
    splits into another number needs new Slabs (and new recordings)."""

    def __init__(self, count: int):
        self.walks = [Lines() for _ in range(count)]
        self.dims = [None] * count
        self.launches = [[] for _ in range(count)]

    def move(self, box: Lines, dims):
        """The slabs of box (walked with launch dims `dims`), in the same structs."""
        planes = slab_planes(dims[0], len(self.walks))
        if len(planes) != len(self.walks):
            raise ValueError(f"a box of {dims[0]} planes makes {len(planes)} slabs, not {len(self.walks)}")
        for q, (a, b) in enumerate(planes):
            set_slab(self.walks[q], box, a, b)
            d = (b - a, *dims[1:])
            if d != self.dims[q]:
                self.dims[q] = d
                for launch in self.launches[q]:
                    launch.set_dim(d)

    def record(self, kernel, inputs, device) -> list:
        """A batch of recorded launches of `kernel`, one a slab, with arguments inputs(walk)."""
        batch = []
        for walk, d, launches in zip(self.walks, self.dims, self.launches):
            launch = record(kernel, d, inputs(walk), device)
            launches.append(launch)
            batch.append(launch)
        return batch


def record(kernel, dims, inputs, device):
    """`wp.launch(..., record_cmd=True)`, checking that the recorded launch holds its struct arguments
    by reference, so that a struct written in place (a moved box, core/launch.Slabs) moves the launch:
    true of Warp 1.19, whose recorded launch keeps each struct's own ctypes."""
    global _structs_by_reference
    launch = wp.launch(kernel, dims, inputs=inputs, device=device, record_cmd=True)
    for value in inputs:
        if wp.types.is_struct(value) and not any(p is value.__ctype__() for p in launch.params):
            _structs_by_reference = False  # from now on a moved box records again (Recorded.keep)
    return launch


# Whether recorded launches hold their struct arguments by reference (true of Warp 1.19; `record`
# turns it off for good the first time a launch holds a copy, and the results stay right, only slower).
_structs_by_reference = True


class Launcher:
    """The launch helpers, on one device with the CPU's threads (`parallel`). `particles`: the
    particle state whose count sets a per-particle launch; `grid`: the MAC grid; `region`: the grid
    stages' box (core/active_box.py), the default box of a splat (set once the simulation built it)."""

    def __init__(self, device, parallel: Parallel, grid, particles, region=None):
        self.device, self.parallel, self.grid, self.particles, self.region = device, parallel, grid, particles, region
        self.launches: Counter[str] = Counter()  # kernel launches by name: proof of what ran
        self._loaded: set = set()  # kernels launched once already (launch_parts)

    @property
    def threads(self) -> int:
        return self.parallel.threads

    def launch(self, kernel, dim, inputs):
        """Every kernel launch goes through here, so `launches` proves what ran."""
        self.launches[kernel.key] += 1
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device)

    def launch_splat(self, kernel, inputs, region=None):
        """Launch a particle-to-grid kernel over every particle, its last two arguments the slab
        [x_lo, x_hi) of grid nodes along x it writes: one slab a thread on the CPU, cut evenly across
        the region's nodes (faces: one more than cells), the first and last reaching the arrays' ends
        so every node belongs to some part. Each part visits the particles in index order, so every
        node sums them in that order whatever the split (core/threads.py)."""
        r = region or self.region
        cuts = split(r.box[0][0], r.box[1][0] + 1, self.threads)
        cuts[0], cuts[-1] = 0, self.grid.face_shape(0)[0]
        self.launch_parts(kernel, [(self.particles.count, [*inputs, a, b]) for a, b in zip(cuts, cuts[1:])])

    def launch_lines(self, kernel, lines, inputs):
        """Launch a kernel that walks a box of cells or faces, a line per thread (core/lines.py), and
        writes only what it walks: lines = (Lines, dims), the Lines struct its first argument. A box of
        SPLIT_CELLS or more runs in slabs on the CPU's threads, with the same result."""
        slabs = line_slabs(*lines, self.threads)
        if len(slabs) == 1:
            self.launch(kernel, slabs[0][1], [slabs[0][0], *inputs])
        else:
            self.launch_parts(kernel, [(d, [slab, *inputs]) for slab, d in slabs])

    def launch_particles(self, kernel, inputs):
        """Launch a per-particle kernel whose first argument is the index of its first particle and
        which writes only its own particles' values: in ranges at once on the CPU's threads (no
        particle's result depends on the split), one launch for few particles or one thread."""
        n = self.particles.count
        if n == 0:
            return
        cuts = split(0, n, self.threads if n >= threads.SPLIT_PARTICLES else 1)
        self.launch_parts(kernel, [(b - a, [a, *inputs]) for a, b in zip(cuts, cuts[1:]) if b > a])

    def launch_box(self, kernel, lo, dims, inputs):
        """Launch a kernel over the box of `dims` cells or faces from `lo` (its last argument: the offset
        of its thread index) that writes only what it is launched on: in slabs along x at once on the
        CPU's threads when the box holds SPLIT_CELLS or more."""
        cuts = split(0, dims[0], self.threads if math.prod(dims) >= threads.SPLIT_CELLS else 1)
        self.launch_parts(kernel, [((b - a, *dims[1:]), [*inputs, wp.vec3i(lo[0] + a, lo[1], lo[2])])
                                   for a, b in zip(cuts, cuts[1:]) if b > a])

    def launch_parts(self, kernel, parts):
        """Launch `kernel` once per (dim, inputs) part, the parts at once on the CPU's threads (but the
        first time one after the other: the first launch compiles or loads the kernel's module, which
        must happen once, on one thread)."""
        self.launches[kernel.key] += len(parts)
        calls = [lambda d=d, inputs=inputs: wp.launch(kernel, dim=d, inputs=inputs, device=self.device)
                 for d, inputs in parts]
        if kernel in self._loaded:
            self.parallel.run(calls)
        elif calls:  # (no part: an empty box, nothing loaded yet)
            for call in calls:
                call()
            self._loaded.add(kernel)
