"""The volume correction (docs/design.md, #volume-correction): how far a cell's fill is beyond the
seeding noise (its excess), and the rate at which the pressure system asks for it to be undone.
Functions only: grid_kernels.pressure_diagonal_and_rhs calls them.
"""

import warp as wp

from .cells import HOLE_FRACTION, fill_fraction

VOLUME_NOISE_BAND = wp.constant(0.1)  # the seeding noise in a cell's rest-volume fraction, left alone


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
def volume_excess(vl: float, vg: float, enclosed: int, inv_dx2: float, dx: float):
    """How far a liquid cell's rest-volume fraction phi = vl/dx^3 is beyond the seeding noise: the
    over-fill past 1 + band, which the volume correction asks to expand; and where the cell has
    liquid on every side (enclosed), the under-fill below 1 - band (gas vg counted as filling it),
    which it asks to contract (near a surface, wall or gas, phi < 1 is legitimate and left alone)."""
    phi = vl * inv_dx2 / dx
    excess = wp.max(phi - 1.0 - VOLUME_NOISE_BAND, 0.0)
    if enclosed == 1:
        phi += vg * inv_dx2 / dx
        excess = wp.min(phi - 1.0 + VOLUME_NOISE_BAND, 0.0) + excess
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
def cell_excess(liq_volume: wp.array3d(dtype=float), gas_volume: wp.array3d(dtype=float),
                gas_kv: wp.array3d(dtype=float), two_phase: int, c: wp.vec3i, enclosed: int, inv_dx2: float,
                dx: float):
    """The volume excess the correction acts on in a cell it governs (volume_excess). Where the cell's
    gas, if any, is incompressible (gas_kv = 0), liquid and gas are one incompressible medium: its total
    fill phi_l + phi_g, over- and under-filled alike (a liquid cell, or a gas cell, which the correction
    governs only then). The gas's own over-fill alone spread a bubble well past its particles'
    volume (nothing closed its under-filled cells); the liquid's alone crushed it to a fraction of it. Beside compressible gas the liquid's over-fill is its own, its under-fill the total."""
    held = liq_volume[c[0], c[1], c[2]]
    gas_here = float(0.0)
    if two_phase != 0:
        gas_here = gas_volume[c[0], c[1], c[2]]
        if gas_kv[c[0], c[1], c[2]] == 0.0:
            held = held + gas_here
            gas_here = 0.0
    return volume_excess(held, gas_here, enclosed, inv_dx2, dx)
