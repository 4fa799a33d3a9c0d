"""What the host reads out of a simulation between steps: copies of the particles, the mass
ledgers (where the liquid and the gas went), the gauge pressure and the liquid's volume. Functions of
a Simulation; its methods of the same names call them."""

from __future__ import annotations

import numpy as np

from .grid import PHASE_FOAM, PHASE_GAS, PHASE_LIQUID, PHASE_SUBGRID, RETIRED


def particles_numpy(sim, include_retired: bool = False) -> dict[str, np.ndarray]:
    """Copies of the state of the active particles (vented gas is retired; liquid flying above an
    open top is active), or of all of them.

    Copies: on the CPU device .numpy() is a view that the next step changes.
    """
    p = sim.particles
    view = {name: p.numpy(name) for name in ("x", "v", "material", "J", "mass", "vol0", "phase", "ids")}
    keep = np.arange(p.count) if include_retired else np.flatnonzero(p.numpy("active") != RETIRED)
    ids = view["ids"][keep]
    if len(ids) > 1 and not (ids[1:] > ids[:-1]).all():  # sorted by cell: back to id order
        keep = keep[np.argsort(ids, kind="stable")]
    return {
        "positions": view["x"][keep].copy(),
        "velocities": view["v"][keep].copy(),
        "ids": view["ids"][keep].copy(),
        "material": view["material"][keep].copy(),
        "J": view["J"][keep].copy(),
        "mass": view["mass"][keep].copy(),
        "volume": (view["vol0"] * view["J"])[keep],
        "phase": view["phase"][keep].copy(),  # grid.PHASE_*: foam and sub-grid bubbles have their own radius
    }


def gas_budget(sim) -> dict[str, float]:
    """Gas mass (kg) in the liquid as resolved gas ("inside") and as sub-grid bubbles, in foam,
    vented to the atmosphere (burst foam included, and injected bubbles released straight into
    the air), the float32 rounding of bubble conversions (effects/subgrid.py), and their sum
    (conserved exactly; injectors add to it). Air the liquid took from the atmosphere is booked as
    taken, so the total does not grow by it: "trapped" (a pocket a splash closed over,
    core/voids.py) and "entrained" (sub-grid bubbles a splash seeded, effects/entrainment.py).
    "volume": the resolved gas's volume."""
    p = sim.particles
    phase = p.numpy("phase")
    active = p.numpy("active") == 1
    mass = p.numpy("mass").astype(np.float64)
    held = {key: float(mass[(phase == code) & active].sum())
            for key, code in (("inside", PHASE_GAS), ("subgrid", PHASE_SUBGRID), ("foam", PHASE_FOAM))}
    vented = float(sim.fields.vented_mass.numpy()[0])
    outflow = sim.fields.outflow_mass.numpy()
    left = float(outflow[PHASE_GAS] + outflow[PHASE_SUBGRID] + outflow[PHASE_FOAM])  # through open walls
    kept = sim.state_arrays()  # the books the void pass and the stages keep (core/host_state.py)
    booked = {key: float(kept.get(f"gas_mass_{key}", np.zeros(1))[0])
              for key in ("rounding", "trapped", "entrained")}
    return {**held, "vented": vented, "left": left, **booked,
            "total": held["inside"] + held["subgrid"] + held["foam"] + vented + left + booked["rounding"]
            - booked["trapped"] - booked["entrained"],
            "volume": float((p.numpy("vol0") * p.numpy("J"))[(phase == PHASE_GAS) & active].sum())}


def mass_budget(sim) -> dict[str, dict[str, float]]:
    """Where the mass went, kg. "liquid": "added" (seeded and emitted), "held" (active liquid
    particles), "left" (through open walls) and "error" = added - held - left (float rounding
    only: 0 up to the sums' order). "gas": gas_budget() (its "left" the gas, foam and sub-grid
    bubbles gone through open walls)."""
    p = sim.particles
    liquid = (p.numpy("phase") == PHASE_LIQUID) & (p.numpy("active") != RETIRED)  # flying above an open top too
    held = float(p.numpy("mass")[liquid].astype(np.float64).sum())
    added = sim.ledger.liquid_added
    left = float(sim.fields.outflow_mass.numpy()[PHASE_LIQUID])
    return {"liquid": {"added": added, "held": held, "left": left, "error": added - held - left},
            "gas": gas_budget(sim)}


def liquid_density(sim) -> float:
    """The liquid's mean rest-volume fraction in its interior, 1 at rest density: over the cells
    whose whole 3^dim block is inside the domain and more than half full of liquid (a surface's
    partly filled cells left out), the mean of phi. Above 1 the liquid is compressed by that share.

    Unlike liquid_volume, the particles' sampling noise does not bias it: phi scatters about 7% from
    cell to cell at 4 particles a cell, and min(phi, 1) reads that scatter as lost volume (a
    shuffle of the particles that keeps every volume reads as a loss there), while the scatter's
    mean is 0. Re-splats the current particles.
    """
    sim.particles_to_grid()
    phi = sim.fields.liq_volume.numpy()[sim.grid.interior_slice()] / sim.grid.dx ** 3
    full = np.pad(phi > 0.5, 1)  # the ghost ring and beyond count as not full
    inner = np.ones_like(phi, dtype=bool)
    offsets = (-1, 0, 1)
    for a in offsets:
        for b in offsets:
            for c in (offsets if sim.grid.dim == 3 else (0,)):
                inner &= full[1 + a:1 + a + phi.shape[0], 1 + b:1 + b + phi.shape[1], 1 + c:1 + c + phi.shape[2]]
    return float(phi[inner].mean()) if inner.any() else float("nan")


def pressure_numpy(sim) -> np.ndarray:
    """Gauge pressure (Pa) on interior cells from the last step; non-fluid cells read 0."""
    return sim.fields.pressure.numpy()[sim.grid.interior_slice()]


def liquid_volume(sim) -> float:
    """Volume the particles fill: sum over cells of min(phi, 1) dx^3, phi the rest-volume fraction.

    Clustering particles (the drift that incompressible MPM suffers) raises phi above 1 in some
    cells and lowers this number. Re-splats the current particles; the grid is rebuilt each step.
    """
    sim.particles_to_grid()
    cell_vol = sim.grid.dx ** 3
    phi = sim.fields.liq_volume.numpy() / cell_vol
    return float(np.minimum(phi, 1.0).sum() * cell_vol)
