"""The box of the grid that the step's grid phases cover (cost in proportion to the liquid, not the domain).

After p2g, one kernel takes the bounding box of the cells that hold an active particle; the host
reads it (6 ints, the step's one read for it) to size the grid phases' launches. Every grid value
that the particles influence lies within BOX_MARGIN cells of that box: the splat reaches 2 cells,
the hole-filling fluid classification 1 more, the projection trusts the faces of fluid cells and
extrapolation adds EXTRAPOLATION_LAYERS layers, and each kernel reads one neighbour further. Outside
it every grid array holds its empty-state value (no mass, EMPTY or wall cells, zero velocity and
pressure, nothing valid), which depends on nothing that changes in time.

The launches cover this step's box united with the previous step's, so the cells that the liquid
just left are reset to the empty state, and cells outside both were last written while outside the
box, i.e. already hold it. The grid arrays therefore equal those of whole-grid launches bit for bit
(tests/test_active_region.py). Scenes whose optional stages write grid arrays at the grid hooks keep
whole-grid launches (`Simulation` decides), since their kernels may write anywhere, unless each such
stage is box-aware (`Stage.grid_box`: gas, surface tension).

The same read brings the box of the resolved gas's particles (`ActiveRegion.gas`, with the same
margin, no union): the gas's own velocity field and its cells' volume change are read only by gas
particles and gas cells, so the gas computes them on that box alone (physics/gas.py). Outside it
they keep stale values, which nothing reads. A step where the void pass seeds trapped air reads the
boxes again (`update(again=True)`) before it splats again; should the second pass seed more, `gas_box`
is the whole grid.
"""

from __future__ import annotations

import warp as wp

from .grid import ACTIVE, PHASE_GAS
from .lines import make_lines
from .threads import CACHE_LINE_FLOATS, Parallel, split

wp.set_module_options({"enable_backward": False})

BOX_MARGIN = 4  # cells around the particles' cells: 3 needed (docstring), 1 spare


@wp.kernel
def reset_bounds(box: wp.array(dtype=wp.int32), stride: int):
    """Bounds of nothing: in each group of `stride` values, (big, big, big, -1, -1, -1) repeated."""
    t = wp.tid()
    if (t % stride) % 6 < 3:
        box[t] = 2147483647
    else:
        box[t] = -1


@wp.kernel
def particle_cell_bounds(x: wp.array(dtype=wp.vec3), active: wp.array(dtype=wp.int32), phase: wp.array(dtype=wp.int32),
                         origin: wp.vec3, inv_dx: float, shape: wp.vec3i, first: int, box: wp.array(dtype=wp.int32),
                         slot: int):
    """Over particles first + tid: box[slot + 0:3], box[slot + 3:6] = smallest and largest cell
    (clamped to the arrays) of an active particle; box[slot + 6:12] the same of the resolved gas's
    (PHASE_GAS) particles."""
    p = wp.tid() + first
    if active[p] != ACTIVE:
        return
    gas = phase[p] == PHASE_GAS
    for a in range(3):
        c = wp.clamp(int(wp.floor((x[p][a] - origin[a]) * inv_dx)), 0, shape[a] - 1)
        wp.atomic_min(box, slot + a, c)
        wp.atomic_max(box, slot + 3 + a, c)
        if gas:
            wp.atomic_min(box, slot + 6 + a, c)
            wp.atomic_max(box, slot + 9 + a, c)


def union(a, b):
    if a[0] == a[1]:
        return b
    if b[0] == b[1]:
        return a
    return (tuple(map(min, a[0], b[0])), tuple(map(max, a[1], b[1])))


class LaunchBox:
    """A box of cells to launch over: `lo` (wp.vec3i, the kernels' offset), `cells` and `faces(axis)` the
    launch dims; `cell_lines` and `face_lines[axis]` the same box walked a line per thread
    (core/lines.py: a Lines struct and its launch dims)."""

    def __init__(self, shape, device):
        self.shape, self.device = tuple(shape), device
        self.dim = 2 if self.shape[2] == 1 else 3  # a 2D grid is one cell thick in z
        self._set(((0, 0, 0), self.shape))

    def _set(self, box):
        self.box = box
        self.lo = wp.vec3i(*box[0])
        self.cells = tuple(h - l for l, h in zip(*box))  # noqa: E741
        self.cell_lines = make_lines(*box, self.dim, self.device)
        self.face_lines = [make_lines(box[0], tuple(h + (a == b) * (h > l) for b, (l, h) in enumerate(zip(*box))),
                                      self.dim, self.device) for a in range(3)]

    def faces(self, axis: int) -> tuple[int, int, int]:
        """Launch dims over the faces normal to `axis` of the box's cells (one more along axis)."""
        if 0 in self.cells:
            return self.cells
        return tuple(n + (a == axis) for a, n in enumerate(self.cells))


class ActiveRegion(LaunchBox):
    """The grid phases' launch box, and `gas`, the resolved gas's (this step's gas particles' cells and
    the margin, no union: what the gas writes there it rewrites every step). Disabled (`enabled=False`):
    both are the whole grid, and `update` reads nothing."""

    def __init__(self, grid, device, enabled: bool = True, margin: int = BOX_MARGIN, parallel: Parallel | None = None):
        super().__init__(grid.cells, device)
        self.enabled, self.margin = enabled, margin
        self.origin, self.inv_dx = wp.vec3(*grid.origin), 1.0 / grid.dx
        self.parallel = parallel or Parallel(1)  # ranges of particles, each with its own 12 bounds
        self.bounds = wp.zeros(CACHE_LINE_FLOATS * self.parallel.threads, dtype=wp.int32, device=device)
        self.previous = ((0, 0, 0), self.shape)  # the first step covers the whole grid
        self._before = self.previous  # the previous step's box while this step's is read (update(again=True))
        self.host_reads = 0
        self.particle_count = 0  # the particles the boxes were taken from (later ones may lie outside)
        self.gas, self.whole = LaunchBox(self.shape, device), LaunchBox(self.shape, device)

    def whole_grid(self):
        """From now on the whole grid (a captured CUDA graph cannot read the box on the host)."""
        self.enabled = False
        self.previous = ((0, 0, 0), self.shape)
        self._set(self.previous)
        self.gas._set(self.previous)

    def gas_box(self, particles) -> LaunchBox:
        """The gas's box; the whole grid if particles were added since the boxes were read (trapped air
        that the void pass seeds may lie outside both boxes, where older gas left its values)."""
        return self.gas if particles.count == self.particle_count else self.whole

    def _grown(self, b):
        """The box of cells from bounds b (smallest, largest cell) with the margin, clamped; empty if none."""
        if b[3] < 0:  # no particle
            return ((0, 0, 0), (0, 0, 0))
        return (tuple(max(int(b[a]) - self.margin, 0) for a in range(3)),
                tuple(min(int(b[3 + a]) + 1 + self.margin, self.shape[a]) for a in range(3)))

    def update(self, particles, again: bool = False):
        """This step's box from the particles (before p2g, which splats within it), united with the previous step's.
        again: the same step's box once more, after particles were added to it (trapped air that the
        void pass seeded: Simulation.step splats again), still united with the previous step's."""
        if not self.enabled:
            return
        if again:
            self.previous = self._before
        self._before = self.previous
        self.particle_count = particles.count
        wp.launch(reset_bounds, self.bounds.shape[0], inputs=[self.bounds, CACHE_LINE_FLOATS], device=self.device)
        args = [particles.x, particles.active, particles.phase, self.origin, self.inv_dx, wp.vec3i(*self.shape)]
        cuts = split(0, particles.count, self.parallel.threads)
        calls = [lambda a=a, n=b - a, q=q: wp.launch(particle_cell_bounds, n, device=self.device,
                                                      inputs=[*args, a, self.bounds, CACHE_LINE_FLOATS * q])
                 for q, (a, b) in enumerate(zip(cuts, cuts[1:])) if b > a]
        if calls:
            self.parallel.run(calls)
        parts = self.bounds.numpy().reshape(-1, CACHE_LINE_FLOATS)[:, :12]  # minima and maxima: exact in any order
        self.host_reads += 1
        b = parts.max(axis=0)
        for lo in (0, 6):
            b[lo:lo + 3] = parts[:, lo:lo + 3].min(axis=0)
        current = self._grown(b[:6])
        self._set(union(current, self.previous))
        self.gas._set(self._grown(b[6:]))
        self.previous = current
