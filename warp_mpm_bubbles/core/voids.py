"""Voids: particle-free cells inside the liquid (docs/design.md, "Voids").

`classify_cells` calls a cell with no particle and a fill fraction under HOLE_FRACTION EMPTY, which
the solve reads as a free surface at p = 0. That is right above the water and wrong inside it: an
EMPTY cell under water pins the pressure to the atmosphere's there, so nothing pushes the water back
in and the hole stays (a filled tank grew 17-56 of them around a rising bubble at 32-64 cells across).

After the cells are classified (and colliders have marked theirs), `VoidPass.apply`:

1. counts, on the device, EMPTY interior cells that have a fluid or solid cell above them in their
   column (against gravity; without gravity every EMPTY interior cell), and their box. Open air
   above a free surface has none, so a calm scene reads these 7 ints and stops here.
2. otherwise finds the voids by the rule diagnostics.void_cells counts by (grid.closed_empty_cells:
   a face-connected EMPTY region is open air if it reaches an open wall, an EMPTY ghost cell, or the
   domain's top layer; without gravity any side; every other EMPTY cell is a void). The device
   marks what is open by position in that box, carries it along lines of EMPTY cells and counts the
   EMPTY cells it did not reach (VoidSearch; a second scalar read; labelling every EMPTY cell on the host cost 60 ms a step
   under a falling 32^3 block). Only if some are left does the host read the types (one int32 per
   cell) and label those cells' regions (grid.connected_labels).
3. makes each void of a region under POCKET_CELLS cells a fluid cell of the phase its volumes say
   (liquid as a rule). Its rest-volume fraction is about 0, so the volume correction asks it to
   contract by its full deficit and the pressure closes it (grid_kernels.pressure_diagonal_and_rhs
   counts a near-empty cell with no gas and no EMPTY neighbour as enclosed). With compressible gas,
   a void beside the gas stays EMPTY, as before (filled, a merging film was thrown at 3.4 m/s).
4. does not close a larger region by its deficit (that is violent: the pour's glass once sealed
   379 cells of air under a sheet, and the water was thrown at 400 m/s). In a scene with gas, one
   that touches no gas is air a splash closed over: it is seeded with gas at the ambient pressure
   (`seeded`), and Simulation.step splats and classifies again, so the same step's solve sees the
   pocket as gas cells, a resolved bubble, never as EMPTY at p = 0 inside the liquid (the pour's 90
   frames: at most 1,045 void cells at one step before, none after). The mass is booked as taken
   from the atmosphere (`VoidPass.state`, checkpointed as "gas_mass_trapped", so Simulation.gas_budget's total stays
   exact). One beside gas is the space the gas just left (a burst's vented cavity), not trapped
   air. Without gas, or beside incompressible gas, a large region stays EMPTY.

Every step, on the device (`clear_holes`), in scenes without gas: a fluid cell with no particle and
no EMPTY neighbour (a void made liquid above) holds nothing, whatever its neighbours' B-splines
splat into it; it becomes a liquid cell with a trace of liquid, so its full deficit counts. With
compressible gas the gas expands into such gaps itself, and closing them by the deficit broke a
rising air bubble up; with incompressible gas the volume correction closes them by their own total
fill, liquid and gas as one medium (see VoidPass.__init__).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from .grid import EMPTY, FLUID, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID, connected_labels
from .cells import cell_type_at
from . import kernel_args
from .host_state import HostState, saved
from .kernel_args import Splat
from .lines import Lines, line_end, line_first, make_lines, on_line
from . import threads as threads_mod

wp.set_module_options({"enable_backward": False})

POCKET_CELLS = 4  # a void region this large is air, not a gap: trapped air with gas, else left EMPTY
# Passes of line sweeps over the axes before the host searches what they left: one reaches the air
# under a falling block or a splash sheet (along its rows), two an L-shaped pocket's far arm.
SWEEP_ROUNDS = 2
VOID_FILL = wp.constant(1.0e-6)  # rest-volume fraction written into a void with none: keeps its faces' density defined


@wp.kernel
def covered_top(box: Lines, types: wp.array3d(dtype=wp.int32), up_axis: int, up_sign: int, ghost: wp.vec3i,
                top: wp.array3d(dtype=wp.int32)):
    """Per column along gravity, the height of the highest interior cell of the box that is not EMPTY
    (-1: none)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if is_interior(types, ghost, c) and types[c[0], c[1], c[2]] != EMPTY:
            col = c
            col[up_axis] = 0
            wp.atomic_max(top, col[0], col[1], col[2], height(types, up_axis, up_sign, c))


@wp.kernel
def count_covered_empty(box: Lines, types: wp.array3d(dtype=wp.int32), top: wp.array3d(dtype=wp.int32),
                        up_axis: int, up_sign: int, ghost: wp.vec3i, covered: wp.array(dtype=wp.int32)):
    """EMPTY interior cells of the box below a fluid or solid cell of their column: the only ones that
    can be voids (with gravity; up_axis < 0 counts every EMPTY interior cell). covered: their count,
    then the lowest and highest index of them on each axis (the box the search below needs)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if is_interior(types, ghost, c) and types[c[0], c[1], c[2]] == EMPTY:
            if is_covered(types, top, up_axis, up_sign, c):
                wp.atomic_add(covered, 0, 1)
                for a in range(3):
                    wp.atomic_min(covered, 1 + a, c[a])
                    wp.atomic_max(covered, 4 + a, c[a])


@wp.func
def is_interior(types: wp.array3d(dtype=wp.int32), ghost: wp.vec3i, c: wp.vec3i):
    for a in range(3):
        if c[a] < ghost[a] or c[a] >= types.shape[a] - ghost[a]:
            return False
    return True


@wp.func
def height(types: wp.array3d(dtype=wp.int32), up_axis: int, up_sign: int, c: wp.vec3i):
    """Cell c's index along gravity, counted upwards."""
    h = c[up_axis]
    if up_sign < 0:
        h = types.shape[up_axis] - 1 - h
    return h


@wp.func
def is_covered(types: wp.array3d(dtype=wp.int32), top: wp.array3d(dtype=wp.int32), up_axis: int, up_sign: int,
               c: wp.vec3i):
    """A fluid or solid cell lies above c in its column (without gravity: every cell counts as covered)."""
    if up_axis < 0:
        return True
    col = c
    col[up_axis] = 0
    return height(types, up_axis, up_sign, c) <= top[col[0], col[1], col[2]]


@wp.kernel
def fill_voids(is_void: wp.array3d(dtype=wp.int32), rho_liquid: float, cell_volume: float, two_phase: int,
               gas_volume: wp.array3d(dtype=float), types: wp.array3d(dtype=wp.int32),
               phase: wp.array3d(dtype=wp.int32), liq_mass: wp.array3d(dtype=float),
               liq_volume: wp.array3d(dtype=float)):
    """A void becomes a fluid cell of the phase its splatted volumes say (as classify_phases): one
    that the gas around reaches more than the liquid is a gas cell the gas expands into (read as
    liquid, it made a compressible cell the liquid's field trusted, and threw gas at 2 m/s when a
    bubble burst). A liquid one with no liquid splatted at all gets a trace (VOID_FILL) of the
    liquid's density, so a face between two voids has a density and its deficit stays the full one."""
    i, j, k = wp.tid()
    if is_void[i, j, k] == 0:
        return
    types[i, j, k] = FLUID
    if two_phase != 0:
        if gas_volume[i, j, k] > liq_volume[i, j, k]:
            phase[i, j, k] = PHASE_GAS
            return
    phase[i, j, k] = PHASE_LIQUID
    if liq_volume[i, j, k] <= 0.0:
        liq_volume[i, j, k] = VOID_FILL * cell_volume
        liq_mass[i, j, k] = rho_liquid * VOID_FILL * cell_volume


@wp.kernel
def clear_holes(box: Lines, dim: int, rho_liquid: float, cell_volume: float, two_phase: int,
                count: wp.array3d(dtype=wp.int32), types: wp.array3d(dtype=wp.int32), phase: wp.array3d(dtype=wp.int32),
                splat: Splat):
    """A fluid cell with no particle and no EMPTY neighbour (a hole inside the material, a former void
    included) holds nothing: the volume its neighbours' B-splines splat into it is not there. It
    becomes a liquid cell holding a trace (VOID_FILL) of liquid, so its full volume deficit counts
    and the pressure closes it from whichever phase is around (a gap the gas leaves under a rising
    bubble would otherwise read as gas that is not there, and stay)."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        i, j, k = c[0], c[1], c[2]
        if types[i, j, k] == FLUID and count[i, j, k] == 0 and not beside_empty(types, dim, c):
            phase[i, j, k] = PHASE_LIQUID
            splat.liq_volume[i, j, k] = VOID_FILL * cell_volume
            splat.liq_mass[i, j, k] = rho_liquid * VOID_FILL * cell_volume
            if two_phase != 0:
                splat.gas_mass[i, j, k] = 0.0
                splat.gas_volume[i, j, k] = 0.0
                splat.gas_pv[i, j, k] = 0.0
                splat.gas_kv[i, j, k] = 0.0


@wp.func
def beside_empty(types: wp.array3d(dtype=wp.int32), dim: int, c: wp.vec3i):
    for a in range(dim):
        for s in range(2):
            n = c
            n[a] = n[a] + 2 * s - 1
            if cell_type_at(types, n) == EMPTY:  # an open wall's ghost cell can be fluid: stay in the array
                return True
    return False


@wp.kernel
def mark_open_air(box: Lines, types: wp.array3d(dtype=wp.int32), top: wp.array3d(dtype=wp.int32), up_axis: int,
                  up_sign: int, ghost: wp.vec3i, reached: wp.array3d(dtype=wp.int32)):
    """1 on the EMPTY cells of the box that are open air by position, 0 on the others."""
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        reached[c[0], c[1], c[2]] = 0
        if types[c[0], c[1], c[2]] == EMPTY:
            if open_by_position(types, top, up_axis, up_sign, ghost, c):
                reached[c[0], c[1], c[2]] = 1


@wp.func
def open_by_position(types: wp.array3d(dtype=wp.int32), top: wp.array3d(dtype=wp.int32), up_axis: int,
                     up_sign: int, ghost: wp.vec3i, c: wp.vec3i):
    """An EMPTY cell that is open air without a search (grid.open_air_seeds: a ghost cell, the top
    layer; without gravity the outer layer), or with nothing but EMPTY cells above it in its column
    (which reaches the top layer)."""
    if not is_interior(types, ghost, c):
        return True
    if up_axis >= 0:
        return not is_covered(types, top, up_axis, up_sign, c)
    for a in range(3):
        if ghost[a] > 0 and (c[a] == ghost[a] or c[a] == types.shape[a] - ghost[a] - 1):
            return True
    return False


@wp.func
def carry_open_air(types: wp.array3d(dtype=wp.int32), reached: wp.array3d(dtype=wp.int32), c: wp.vec3i, run: int):
    """One cell of a line sweep: whether open air carries on past it (it is EMPTY and reached)."""
    if types[c[0], c[1], c[2]] != EMPTY:
        return 0
    if reached[c[0], c[1], c[2]] != 0:
        return 1
    if run != 0:
        reached[c[0], c[1], c[2]] = 1
    return run


@wp.kernel
def sweep_open_air(lo: wp.vec3i, hi: wp.vec3i, types: wp.array3d(dtype=wp.int32), axis: int,
                   reached: wp.array3d(dtype=wp.int32)):
    """Along each line of cells parallel to `axis` within the box [lo, hi) (one thread a line), forward
    then back: an EMPTY cell face-connected along the line to a reached one is reached. One pass carries
    the open air any distance along its lines, so a few passes over the axes reach what a flood fill
    would in shapes that are not mazes; the count after them says whether any EMPTY cell is left."""
    ti, tj, tk = wp.tid()
    c = wp.vec3i(ti + lo[0], tj + lo[1], tk + lo[2])
    run = int(0)
    for s in range(lo[axis], hi[axis]):
        c[axis] = s
        run = carry_open_air(types, reached, c, run)
    run = int(0)
    for s in range(lo[axis], hi[axis]):
        c[axis] = hi[axis] - 1 - (s - lo[axis])
        run = carry_open_air(types, reached, c, run)


@wp.kernel
def count_unreached_empty(box: Lines, types: wp.array3d(dtype=wp.int32), reached: wp.array3d(dtype=wp.int32),
                          counter: wp.array(dtype=wp.int32)):
    ti, tj, tk = wp.tid()
    first = line_first(box, ti, tj, tk)
    for s in range(first[box.axis], line_end(box, first)):
        c = on_line(first, box.axis, s)
        if types[c[0], c[1], c[2]] == EMPTY and reached[c[0], c[1], c[2]] == 0:
            wp.atomic_add(counter, 0, 1)


def unreached_regions(types: np.ndarray, reached: np.ndarray, lo) -> tuple[np.ndarray, np.ndarray]:
    """The voids among the EMPTY cells the sweeps did not reach in the search box (types and reached
    cut to it, `lo` its first cell): the face-connected regions of them with no face neighbour that was
    reached (any such neighbour is open air, so its region is too). Every such cell lies inside the box
    with its neighbours (the box is the covered cells' grown by one). Returns (cells, labels) as
    grid.closed_empty_cells does, which it equals."""
    cells = np.argwhere((types == EMPTY) & (reached == 0))
    if len(cells) == 0:
        return cells, np.zeros(0, int)
    labels = connected_labels(cells, 3, faces_only=True)
    touches = np.zeros(len(cells), bool)
    for a in range(3):
        for s in (-1, 1):
            n = cells.copy()
            n[:, a] += s
            inside = (n[:, a] >= 0) & (n[:, a] < types.shape[a])
            touches[inside] |= reached[tuple(n[inside].T)] != 0
    closed = ~np.isin(labels, np.unique(labels[touches]))
    return cells[closed] + np.asarray(lo), labels[closed]


class VoidSearch:
    """Finds the voids of a cell-type array on the device, as grid.closed_empty_cells defines them;
    `launch(kernel, dim, inputs)` launches on the arrays' device. See find().

    launch_parts(kernel, [(dim, inputs), ...]), with `threads`: launches the parts of one sweep at once
    on the CPU's threads (core/launch.Launcher.launch_parts); without it they run one after the other.
    A sweep's lines are independent (each reads and writes only its own cells), so slabs of them give
    the same marks whatever the split."""

    def __init__(self, cells, ghost, up, dim: int, device, launch, launch_parts=None, threads: int = 1):
        self.cells, self.ghost, self.up, self.dim, self.launch = tuple(cells), tuple(ghost), up, dim, launch
        self.launch_parts = launch_parts or (lambda kernel, parts: [launch(kernel, d, i) for d, i in parts])
        self.threads, self.split_cells = threads, threads_mod.SPLIT_CELLS
        self.device = device
        column = list(cells)
        if up[0] >= 0:
            column[up[0]] = 1
        self.top = wp.zeros(tuple(column), dtype=wp.int32, device=device)
        big = np.iinfo(np.int32).max
        self.covered_reset = wp.array([0, big, big, big, -1, -1, -1], dtype=wp.int32, device=device)
        self.covered = wp.zeros(7, dtype=wp.int32, device=device)  # count, then the box's lowest, highest cell
        self.counter = wp.zeros(1, dtype=wp.int32, device=device)
        self.reached = wp.zeros(cells, dtype=wp.int32, device=device)  # EMPTY cells known to be open air

    def find(self, types, region=None):
        """(types on the host, void cells, their region labels), or None when there is no void.
        region: a box (lo, hi) outside which every interior cell is EMPTY (the grid phases' box), or
        None for the whole grid.

        1. Count the covered EMPTY cells (below a fluid or solid cell of their column; without gravity
           every EMPTY interior cell) and their box: one small read, and a calm scene stops here.
        2. In that box grown by one cell (its outer layer is open air or not EMPTY), mark the EMPTY
           cells that are open air by position, carry the mark along lines of EMPTY cells
           (SWEEP_ROUNDS passes over the axes) and count the cells left: one more scalar, and usually
           that is all (the air under a falling block is reached along its rows).
        3. Only when some are left, read the types and label those cells' regions on the host."""
        (up_axis, up_sign), ghost = self.up, wp.vec3i(*self.ghost)
        lo, hi = region or ((0, 0, 0), self.cells)
        wp.copy(self.covered, self.covered_reset)
        if up_axis >= 0:  # columns: only the region's hold a fluid or solid cell; below it they are covered
            self.top.fill_(-1)
            self._launch(covered_top, lo, hi, [types, up_axis, up_sign, ghost, self.top])
            lo, hi = list(lo), list(hi)
            lo[up_axis], hi[up_axis] = 0, self.cells[up_axis]
        else:
            lo, hi = (0, 0, 0), self.cells
        self._launch(count_covered_empty, lo, hi, [types, self.top, up_axis, up_sign, ghost, self.covered])
        covered = self.covered.numpy()
        if covered[0] == 0:
            return None
        lo, hi = np.maximum(covered[1:4] - 1, 0), np.minimum(covered[4:7] + 2, self.cells)
        box, end = tuple(int(h - l) for l, h in zip(lo, hi)), wp.vec3i(*hi)  # noqa: E741
        self._launch(mark_open_air, lo, hi, [types, self.top, up_axis, up_sign, ghost, self.reached])
        for _ in range(SWEEP_ROUNDS):
            for a in range(self.dim):
                self._sweep(a, box, lo, end, types)
        self.counter.zero_()
        self._launch(count_unreached_empty, lo, hi, [types, self.reached, self.counter])
        if int(self.counter.numpy()[0]) == 0:
            return None
        host = types.numpy().copy()  # the justified host read (only on steps with unreached EMPTY cells)
        inside = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi))
        cells, labels = unreached_regions(host[inside], self.reached.numpy()[inside], lo)
        return (host, cells, labels) if len(cells) else None

    def _sweep(self, axis: int, box, lo, end, types):
        """sweep_open_air along `axis` over the box of `box` cells from `lo`: its lines (the box with
        `axis` cut to 1) in slabs across another axis, one a thread when the box holds split_cells
        (SPLIT_CELLS) cells or more (the sweeps under a falling 32^3 block took 5 ms a step on one thread)."""
        lines = list(box)
        lines[axis] = 1
        across = 1 if axis == 0 else 0
        parts = self.threads if math.prod(box) >= self.split_cells else 1
        cuts = threads_mod.split(0, lines[across], parts)
        launches = []
        for a, b in zip(cuts, cuts[1:]):
            if b > a:
                first = [int(v) for v in lo]
                first[across] += a
                lines[across] = b - a
                launches.append((tuple(lines), [wp.vec3i(*first), end, types, axis, self.reached]))
        self.launch_parts(sweep_open_air, launches)

    def _launch(self, kernel, lo, hi, inputs):
        """A launch over the box [lo, hi), a line of cells a thread (core/lines.py)."""
        box, dims = make_lines(lo, hi, self.dim, self.device)
        self.launch(kernel, dims, [box, *inputs])


@dataclass
class TrappedAir(HostState):
    gas_mass: float = saved("gas_mass_trapped", 0.0)  # kg of air taken from the atmosphere into pockets


class VoidPass:
    """Finds the voids after the cells are classified (VoidSearch) and makes them liquid (or, with gas,
    trapped air); see the module docstring. `last_voids`: void cells found this step (the run's report),
    trapped air seeded this step included, though its cells are gas by the solve."""

    def __init__(self, sim):
        self.sim = sim
        g = sim.grid
        self.search = VoidSearch(g.cells, g.ghost, sim.up, g.dim, sim.device, sim.launch, sim.launch_parts,
                                 sim.parallel.threads)
        self.mask = wp.zeros(g.cells, dtype=wp.int32, device=sim.device)
        liquids = [m for m in sim.scene.materials.values() if m.kind == "liquid"]
        self.rho_liquid = max((m.density for m in liquids), default=1000.0)
        gases = [i for i, m in enumerate(sim.scene.materials.values()) if m.is_gas]
        self.gas_material = gases[0] if gases and sim.has_gas else None
        # Holes are cleared only in scenes without gas. With compressible gas, clearing the holes a
        # rising air bubble leaves drew its gas out into the wake (the largest bubble kept 22-41% of
        # the gas after five diameters instead of 67-73%; tests/test_gas.py). With incompressible
        # gas the correction closes a hole by its own fill, as one medium (volume_correction.cell_excess):
        # cleared to liquid, a hole counted its whole cell as missing on top of its neighbours' share
        # of the same gap, and holes inside the bubble became liquid cells, which made the
        # bubble's rise speed jitter more.
        gas_kinds = [m for m in sim.scene.materials.values() if m.is_gas] if sim.has_gas else []
        self.compressible = any(m.eos != "incompressible" for m in gas_kinds)
        self.clear_holes = not gas_kinds
        self.state = TrappedAir()  # checkpointed (core/host_state.py)
        self.last_voids = 0
        self.by_frame: dict[int, int] = {}  # most void cells at one step, per frame that had any (run summary)
        self.pockets = 0  # void regions seeded as trapped air
        self.seeded = False  # whether this pass seeded trapped air (then Simulation.step splats and classifies again)
        self._step = -1  # the step of the last pass: a second pass in the same step is that redo
        # Bubble gaps: particle-free regions beside compressible gas, left EMPTY (see _fill_voids) and
        # counted apart from the voids: they are connected to a gas region, not closed off in the liquid.
        self.gap_cells = np.zeros((0, 3), int)
        self.gaps_by_frame: dict[int, int] = {}  # most gap cells at one step, per frame that had any

    def apply(self, dt: float):
        """The pass (module docstring). Called a second time in a step after it seeded trapped air
        (the resplat phase, core/step.py): then the pocket's cells hold gas particles and are gas
        cells, and last_voids keeps the larger count of the two passes (the voids found this step)."""
        sim, g, f = self.sim, self.sim.grid, self.sim.fields
        again = self._step == sim.stats.steps
        self._step = sim.stats.steps
        found = self.last_voids if again else 0
        self.last_voids = 0
        self.seeded = False
        self.gap_cells = self.gap_cells[:0]
        voids = self.search.find(f.types, sim.region.box)
        if voids is not None:
            self._fill_voids(*voids)
        self.last_voids = max(self.last_voids, found)
        if self.last_voids:
            self.by_frame[sim.frame] = max(self.by_frame.get(sim.frame, 0), self.last_voids)
        if len(self.gap_cells) and (again or not self.seeded):  # the gaps the solve sees (a seeding pass is redone)
            self.gaps_by_frame[sim.frame] = max(self.gaps_by_frame.get(sim.frame, 0), len(self.gap_cells))
        if self.clear_holes:
            box, dims = sim.region.cell_lines
            sim.launch(clear_holes, dims, [box, g.dim, self.rho_liquid, g.dx**3, sim.two_phase, f.cell_count, f.types,
                                              f.phase_cells, kernel_args.splat(f)])

    def _fill_voids(self, types, cells, labels):
        """Small voids (under POCKET_CELLS cells) become liquid with their full deficit; larger ones, in a
        scene with gas, are seeded with gas (trapped air; the step then splats again), else stay EMPTY."""
        sim, g, f = self.sim, self.sim.grid, self.sim.fields
        ids, inverse, sizes = np.unique(labels, return_inverse=True, return_counts=True)
        large = sizes[inverse] >= POCKET_CELLS
        touching = self._touching_gas(cells, labels, types) if self.gas_material is not None else large & False
        # With compressible gas, a void beside the gas is a gap in its bubble, left to it: EMPTY, p = 0,
        # which draws the gas (and the liquid) in. Closed as liquid, the film between two merging air
        # bubbles was thrown at 3.4 m/s; made a gas cell with no gas in it, 2.0 m/s; held at the gas's
        # pressure, the pour's gaps grew to 5171 cells (both sides) or lasted 4x longer (liquid side
        # only): docs/design.md#voids.
        gap = touching & self.compressible
        self.gap_cells = cells[gap]
        self.last_voids = int((~gap).sum())
        small = ~large & ~gap
        if small.any():
            mask = np.zeros(g.cells, np.int32)
            mask[tuple(cells[small].T)] = 1
            self.mask.assign(mask)
            sim.launch(fill_voids, g.cells, [self.mask, self.rho_liquid, g.dx**3, sim.two_phase, f.gas_volume,
                                             f.types, f.phase_cells, f.liq_mass, f.liq_volume])
        pockets = large & ~touching
        if pockets.any() and self.gas_material is not None:
            self.pockets += len(np.unique(labels[pockets]))
            self._seed_gas(cells[pockets])
            self.seeded = True

    def gap_mask(self) -> np.ndarray:
        """This step's bubble gaps as a boolean cell array (diagnostics.void_cells leaves them out)."""
        mask = np.zeros(self.sim.grid.cells, bool)
        mask[tuple(self.gap_cells.T)] = True
        return mask

    def _touching_gas(self, cells, labels, types):
        """Void cells whose region has a gas cell, a gas particle or a sub-grid bubble in it or beside
        it: the space a bubble's gas just left (vented at a burst, shrunk to a sub-grid bubble) is not
        air a splash trapped, and seeding it made gas that vented again at 2 m/s."""
        sim, g = self.sim, self.sim.grid
        gas = (types == FLUID) & (sim.fields.phase_cells.numpy() == PHASE_GAS)
        gas |= sim.fields.gas_count.numpy() > 0
        p = sim.particles  # a sub-grid bubble in it: the space a resolved bubble shrunk out of
        sub = (p.numpy("phase") == PHASE_SUBGRID) & (p.numpy("active") == 1)
        if sub.any():
            idx = np.floor((p.numpy("x")[sub] - np.asarray(g.origin)) / g.dx).astype(int)
            gas[tuple(np.clip(idx, 0, np.array(g.cells) - 1).T)] = True
        touched = gas[tuple(cells.T)]
        for a in range(g.dim):
            for s in (-1, 1):
                n = cells.copy()
                n[:, a] = np.clip(n[:, a] + s, 0, g.cells[a] - 1)
                touched |= gas[tuple(n.T)]
        return np.isin(labels, np.unique(labels[touched]))

    def _seed_gas(self, cells):
        sim, g = self.sim, self.sim.grid
        ppc = sim.scene.solver.particles_per_cell
        rng = np.random.default_rng([sim.scene.solver.seed, sim.stats.steps])  # same run, same seeds (resume too)
        jitter = rng.random((len(cells), ppc, 3))
        if g.dim == 2:
            jitter[..., 2] = 0.5
        corner = cells[:, None, :] * g.dx + np.asarray(g.origin)
        positions = (corner + jitter * g.dx).reshape(-1, 3)
        n = len(positions)
        material = np.full(n, self.gas_material, np.int32)
        volume = np.full(n, g.dx**3 / ppc)
        added = sim.add_particles(positions, np.zeros((n, 3)), material, volume)
        mass = float(sim.particles.numpy("mass")[added].astype(np.float64).sum())
        self.state.gas_mass += mass
