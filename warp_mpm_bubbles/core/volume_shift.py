"""The volume correction that moves positions: `[solver].volume_correction_moves = "positions"`, the
default.

Moving velocities, the correction asks each over- or under-filled liquid cell for a divergence d of
the step's pressure solve (core/volume_correction.py). The particles then carry that divergence in
their velocities, and the next step's u* still holds part of it: the solve undoes that part and asks
the new d, so the pressure it returns holds a term of about rho (d_old - d_new) L^2 / dt, and the
velocities the noise the correction answers. A noise band keeps most cells at d = 0, but what it lets
through it answers in one-signed kicks, which make a rising bubble shiver.

This mode keeps the correction out of the flow in the cells enclosed in liquid (or gas of fixed
density), where the particles' sampling is all that makes a cell over- or under-full:
- the step's solve sees the flow's right-hand side only there, so its pressure and velocity are the
  flow's; each such cell's whole excess is asked, with no band (volume_correction.correction_target);
- the correction's own system, A phi = d / dt with the same operator A, gives a displacement field
  u_c = -dt / rho grad phi on the faces, as the projection would, with div u_c = d;
- in g2p each particle of the liquid (and of a gas of fixed density, which the correction's cells
  also hold) moves by dt u_c too, sampled at its start with the stencil its velocity is gathered
  with (transfer_kernels.G2P); its velocity is not touched.
A cell at a free surface, a wall or compressible gas keeps asking the step's solve, past the band: a
shift there pushed a film's liquid into the compressible gas beside it, which gives way to the
solve's pressure but not to a shift.

phi is a correction to a correction, so its solve stops at SHIFT_TOLERANCE, 10%: what one step
leaves unanswered stays in the fill and is asked again the next. Measured against 1% (Hysing's
tank at 40 and 80 cells, the dam break at 16 cells per a): the same jitter, rise and compression
to the printed digits, in 1.8 iterations a step instead of 3.1 on the peer block; at 30% the
bubble's jitter at 40 cells grew from 0.12% to 0.45%. It starts from the last step's phi, which the
checkpoint keeps, so a resumed run moves exactly as one that never stopped.
"""

from __future__ import annotations

import warp as wp

from . import grid_kernels as gk
from .pressure import PressureSystem

SHIFT_TOLERANCE = 0.1  # the correction's solve: relative residual (see the module docstring)


class VolumeShift:
    """The correction's own solve, and the displacement field g2p moves particles by (see the module docstring)."""

    def __init__(self, sim):
        f = sim.fields
        f.correction_rhs, f.correction_potential = f.cells(), f.cells()
        self.full_pressure = wp.zeros_like(f.pressure)  # the step's, kept while phi borrows its array
        self.shift = [wp.zeros_like(v) for v in f.vel]  # u_c on the faces
        self.marks = [wp.zeros_like(v) for v in f.valid]  # which faces the gradient set (unused)
        self.iterations = self.solves = 0  # for the run summary

    def solve(self, sim, step, singular: bool, n_fluid: int, apart: bool):
        """After the step's projection: phi from A phi = d / dt, then u_c = -dt / rho grad phi.

        Solved in the step's own arrays (f.rhs, f.pressure), so the solver's recorded launches
        replay; the pressure, and the solver's guess of how long the next solve takes, are put back."""
        f, r, solver, settings = sim.fields, sim.region, sim.solver, sim.scene.solver
        wp.copy(self.full_pressure, f.pressure)
        wp.copy(f.pressure, f.correction_potential)
        wp.copy(f.rhs, f.correction_rhs)
        if apart:  # each sealed region solvable on its own, as the step's rhs was made (core/sealed_regions.py)
            sim.sealed.remove_rhs_means(sim, f)
        predicted = solver.predicted
        info = solver.solve(
            PressureSystem(f.types, tuple(f.inv_rho), f.diag, f.extra_diag), f.rhs, f.pressure,
            tol=SHIFT_TOLERANCE, max_iter=settings.cg_max_iterations, preconditioner=settings.preconditioner,
            singular=singular, n_fluid=n_fluid, region=r.box if r.enabled else None, same_system=True,
        )
        solver.predicted = predicted
        self.iterations += info.iterations
        self.solves += 1
        wp.copy(f.correction_potential, f.pressure)
        for a in sim.grid.axes:
            self.shift[a].zero_()
            sim.launch_lines(gk.subtract_pressure_gradient, r.face_lines[a],
                             [step, a, f.types, f.pressure, f.inv_rho[a], self.shift[a], self.marks[a]])
        wp.copy(f.pressure, self.full_pressure)
