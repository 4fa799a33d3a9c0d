"""The gas's equation of state on the device: a particle's gauge pressure and compressibility from
its volume ratio J (isothermal p V = const, adiabatic p V^gamma = const, or a fixed density), and a
cell's, the mixture's (docs/design.md, #gas-system). Functions only: they compile into the kernels
that call them (core/transfer_kernels.py, core/grid_kernels.py, physics/gas.py, effects/subgrid.py).
"""

from __future__ import annotations

import warp as wp

from .grid import INTERFACE_BASELINE

wp.set_module_options({"enable_backward": False})

# Gas laws per particle (0: liquid, or a gas with a fixed density: no pressure from compression).
GAS_ISOTHERMAL = 1
GAS_ADIABATIC = 2


@wp.func
def gas_pressure(law: int, J: float, gamma: float, p_atm: float):
    """Gauge pressure of gas compressed to volume ratio J from rest at p_atm."""
    if law == GAS_ISOTHERMAL:
        return p_atm * (1.0 / J - 1.0)
    if law == GAS_ADIABATIC:
        return p_atm * (wp.pow(J, -gamma) - 1.0)
    return 0.0


@wp.func
def gas_compressibility(law: int, J: float, gamma: float, p_atm: float):
    """kappa = 1 / bulk modulus: 1/p for isothermal gas, 1/(gamma p) adiabatic, 0 incompressible."""
    p_abs = p_atm + gas_pressure(law, J, gamma, p_atm)
    if law == GAS_ISOTHERMAL:
        return 1.0 / p_abs
    if law == GAS_ADIABATIC:
        return 1.0 / (gamma * p_abs)
    return 0.0


@wp.func
def cell_compressibility(kv: float, vg: float, interface: int, cell_volume: float):
    """kappa of a cell holding gas (kv: the gas's volume-weighted kappa, vg: its volume). Baseline: a
    gas cell is all gas. Sharp: the mixture's, kappa = alpha kappa_gas (Wood 1930; the liquid's is
    ~0), so the liquid in a cell the interface crosses is not stretched as if it were gas, with
    alpha = vg / cell_volume: the gas then takes the whole cell's volume change the solve allows
    (update_gas_J gives it div dx^3 dt, gas_volume_rate), as the solve assumed. alpha = vg / (vg + vl)
    agreed only in cells exactly filled; a lone gas particle among empty cells (0.05-0.17 of a cell
    of gas, no liquid) had its J moved 1/alpha times more than the solve expected, its pressure
    alternated every step and it reached 241 m/s in the pour (docs/design.md, #gas-system)."""
    kappa = kv / vg
    if interface != INTERFACE_BASELINE:
        kappa = kappa * vg / cell_volume
    return kappa
