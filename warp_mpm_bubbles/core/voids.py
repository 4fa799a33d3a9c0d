"""Voids: particle-free cells inside the liquid (issue #12; docs/design.md, "Voids").

`classify_cells` calls a cell with no particle and a fill fraction under HOLE_FRACTION EMPTY, which
the solve reads as a free surface at p = 0. That is right above the water and wrong inside it: an
EMPTY cell under water pins the pressure to the atmosphere's there, so nothing pushes the water back
in and the hole stays (a filled tank grew 17-56 of them around a rising bubble at 32-64 cells across).

After the cells are classified (and colliders have marked theirs), `VoidPass.apply`:

1. counts, on the device, EMPTY interior cells that have a fluid or solid cell above them in their
   column (against gravity; without gravity every EMPTY interior cell). Open air above a free
   surface has none, so a calm scene reads one scalar and stops here.
2. otherwise reads the cell types (one host read of an int32 per cell, only on steps that have such
   cells) and labels the face-connected EMPTY regions (grid.connected_labels). A region is open air
   if it reaches an open wall (an EMPTY ghost cell) or the domain's top layer (without gravity: any
   side), the rule diagnostics.void_cells counts by; every other EMPTY cell is a void.
3. makes each void of a region under POCKET_CELLS cells a fluid cell of the phase its volumes say
   (liquid as a rule). Its rest-volume fraction is about 0, so the volume correction asks it to
   contract by its full deficit and the pressure closes it (grid_kernels.pressure_diagonal_and_rhs
   counts a near-empty cell with no gas and no EMPTY neighbour as enclosed). With compressible gas,
   a void beside the gas stays EMPTY, as before (filled, a merging film was thrown at 3.4 m/s).
4. leaves a larger region EMPTY this step (closing it by a deficit is violent: the pour's glass
   once sealed 379 cells of air under a sheet, and the water was thrown at 400 m/s). In a scene with
   gas, one that touches no gas is air a splash closed over: it is seeded with gas at the ambient
   pressure, a resolved bubble from the next step on; the mass is booked as taken from the
   atmosphere (host_state["gas_mass_trapped"], so Simulation.gas_budget's total stays exact). One
   beside gas is the space the gas just left (a burst's vented cavity), not trapped air.

Every step, on the device (`clear_holes`), in scenes without gas: a fluid cell with no particle and
no EMPTY neighbour (a void made liquid above) holds nothing, whatever its neighbours' B-splines
splat into it; it becomes a liquid cell with a trace of liquid, so its full deficit counts. With
compressible gas the gas expands into such gaps itself, and closing them by the deficit broke a
rising air bubble up; with incompressible gas the volume correction closes them by their own total
fill, liquid and gas as one medium (see VoidPass.__init__).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .grid import EMPTY, FLUID, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID, connected_labels
from .grid_kernels import cell_type_at

wp.set_module_options({"enable_backward": False})

POCKET_CELLS = 4  # a void region this large is air, not a gap: trapped air with gas, else left EMPTY
VOID_FILL = wp.constant(1.0e-6)  # rest-volume fraction written into a void with none: keeps its faces' density defined


@wp.kernel
def covered_top(types: wp.array3d(dtype=wp.int32), up_axis: int, up_sign: int, ghost: wp.vec3i,
                top: wp.array3d(dtype=wp.int32)):
    """Per column along gravity, the height of the highest interior cell that is not EMPTY (-1: none)."""
    i, j, k = wp.tid()
    c = wp.vec3i(i, j, k)
    for a in range(3):
        if c[a] < ghost[a] or c[a] >= types.shape[a] - ghost[a]:
            return
    if types[i, j, k] == EMPTY:
        return
    h = c[up_axis]
    if up_sign < 0:
        h = types.shape[up_axis] - 1 - h
    col = c
    col[up_axis] = 0
    wp.atomic_max(top, col[0], col[1], col[2], h)


@wp.kernel
def count_covered_empty(types: wp.array3d(dtype=wp.int32), top: wp.array3d(dtype=wp.int32), up_axis: int,
                        up_sign: int, ghost: wp.vec3i, counter: wp.array(dtype=wp.int32)):
    """EMPTY interior cells below a fluid or solid cell of their column: the only ones that can be voids
    (with gravity; up_axis < 0 counts every EMPTY interior cell)."""
    i, j, k = wp.tid()
    c = wp.vec3i(i, j, k)
    for a in range(3):
        if c[a] < ghost[a] or c[a] >= types.shape[a] - ghost[a]:
            return
    if types[i, j, k] != EMPTY:
        return
    if up_axis >= 0:
        h = c[up_axis]
        if up_sign < 0:
            h = types.shape[up_axis] - 1 - h
        col = c
        col[up_axis] = 0
        if h > top[col[0], col[1], col[2]]:
            return
    wp.atomic_add(counter, 0, 1)


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
    if is_void[i, j, k] == 2:  # beside compressible gas: the gas's if it reaches it, else left EMPTY
        if gas_volume[i, j, k] > 0.0:
            types[i, j, k] = FLUID
            phase[i, j, k] = PHASE_GAS
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
def clear_holes(count: wp.array3d(dtype=wp.int32), types: wp.array3d(dtype=wp.int32), dim: int,
                rho_liquid: float, cell_volume: float, two_phase: int, phase: wp.array3d(dtype=wp.int32),
                liq_mass: wp.array3d(dtype=float), liq_volume: wp.array3d(dtype=float),
                gas_mass: wp.array3d(dtype=float), gas_volume: wp.array3d(dtype=float),
                gas_pv: wp.array3d(dtype=float), gas_kv: wp.array3d(dtype=float)):
    """A fluid cell with no particle and no EMPTY neighbour (a hole inside the material, a former void
    included) holds nothing: the volume its neighbours' B-splines splat into it is not there. It
    becomes a liquid cell holding a trace (VOID_FILL) of liquid, so its full volume deficit counts
    and the pressure closes it from whichever phase is around (a gap the gas leaves under a rising
    bubble would otherwise read as gas that is not there, and stay)."""
    i, j, k = wp.tid()
    if types[i, j, k] != FLUID or count[i, j, k] != 0:
        return
    for a in range(dim):
        for s in range(2):
            n = wp.vec3i(i, j, k)
            n[a] = n[a] + 2 * s - 1
            if cell_type_at(types, n) == EMPTY:  # an open wall's ghost cell can be fluid: stay in the array
                return
    phase[i, j, k] = PHASE_LIQUID
    liq_volume[i, j, k] = VOID_FILL * cell_volume
    liq_mass[i, j, k] = rho_liquid * VOID_FILL * cell_volume
    if two_phase != 0:
        gas_mass[i, j, k] = 0.0
        gas_volume[i, j, k] = 0.0
        gas_pv[i, j, k] = 0.0
        gas_kv[i, j, k] = 0.0


def void_mask(types: np.ndarray, ghost, up) -> tuple[np.ndarray, np.ndarray]:
    """The void cells of a cell-type array: (cells, labels), an (m, 3) index array of the EMPTY cells
    whose face-connected EMPTY region reaches neither an open wall nor the domain's top layer (any
    side without gravity), and each one's region label (see diagnostics.void_cells)."""
    empty = np.argwhere(types == EMPTY)
    if len(empty) == 0:
        return empty, np.zeros(0, int)
    labels = connected_labels(empty, 3, faces_only=True)
    shape, ghost = np.array(types.shape), np.array(ghost)
    in_ghost = ((empty < ghost) | (empty >= shape - ghost)).any(axis=1)
    axis, sign = up
    if axis < 0:
        top = ((empty == ghost) | (empty == shape - ghost - 1)).any(axis=1)
    else:
        top = empty[:, axis] == (shape[axis] - ghost[axis] - 1 if sign > 0 else ghost[axis])
    closed = ~np.isin(labels, np.unique(labels[in_ghost | top])) & ~in_ghost
    return empty[closed], labels[closed]


class VoidPass:
    """Finds the voids after the cells are classified and makes them liquid (or, with gas, trapped
    air); see the module docstring. `last_voids`: void cells found this step (the run's report)."""

    def __init__(self, sim):
        self.sim = sim
        g = sim.grid
        column = list(g.cells)
        if sim.up[0] >= 0:
            column[sim.up[0]] = 1
        self.top = wp.zeros(tuple(column), dtype=wp.int32, device=sim.device)
        self.counter = wp.zeros(1, dtype=wp.int32, device=sim.device)
        self.mask = wp.zeros(g.cells, dtype=wp.int32, device=sim.device)
        liquids = [m for m in sim.scene.materials.values() if m.kind == "liquid"]
        self.rho_liquid = max((m.density for m in liquids), default=1000.0)
        gases = [i for i, m in enumerate(sim.scene.materials.values()) if m.is_gas]
        self.gas_material = gases[0] if gases and sim.has_gas else None
        # Holes are cleared only in scenes without gas. With compressible gas, clearing the holes a
        # rising air bubble leaves drew its gas out into the wake (the largest bubble kept 22-41% of
        # the gas after five diameters instead of 67-73%; tests/test_gas.py). With incompressible
        # gas the correction closes a hole by its own fill, as one medium (grid_kernels.cell_excess):
        # cleared to liquid, a hole counted its whole cell as missing on top of its neighbours' share
        # of the same gap, and holes inside the bubble became liquid cells (issue #12, the 2D
        # benchmark at 40 cells: velocity jitter 0.0045 cleared, 0.0031 not).
        gas_kinds = [m for m in sim.scene.materials.values() if m.is_gas] if sim.has_gas else []
        self.compressible = any(m.eos != "incompressible" for m in gas_kinds)
        self.clear_holes = not gas_kinds
        if self.gas_material is not None:  # checkpointed with the rest of host_state
            sim.host_state.setdefault("gas_mass_trapped", np.zeros(1))
        self.last_voids = 0
        self.by_frame: dict[int, int] = {}  # most void cells at one step, per frame that had any (run summary)
        self.pockets = 0  # void regions seeded as trapped air

    def apply(self, dt: float):
        sim, g, f = self.sim, self.sim.grid, self.sim.fields
        up_axis, up_sign = sim.up
        ghost = wp.vec3i(*g.ghost)
        self.counter.zero_()
        if up_axis >= 0:
            self.top.fill_(-1)
            sim.launch(covered_top, g.cells, [f.types, up_axis, up_sign, ghost, self.top])
        sim.launch(count_covered_empty, g.cells, [f.types, self.top, up_axis, up_sign, ghost, self.counter])
        self.last_voids = 0
        if int(self.counter.numpy()[0]) > 0:  # the one scalar read: some EMPTY cell is covered
            self._fill_voids()
        if self.clear_holes:
            sim.launch(clear_holes, g.cells, [f.cell_count, f.types, g.dim, self.rho_liquid, g.dx**3,
                                              sim.two_phase, f.phase_cells, f.liq_mass, f.liq_volume, f.gas_mass,
                                              f.gas_volume, f.gas_pv, f.gas_kv])

    def _fill_voids(self):
        """Small voids (under POCKET_CELLS cells) become liquid with their full deficit; larger ones stay
        EMPTY this step and, in a scene with gas, are seeded with gas for the next (trapped air)."""
        sim, g, f = self.sim, self.sim.grid, self.sim.fields
        types = f.types.numpy().copy()  # the justified host read (only on steps with covered EMPTY cells)
        cells, labels = void_mask(types, g.ghost, sim.up)
        self.last_voids = len(cells)
        if len(cells) == 0:
            return
        self.by_frame[sim.frame] = max(self.by_frame.get(sim.frame, 0), len(cells))
        ids, inverse, sizes = np.unique(labels, return_inverse=True, return_counts=True)
        large = sizes[inverse] >= POCKET_CELLS
        touching = self._touching_gas(cells, labels, types) if self.gas_material is not None else large & False
        # With compressible gas, a void beside the gas is left to it (EMPTY, as before): closed as
        # liquid, the film between two merging air bubbles was thrown at 3.4 m/s (as gas, 2.0 m/s).
        small = ~large & ~(touching & self.compressible)
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
        sim.host_state["gas_mass_trapped"] = sim.host_state["gas_mass_trapped"] + mass
