"""Viscosity (docs/viscosity.md): runs when any material has viscosity > 0.

    force     the stress div(mu (grad u + grad u^T)) on u*, across the gas-liquid interface
              (physics/viscous_solve.py): forward Euler, or backward Euler by PCG with a symmetric
              Gauss-Seidel preconditioner on each velocity component (physics/viscous_pcg.py)
    dt_limit  "viscous": forward Euler's stability, dt <= 2 / max_f (Gershgorin rate / rho_f), from
              the last step's grid; none when the step is implicit

[effects.viscosity].solver picks: "explicit", "implicit", or "auto" (the default): explicit while its
limit is not below the step the other limits allow (then it costs nothing in steps), implicit
otherwise. mu of each phase is the largest dynamic viscosity among its materials.
"""

import math
from dataclasses import dataclass

from ..core.host_state import HostState, saved
from ..core.stage import Stage
from ..scene.effects import Viscosity
from .viscous_solve import ViscousSolver


@dataclass
class ViscousRate(HostState):
    rate: float = saved("viscous_rate", 0.0)  # 1/s: the last grid's explicit rate


class ViscosityStage(Stage):
    name = "viscosity"
    limit = "viscous"
    Settings = Viscosity
    graph_safe = False  # its force reads the grid's explicit rate on the host (explicit or implicit)

    def __init__(self, ctx, settings=None):
        super().__init__(ctx, settings or Viscosity())
        materials = list(ctx.scene.materials.values())
        mu = lambda ms: max((m.viscosity for m in ms), default=0.0)  # noqa: E731
        self.mu_liquid = mu([m for m in materials if m.kind == "liquid"])
        self.mu_gas = mu([m for m in materials if m.is_gas])
        # Before the first step's grid exists: each material's own rate, 8 dim nu/dx^2 (4 dim for
        # the Laplacian part, as much again for grad div), so the limit is dx^2 / (4 dim nu).
        nu = max((m.viscosity / m.density for m in materials if m.kind != "foam"), default=0.0)
        # The last grid's rate (1/s) sets the next step, so a resumed run needs it: its state.
        self.state = ViscousRate(8 * ctx.grid.dim * nu / ctx.grid.dx**2)
        self.solver = ViscousSolver(ctx.grid, ctx.device, ctx.launch, launch_parts=ctx.launch_parts,
                                    threads=ctx.launcher.threads, parallel=ctx.launcher.parallel,
                                    counter=ctx.launcher.launches)
        self.counts = {"explicit_steps": 0, "implicit_steps": 0, "substeps": 0, "pcg_iterations": 0,
                       "pcg_max_iterations": 0, "pcg_unconverged": 0}
        self._probing = False

    def state_arrays(self) -> dict:
        """The rate, and the implicit solve's warm start once it has one (a resumed run takes the
        steps and iterations of one that never stopped)."""
        return {**super().state_arrays(), **self.solver.guess_arrays()}

    def load_state(self, arrays: dict) -> None:
        super().load_state(arrays)
        self.solver.load_guess(arrays)

    def explicit_limit(self, ctx) -> float:
        """Forward Euler's largest stable step on the last grid seen (s)."""
        rate = self.state.rate
        return 2.0 / rate if rate > 0.0 else math.inf

    def dt_limit(self, ctx) -> float:
        mode = self.settings.solver
        if mode == "implicit" or self._probing:
            return math.inf
        limit = self.explicit_limit(ctx)
        if mode == "explicit":
            return limit
        self._probing = True  # auto: compare with what the other limits allow
        try:
            others = min(ctx.dt_limits().values(), default=math.inf)
        finally:
            self._probing = False
        return limit if limit >= others else math.inf

    def force(self, ctx, dt: float):
        f, s = ctx.fields, self.settings
        self.solver.set_viscosity(f.types, f.liq_volume, f.gas_volume, ctx.two_phase, self.mu_liquid, self.mu_gas)
        self.state.rate = float(self.solver.prepare(f.types, f.inv_rho, dt))
        limit = self.explicit_limit(ctx)
        if s.solver == "implicit" or (s.solver == "auto" and dt > limit):
            info = self.solver.implicit(f.types, f.inv_rho, f.vel, dt, s.tolerance, s.max_iterations)
            c = self.counts
            c["implicit_steps"] += 1
            c["pcg_iterations"] += info.iterations
            c["pcg_max_iterations"] = max(c["pcg_max_iterations"], info.iterations)
            c["pcg_unconverged"] += 0 if info.converged else 1
            return
        # Explicit. Its limit came from the last step's grid; if this grid is stiffer, substep.
        n = max(1, math.ceil(dt / limit - 1e-9))
        for _ in range(n):
            self.solver.explicit(f.types, f.inv_rho, f.vel, dt / n)
        self.counts["explicit_steps"] += 1
        self.counts["substeps"] += n
