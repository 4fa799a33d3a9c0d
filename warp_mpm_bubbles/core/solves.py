"""What an iterative solve reports (the pressure's PCG, core/pressure.py; the viscous PCG,
physics/viscous_iterate.py) and a run's tally of them, which the run summary prints."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class SolveInfo:
    iterations: int
    residual: float  # ||b - A x|| / ||b|| at exit
    converged: bool


@dataclass
class SolverStats:
    steps: int = 0
    cg_iterations: int = 0
    cg_max_iterations: int = 0
    cg_solves: int = 0
    cg_unconverged: int = 0
    cg_worst_residual: float = 0.0
    dt_history: list[float] = field(default_factory=list)
    limited_by: dict[str, int] = field(default_factory=dict)  # steps per limit name that set them ("frame": the frame's end)

    def record(self, info: SolveInfo):
        """Add the step's pressure solve."""
        self.cg_solves += 1
        self.cg_iterations += info.iterations
        self.cg_max_iterations = max(self.cg_max_iterations, info.iterations)
        self.cg_worst_residual = max(self.cg_worst_residual, info.residual)
        self.cg_unconverged += 0 if info.converged else 1
