"""The volume correction (docs/design.md, #volume-correction): how far a cell's fill is beyond the
seeding noise (its excess), and the rate at which the pressure system asks for it to be undone.
Functions only: grid_kernels.pressure_diagonal_and_rhs calls them; core/volume_shift.py moves the
particles when the correction moves positions rather than velocities.
"""

import warp as wp

from .cells import HOLE_FRACTION, cell_type_at, fill_fraction
from .grid import FLUID
from .kernel_args import CellPhases, Splat

VOLUME_NOISE_BAND = wp.constant(0.1)  # the seeding noise in a cell's rest-volume fraction, left alone


# [solver].volume_fill: which fill the excess is read from (StepParams.volume_fill)
VOLUME_FILLS = ("cell", "smoothed")
VOLUME_FILL_SMOOTHED = wp.constant(1)

# [solver].volume_correction_moves: what the correction moves (StepParams.volume_moves). "velocities":
# its divergence is asked of the pressure solve, so the particles carry it; "positions": it is
# solved for on its own and only displaces the particles (core/volume_shift.py).
VOLUME_MOVES = ("velocities", "positions")
VOLUME_MOVES_POSITIONS = wp.constant(1)

MAX_VOLUME_SHARE = 1.0  # the most of a cell's excess one step may undo: more overshoots (and collapses)


def volume_relaxation_rate(relaxation_time: float, dt: float) -> float:
    """The volume correction's rate, 1/s (docs/design.md, #volume-correction): a cell's excess is
    undone at excess / tau per second, tau = SolverSettings.volume_relaxation(dx) ([solver].volume_relaxation_time,
    or the cell over [solver].volume_correction_speed), so the state at a time does not depend on the step; but never more than MAX_VOLUME_SHARE of it in one step, so no
    setting (and no tiny step) overshoots. 0 turns the correction off."""
    if relaxation_time <= 0.0:
        return 0.0
    return 1.0 / max(relaxation_time, dt / MAX_VOLUME_SHARE)


@wp.func
def volume_excess(vl: float, vg: float, enclosed: int, inv_dx2: float, dx: float, band: float):
    """How far a liquid cell's rest-volume fraction phi = vl/dx^3 is beyond the seeding noise `band`
    (VOLUME_NOISE_BAND for one cell's fill, 0 for the smoothed fill): the over-fill past 1 + band,
    which the volume correction asks to expand; and where the cell has liquid on every side
    (enclosed), the under-fill below 1 - band (gas vg counted as filling it), which it asks to
    contract (near a surface, wall or gas, phi < 1 is legitimate and left alone)."""
    phi = vl * inv_dx2 / dx
    excess = wp.max(phi - 1.0 - band, 0.0)
    if enclosed == 1:
        phi += vg * inv_dx2 / dx
        excess = wp.min(phi - 1.0 + band, 0.0) + excess
    return excess


@wp.func
def is_hole(liq_volume: wp.array3d(dtype=float), gas_volume: wp.array3d(dtype=float), two_phase: int, c: wp.vec3i,
            inv_dx3: float, pinned: int):
    """A near-empty cell with no gas and no EMPTY neighbour is a hole inside the material
    (core/voids.py): its deficit counts whatever its neighbours are, so the correction closes it."""
    if pinned != 0 or fill_fraction(liq_volume, gas_volume, two_phase, c, inv_dx3) > HOLE_FRACTION:
        return False
    return two_phase == 0 or gas_volume[c[0], c[1], c[2]] == 0.0


@wp.func
def held_volume(splat: Splat, two_phase: int, c: wp.vec3i):
    """The volume that fills cell c as one incompressible medium: its liquid, and its gas where the
    gas is incompressible (gas_kv = 0)."""
    held = splat.liq_volume[c[0], c[1], c[2]]
    if two_phase != 0:
        if splat.gas_kv[c[0], c[1], c[2]] == 0.0:
            held = held + splat.gas_volume[c[0], c[1], c[2]]
    return held


@wp.func
def compressible_gas_volume(splat: Splat, two_phase: int, c: wp.vec3i):
    """Cell c's gas where it is compressible (gas_kv > 0), which held_volume leaves out: it counts
    only against the cell's under-fill (volume_excess)."""
    if two_phase != 0:
        if splat.gas_kv[c[0], c[1], c[2]] > 0.0:
            return splat.gas_volume[c[0], c[1], c[2]]
    return 0.0


@wp.func
def cell_excess(splat: Splat, two_phase: int, c: wp.vec3i, enclosed: int, inv_dx2: float, dx: float, band: float):
    """The volume excess the correction acts on in a cell it governs (volume_excess), past `band`.
    Where the cell's gas, if any, is incompressible (gas_kv = 0), liquid and gas are one
    incompressible medium: its total fill phi_l + phi_g, over- and under-filled alike (a liquid
    cell, or a gas cell, which the correction governs only then). The gas's own over-fill alone
    spread a bubble well past its particles' volume (nothing closed its under-filled cells); the
    liquid's alone crushed it to a fraction of it. Beside compressible gas the liquid's over-fill is
    its own, its under-fill the total."""
    return volume_excess(held_volume(splat, two_phase, c), compressible_gas_volume(splat, two_phase, c), enclosed,
                         inv_dx2, dx, band)


@wp.func
def smoothed_excess(cells: CellPhases, splat: Splat, two_phase: int, c: wp.vec3i, dim: int, enclosed: int,
                    inv_dx2: float, dx: float, enclosed_cells: wp.array3d(dtype=wp.int32)):
    """The excess of [solver].volume_fill = "smoothed" (docs/design.md, #volume-correction): the
    excess, with no noise band, of the mean held volume over the fluid cells of the 3^dim block,
    weighted (1 2 1)/4 along each axis. A neighbour beside a free surface, a wall or compressible
    gas (not enclosed) is partly empty for a reason that is not the liquid's density, so it counts
    as exactly full: neither its room nor its noise is read (counting it as at least full, its
    over-fill but not its under-fill, biased the mean up at every surface and pumped a sloshing
    tank's energy to 5 times its start in 1,000 steps). The cell itself always counts its own.

    Why: most of the particles' sampling noise in one cell's fill (about 7% of it at 4 per cell)
    is gone from the mean, so no dead band is needed; and a correction that answers its excess in
    proportion, not past a band, does not turn that noise into a rectified, one-signed divergence
    that shakes a bubble (docs/design.md, #limitations).

    A cell that is not enclosed keeps the cell rule (cell_excess): there only its over-fill is
    undone, so any noise it answered would be rectified into a steady expansion (with no band a
    resting tank rose, a head's floor pressure read 5% high); and a stream piling into a corner
    needs its own cell's over-fill undone, not a sixteenth of it."""
    if enclosed == 0:
        return cell_excess(splat, two_phase, c, enclosed, inv_dx2, dx, VOLUME_NOISE_BAND)
    types = cells.types
    cell_volume = dx * dx * dx
    kz = int(0)
    if dim == 3:
        kz = 1
    total = float(0.0)
    weight = float(0.0)
    for a in range(-1, 2):
        for b in range(-1, 2):
            for e in range(-kz, kz + 1):
                n = c + wp.vec3i(a, b, e)
                if cell_type_at(types, n) == FLUID:
                    w = float((2 - abs(a)) * (2 - abs(b)) * (2 - abs(e)))
                    held = held_volume(splat, two_phase, n)
                    beside = a != 0 or b != 0 or e != 0
                    if beside and enclosed_cells[n[0], n[1], n[2]] == 0:  # grid_kernels.mark_enclosed
                        held = cell_volume
                    total += w * held
                    weight += w
    return volume_excess(total / weight, compressible_gas_volume(splat, two_phase, c), enclosed, inv_dx2, dx, 0.0)


@wp.func
def correction_target(fill: int, shifted: int, rate: float, cells: CellPhases, splat: Splat, two_phase: int,
                      c: wp.vec3i, dim: int, enclosed: int, inv_dx2: float, dx: float,
                      enclosed_cells: wp.array3d(dtype=wp.int32)):
    """The divergence (1/s) the correction asks of cell c: the rate times its excess by the scene's
    fill, so at most MAX_VOLUME_SHARE * excess / dt (volume_relaxation_rate).

    `shifted`: c is enclosed and its correction moves positions (core/volume_shift.py). Its own
    fill is then answered whole, with no band: the band keeps the particles' sampling noise out of
    the velocities, and a shift puts nothing in them; past a band the noise is answered in one-signed
    kicks that shake a rising bubble (docs/design.md, #volume-shift)."""
    if fill == VOLUME_FILL_SMOOTHED:
        return rate * smoothed_excess(cells, splat, two_phase, c, dim, enclosed, inv_dx2, dx, enclosed_cells)
    band = VOLUME_NOISE_BAND
    if shifted != 0:
        band = 0.0
    return rate * cell_excess(splat, two_phase, c, enclosed, inv_dx2, dx, band)
