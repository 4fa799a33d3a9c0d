"""The simulation's state, apart from the stepper: particle arrays and grid fields on one device.

`ParticleState` holds one array per particle field, all of the same capacity, the first `count`
in use. Every scene has the fields of PARTICLE_FIELDS; a stage adds its own with `add_field`
(foam lifetimes, sub-grid drag impulses), and those grow, compact, sort and checkpoint with the rest.
`sort_by_cell` orders the particles by the cell they are in (the step does it every few steps), so
the transfers read and add to the grid in memory order; `ids` moves with the rest, and `sort_by_id`
puts them back in the order they were added (Simulation.advance_to does, before it returns).

`GridFields` holds the MAC grid's face and cell arrays, rebuilt by every step (only `pressure`,
the solver's warm start, and the ledgers `vented_mass` and `outflow_mass` carry over and are checkpointed). A
stage that needs a grid array of its own allocates it in its constructor; gas arrays are one-cell
placeholders until the gas stage replaces them (the core kernels take them as arguments either way).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .boundary import finite
from .geometry import GridGeometry
from .grid import ACTIVE
from .threads import CACHE_LINE_FLOATS

# The per-particle arrays every scene has: position (m), velocity (m/s), APIC affine matrix (1/s),
# mass (kg), rest volume (m^3), J = volume / rest volume, grid.PHASE_*, 1 while simulated (0:
# retired), index into scene.materials, gas law code and adiabatic exponent, stable id.
PARTICLE_FIELDS = {"x": wp.vec3, "v": wp.vec3, "C": wp.mat33, "mass": float, "vol0": float, "J": float,
                   "phase": wp.int32, "active": wp.int32, "material": wp.int32, "gas_law": wp.int32,
                   "gas_gamma": float, "ids": wp.int64}
GRID_CHECKPOINT = ("pressure", "vented_mass", "outflow_mass", "correction_potential")  # what a step reads from the previous one


@wp.kernel(enable_backward=False)
def cell_keys(x: wp.array(dtype=wp.vec3), active: wp.array(dtype=wp.int32), geo: GridGeometry, cells: wp.vec3i,
              keys: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32)):
    """Sort key of each particle: its cell's linear index (z fastest, as the grid arrays are laid
    out); retired particles and non-finite positions sort last (p2g reports the latter)."""
    p = wp.tid()
    order[p] = p
    xp = x[p]
    if active[p] != ACTIVE or not finite(xp):
        keys[p] = cells[0] * cells[1] * cells[2]
        return
    c = (xp - geo.origin) / geo.dx
    i = wp.clamp(int(wp.floor(c[0])), 0, cells[0] - 1)
    j = wp.clamp(int(wp.floor(c[1])), 0, cells[1] - 1)
    k = wp.clamp(int(wp.floor(c[2])), 0, cells[2] - 1)
    keys[p] = (i * cells[1] + j) * cells[2] + k


@wp.kernel(enable_backward=False)
def id_keys(ids: wp.array(dtype=wp.int64), keys: wp.array(dtype=wp.int64), order: wp.array(dtype=wp.int32)):
    p = wp.tid()
    order[p] = p
    keys[p] = ids[p]


@wp.kernel(enable_backward=False)
def gather_rows(src: wp.array2d(dtype=wp.uint32), order: wp.array(dtype=wp.int32), dst: wp.array2d(dtype=wp.uint32)):
    """dst[p] = src[order[p]]: a particle's value as 32-bit words (any field type)."""
    p = wp.tid()
    q = order[p]
    for w in range(src.shape[1]):
        dst[p, w] = src[q, w]


def _words(arr, n: int):
    """The first n elements of a contiguous particle array seen as rows of 32-bit words."""
    size = wp.types.type_size_in_bytes(arr.dtype)
    if size % 4:
        raise TypeError(f"particle field dtype {arr.dtype} is not a whole number of 32-bit words; sort_by_cell "
                        "cannot move it (use a 32- or 64-bit type)")
    return wp.array(ptr=arr.ptr, dtype=wp.uint32, shape=(n, size // 4), device=arr.device)


class ParticleState:
    """Particle arrays on `device`; `count` of them in use, the arrays hold capacity >= that."""

    def __init__(self, device):
        self.device = device
        self.count = 0
        self._sort_keys = self._sort_order = self._sort_scratch = None  # the sorts' buffers
        self.in_id_order = True  # as appended and compacted; False after sort_by_cell
        self.fields = dict(PARTICLE_FIELDS)
        for name, dtype in self.fields.items():
            setattr(self, name, wp.zeros(0, dtype=dtype, device=device))

    @property
    def capacity(self) -> int:
        return len(self.x)

    def add_field(self, name: str, dtype):
        """A per-particle array for a stage (zero for existing particles)."""
        self.fields[name] = dtype
        setattr(self, name, wp.zeros(self.capacity, dtype=dtype, device=self.device))

    def reserve(self, n: int):
        """Room for n particles; arrays grow geometrically, keeping the ones in use."""
        capacity = self.capacity
        if n <= capacity:
            return
        capacity = n if capacity == 0 else max(n, 2 * capacity)
        for name, dtype in self.fields.items():
            new = wp.zeros(capacity, dtype=dtype, device=self.device)
            if self.count:
                wp.copy(new, getattr(self, name), count=self.count)
            setattr(self, name, new)

    def append(self, values: dict[str, np.ndarray], n: int) -> slice:
        """Append n particles; `values` maps field names to numpy arrays (missing fields stay 0)."""
        start = self.count
        self.reserve(start + n)
        for name, dtype in self.fields.items():
            if name in values and n:
                src = wp.array(np.asarray(values[name]), dtype=dtype, device=self.device)
                wp.copy(getattr(self, name), src, dest_offset=start, count=n)
        self.count = start + n
        return slice(start, start + n)

    def compact(self, keep: np.ndarray):
        """Keep only the particles at these indices, in their order (so every kernel's sums run in
        the same order and results stay the same bit for bit)."""
        for name, dtype in self.fields.items():
            data = getattr(self, name).numpy()[: self.count][keep]
            compacted = wp.zeros(self.capacity, dtype=dtype, device=self.device)
            if len(keep):
                wp.copy(compacted, wp.array(data, dtype=dtype, device=self.device), count=len(keep))
            setattr(self, name, compacted)
        self.count = len(keep)

    def sort_by_cell(self, geometry, cells, launch=None):
        """Reorder every field (stages' fields included) by cell, in place (the arrays stay the same
        objects). Warp's radix sort is stable, so particles in one cell keep their order and the
        result is the same on every run; it changes the order of the transfers' float sums only.
        `launch(kernel, dim, inputs)` runs the kernels (Simulation.launch counts them)."""
        n, launch = self.count, self._launcher(launch)
        if n == 0:
            return
        keys, order = self._sort_buffers(n, wp.int32)
        cells = wp.vec3i(*cells)
        launch(cell_keys, n, [self.x, self.active, geometry, cells, keys, order])
        wp.utils.radix_sort_pairs(keys, order, n, end_bit=max(1, int(cells[0] * cells[1] * cells[2]).bit_length()))
        self._permute(order, n, launch)
        self.in_id_order = False

    def sort_by_id(self, max_id: int, launch=None):
        """Back to id order (ids below max_id): the order appends and compaction keep, so between
        frames the arrays are laid out as if they had never been sorted."""
        n, launch = self.count, self._launcher(launch)
        if n:
            keys, order = self._sort_buffers(n, wp.int64)
            launch(id_keys, n, [self.ids, keys, order])
            wp.utils.radix_sort_pairs(keys, order, n, end_bit=max(1, int(max_id).bit_length()))
            self._permute(order, n, launch)
        self.in_id_order = True

    def _launcher(self, launch):
        return launch or (lambda k, dim, inputs: wp.launch(k, dim=dim, inputs=inputs, device=self.device))

    def _sort_buffers(self, n: int, key_dtype):
        """Keys and values for the radix sort (it needs room for 2n), and the gather's scratch."""
        words = max(wp.types.type_size_in_bytes(d) for d in self.fields.values()) // 4
        if self._sort_order is None or len(self._sort_order) < 2 * n or len(self._sort_scratch) < n * words:
            self._sort_keys = {}
            self._sort_order = wp.zeros(2 * self.capacity, dtype=wp.int32, device=self.device)
            self._sort_scratch = wp.zeros(self.capacity * words, dtype=wp.uint32, device=self.device)
        if key_dtype not in self._sort_keys:
            self._sort_keys[key_dtype] = wp.zeros(len(self._sort_order), dtype=key_dtype, device=self.device)
        return self._sort_keys[key_dtype], self._sort_order

    def _permute(self, order, n: int, launch):
        """field[p] = field[order[p]] for every field, through the scratch buffer."""
        for name in self.fields:
            field = _words(getattr(self, name), n)
            scratch = wp.array(ptr=self._sort_scratch.ptr, dtype=wp.uint32, shape=field.shape, device=self.device)
            launch(gather_rows, n, [field, order, scratch])
            wp.copy(field, scratch)

    def numpy(self, name: str) -> np.ndarray:
        """The in-use part of one field (a view on the CPU device: the next step changes it)."""
        return getattr(self, name).numpy()[: self.count]


class GridFields:
    """The grid arrays of one MacGrid on `device` (see the module docstring)."""

    def __init__(self, grid, device, parts: int = 1):
        self.grid, self.device = grid, device
        faces, cells = self.faces, self.cells
        self.mom, self.face_mass, self.vel, self.inv_rho = faces(), faces(), faces(), faces()
        self.vel_tmp, self.valid, self.valid_tmp = faces(), faces(wp.int32), faces(wp.int32)
        self.liq_mass, self.liq_volume = cells(), cells()
        # p2g adds (momentum, mass) per face and (mass, volume) per cell as pairs, then splits them.
        self.face_pairs, self.cell_pairs = faces(wp.vec2), cells(wp.vec2)
        self.cell_count, self.types, self.phase_cells = cells(wp.int32), cells(wp.int32), cells(wp.int32)
        self.pressure, self.diag, self.rhs = cells(), cells(), cells()
        self.extra_diag = cells()  # kappa/dt^2 of gas cells
        # Gas state per cell: one-cell placeholders that no kernel reads until the gas stage
        # allocates them (physics/gas.py).
        placeholder = self.placeholder
        self.gas_mass, self.gas_volume, self.gas_pv, self.gas_kv = (placeholder() for _ in range(4))
        self.gas_count = placeholder(wp.int32)
        self.target_div, self.gas_rate = placeholder(), placeholder()
        self.correction_rhs = placeholder()
        self.correction_potential = placeholder()
        self.enclosed_cells = placeholder(wp.int32)  # the smoothed fill's (core/grid_kernels.mark_enclosed)
        self.ceiling = placeholder(wp.int32)
        self.gas_vel = self.gas_valid = None  # the gas's own face field (sharp interface, own liquid field)
        # fluid cells, pinned cells (pressure_diagonal_and_rhs), then a copy of nonfinite: one read.
        # One such group a cache line apart per part of the assembly (core/threads.py), added on the host.
        self.counters = wp.zeros(parts * CACHE_LINE_FLOATS, dtype=wp.int32, device=device)
        # The step's one read-back: [0] fastest particle this step, [1] bubbles entrained this step,
        # [2] the gas's largest |gauge pressure|, [3] its fastest volume change rate, [4] whether a
        # cavity may exist next step (physics/gas.py)
        self.max_speed = wp.zeros(5, dtype=float, device=device)
        self.nonfinite = wp.zeros(1, dtype=wp.int32, device=device)  # particles p2g refused this step
        self.vented_mass = wp.zeros(1, dtype=wp.float64, device=device)  # kg of gas gone to the air
        self.outflow_mass = wp.zeros(4, dtype=wp.float64, device=device)  # kg gone through open walls, by PHASE_*

    def faces(self, dtype=float) -> list:
        """One array per simulated axis' faces (three in 2D too: the w faces are never read)."""
        return [wp.zeros(self.grid.face_shape(a), dtype=dtype, device=self.device) for a in range(3)]

    def cells(self, dtype=float):
        return wp.zeros(self.grid.cells, dtype=dtype, device=self.device)

    def placeholder(self, dtype=float):
        return wp.zeros((1, 1, 1), dtype=dtype, device=self.device)
