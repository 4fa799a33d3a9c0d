"""The implicit viscous solve's PCG (physics/viscous_solve.py, ViscousSolver.implicit), as a base class
of ViscousSolver: the iteration, its preconditioners and its warm start. The kernels are in
physics/viscous_pcg.py and physics/viscous_multigrid.py; the operator, its diagonal and the launches
(`apply`, `_walk`, `_sums`, the scratch arrays) are ViscousSolver's.

Preconditioners (ViscousSolver.preconditioner):

- "sgs" (the default): one symmetric Gauss-Seidel sweep of each component's own block of the
  matrix (the normal and shear stress coupling a face to the faces of its own axis; the cross
  terms du_b/dx_a between components are left out, so M is block diagonal and, like A, symmetric
  positive definite, as PCG needs). Faces are coloured red and black by the parity of i + j + k:
  every face a face couples to in its block is one index away, so of the other colour, and from
  z = 0 the half-sweeps red, black, red are forward then backward Gauss-Seidel (the backward black
  sweep would repeat the forward one). Each half-sweep reads only the other colour, so its result
  does not depend on the threads' order. `sweeps` repeats the (black, red) pair.
- "multigrid": a V-cycle of each component's block (physics/viscous_multigrid.py). Fewer iterations
  (5.1 against 7.5 a solve on the 1000:1 tank at 80 cells) but a V-cycle costs about six of the
  half-sweeps above, so the stage takes about twice the time there (docs/viscosity.md, "Measured").
- "jacobi": the diagonal alone.

Warm start (`warm_start`, on by default): the PCG starts from a guess of the change delta, the last
two solves' changes per second extrapolated linearly in time to this step (the last one alone after
the first solve), scaled by gamma = b.g / g.A g: the multiple of the guess closest to the solution
in the energy norm, so never further from it than a cold start. At low Reynolds numbers the change
moves slowly from step to step: 11.7 -> 7.5 iterations a solve on the 1000:1 tank at 80 cells, 6.0
-> 5.0 on Hysing's case 1 at 40 (docs/viscosity.md, "Measured"). The tolerance stays relative to the
right-hand side, so the answer is a cold start's to the tolerance. A checkpoint keeps both changes
(guess_arrays), so a resumed run iterates as one that never stopped.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..core.solves import SolveInfo
from .viscous_multigrid import FaceMultigrid, dot_rz, pcg_residual, unknowns_box
from .viscous_pcg import (BLACK, OPERATOR, RED, RHS, add_into, guess_start, pcg_direction, pcg_restart, pcg_start,
                          pcg_step, pcg_update, sgs_sweep)


class ImplicitSolve:
    """PCG on (rho + dt K) delta = -dt K u*: the part of ViscousSolver that iterates."""

    PRECONDITIONERS = ("sgs", "jacobi", "multigrid")

    def _pcg_dots(self, kernel, inputs_of):
        self.dots.zero_()
        for a in self.grid.axes:
            self._walk(kernel, self.r[a].shape, [*inputs_of(a), self.dots])
        _, rr, rz = self._sums()
        return float(rr), float(rz)

    def _sweeps(self, dt: float, colours) -> float:
        """Gauss-Seidel half-sweeps of z = M^-1 r, colour by colour; returns the r . z they add to
        dots[2] (each face's last value: the half-sweeps that end M^-1 visit every face once)."""
        scale = float(dt) * self.inv_dx * self.inv_dx
        for a in self.grid.axes:
            for colour in colours:
                self._walk(sgs_sweep, self.z[a].shape, [colour, a, scale, self.mu_around[a], self.diag[a], self.r[a],
                                                        self.z[a], self.dots])
        return float(self._sums()[2])

    def _last_sweeps(self, dt: float) -> float:
        """After the red half-sweep: black, red, as many times as self.sweeps (symmetric Gauss-Seidel
        iterations); r . z from the last pair, which sets every face's final value."""
        for _ in range(self.sweeps - 1):
            self._sweeps(dt, (BLACK, RED))
        self.dots.zero_()
        return self._sweeps(dt, (BLACK, RED))

    def _build_multigrid(self, inv_rho, dt: float):
        """Each component's V-cycle for this solve, over its unknown faces' box (prepare() has set
        the diagonal for this dt)."""
        if self.multigrid is None:
            self.multigrid = [FaceMultigrid(self.r[a].shape, a, self.dim, self.device, parallel=self._parallel)
                              for a in self.grid.axes]
        scale = float(dt) * self.inv_dx * self.inv_dx
        self._cycled = []  # the components with unknowns (the others keep z = 0)
        for a, mg in zip(self.grid.axes, self.multigrid):
            box = unknowns_box(inv_rho[a], self.dim)
            self.z[a].zero_()
            if box is not None:
                mg.build_faces(scale, inv_rho[a], self.diag[a], self.mu_around[a], box)
                self._cycled.append(a)

    def _v_cycles(self) -> float:
        """z = M^-1 r by a V-cycle per component; returns r . z."""
        self.dots.zero_()
        for a in self._cycled:
            self.multigrid[a].apply(self.r[a], self.z[a])
            self._walk(dot_rz, self.r[a].shape, [self.r[a], self.z[a], self.dots])
        return float(self._sums()[2])

    def _first_direction(self, dt: float) -> float:
        """d = z = M^-1 r for the preconditioners that pcg_start does not apply (its z is the diagonal's);
        returns r . z."""
        if self.preconditioner == "sgs":  # from z = 0: red, black, red
            for a in self.grid.axes:
                self.z[a].zero_()
            self._sweeps(dt, (RED,))
            rz = self._last_sweeps(dt)
        else:
            rz = self._v_cycles()
        for a in self.grid.axes:
            wp.copy(self.d[a], self.z[a])
        return rz

    def _step(self, alpha: float):
        """x += alpha d, r -= alpha A d and what of z = M^-1 r the update's kernel makes; (r . r, r . z)."""
        x = self.delta
        if self.preconditioner == "sgs":  # the update's red z = r / diag is the sweep's first half-sweep
            return self._pcg_dots(pcg_update, lambda a: [alpha, self.d[a], self.Ad[a], self.diag[a], x[a], self.r[a],
                                                         self.z[a]])
        if self.preconditioner == "multigrid":
            return self._pcg_dots(pcg_residual, lambda a: [alpha, self.d[a], self.Ad[a], x[a], self.r[a]])
        return self._pcg_dots(pcg_step, lambda a: [alpha, self.d[a], self.Ad[a], self.diag[a], x[a], self.r[a],
                                                   self.z[a]])

    def guess_arrays(self) -> dict:
        """The warm start's guess by checkpoint name (none before the first implicit solve)."""
        if self._guess_dt <= 0.0:
            return {}
        out = {"viscous_guess_dt": np.array([self._guess_dt], np.float64),
               "viscous_previous_dt": np.array([self._previous_dt], np.float64)}
        for a in self.grid.axes:
            out[f"viscous_guess_{'xyz'[a]}"] = self.delta[a].numpy()
            out[f"viscous_previous_{'xyz'[a]}"] = self.previous[a].numpy()
        return out

    def load_guess(self, arrays: dict):
        """Take back guess_arrays' values (a checkpoint without them: start cold, as before)."""
        if "viscous_guess_dt" not in arrays:
            return
        for a in self.grid.axes:
            self.delta[a].assign(np.asarray(arrays[f"viscous_guess_{'xyz'[a]}"], np.float32))
            self.previous[a].assign(np.asarray(arrays[f"viscous_previous_{'xyz'[a]}"], np.float32))
        self._guess_dt = float(arrays["viscous_guess_dt"][0])
        self._previous_dt = float(arrays["viscous_previous_dt"][0])

    def _extrapolation(self, dt: float):
        """The guess's weights: the change per second, delta / dt, extrapolated linearly in time from
        the last two solves (the last one alone after a cold start), times this dt."""
        ratio = dt / self._guess_dt
        if self._previous_dt <= 0.0:
            return float(ratio), 0.0
        return float(ratio * (1.0 + ratio)), float(ratio * dt / self._previous_dt)

    def _start(self, types, inv_rho, dt: float):
        """r = b - A x, d = the Jacobi direction, from x = 0, or from the last solve's change (warm
        start); returns (|b|, r . r, r . d). b = self.tmp holds the right-hand side."""
        b, x = self.tmp, self.delta
        if not (self.warm_start and self._guess_dt > 0.0):
            rr, rz = self._pcg_dots(pcg_start, lambda a: [b[a], self.diag[a], x[a], self.r[a], self.d[a]])
            return math.sqrt(rr), rr, rz
        c1, c2 = self._extrapolation(dt)
        self.dots.zero_()
        for a in self.grid.axes:
            self._walk(guess_start, x[a].shape, [c1, c2, inv_rho[a], b[a], x[a], self.previous[a], self.dots])
        self._previous_dt = self._guess_dt
        bg = float(self._sums()[2])
        gAg = self.apply(OPERATOR, types, inv_rho, x, dt, self.Ad)
        # The guess g scaled by gamma = b.g / g.A g, the multiple of it closest to the solution in
        # the energy norm: never further from it than x = 0 is, whatever the extrapolation did
        # (honey's steps shrink the change fivefold a step, where extrapolating overshoots).
        gamma = bg / gAg if gAg > 0.0 else 0.0
        self.dots.zero_()
        for a in self.grid.axes:
            self._walk(pcg_restart, x[a].shape, [float(gamma), b[a], self.Ad[a], self.diag[a], x[a], self.r[a],
                                                 self.d[a], self.dots])
        bb, rr, rz = (float(v) for v in self._sums())
        return math.sqrt(bb), rr, rz

    def implicit(self, types, inv_rho, vel, dt: float, tol: float, max_iter: int) -> SolveInfo:
        """Backward Euler: solve (rho + dt K) u = rho u* for the unknown faces, in place, by PCG on
        the change delta = u - u*: (rho + dt K) delta = -dt K u* (the walls' values enter through
        u*). prepare() must have run with this dt."""
        b, x = self.tmp, self.delta
        pre = self.preconditioner
        self.apply(RHS, types, inv_rho, vel, dt, b)
        b_norm, rr, rz = self._start(types, inv_rho, dt)
        self._guess_dt = float(dt)
        it, rel = 0, 0.0
        if b_norm == 0.0:
            for a in self.grid.axes:
                x[a].zero_()
        else:
            rel = math.sqrt(rr) / b_norm
            if pre == "multigrid" and rel > tol:
                self._build_multigrid(inv_rho, dt)
            if pre != "jacobi" and rel > tol:
                rz = self._first_direction(dt)
            while rel > tol and it < max_iter:
                dAd = self.apply(OPERATOR, types, inv_rho, self.d, dt, self.Ad)
                if dAd <= 0.0:
                    break  # round-off at convergence
                rr, rz_new = self._step(float(rz / dAd))
                it += 1
                rel = math.sqrt(rr) / b_norm
                if rel <= tol:
                    break  # converged: no next direction needed
                if pre == "sgs":
                    rz_new = self._last_sweeps(dt)
                elif pre == "multigrid":
                    rz_new = self._v_cycles()
                for a in self.grid.axes:
                    self._walk(pcg_direction, self.d[a].shape, [self.z[a], float(rz_new / rz), self.d[a]])
                rz = rz_new
            for a in self.grid.axes:
                self._walk(add_into, vel[a].shape, [x[a], vel[a]])
        return SolveInfo(it, rel, rel <= tol)
