"""The step, declared once: the ordered phases of one time step, core work and hook points alike.

`Simulation.step` runs this list one phase after another; `Simulation.step_graph` (CUDA) runs the
same list, capturing each stretch of capturable phases between the ones that read the host into a
CUDA graph (`step_plan(..., graph=True)` cuts it). Nothing else holds the order of a step: the hook
tables in docs/new_effect.md, docs/design.md and core/stage.py are checked against `STEP` by
tests/test_step.py.

Each phase says:

- ``hook``: a point where the scene's optional stages run (`Stage`), else the core's own work,
  done by `Simulation._phase_<name>`;
- ``timer``: the run summary's line it is timed on; a hook with None times each stage on its own
  line (`Stage.timer`); a core phase with None is not timed;
- ``writes_grid``: it (or a stage at it) writes grid arrays: a scene keeps the active box only if
  every stage at such a hook is box-aware (`Stage.grid_box`, core/active_box.py);
- ``reads_host``: it reads device data on the host (a synchronization; docs/host_syncs.md);
- ``capturable``: it may run inside a CUDA graph (it launches device work only and bakes in no
  value that changes from step to step but dt). A hook is captured only if every stage at it
  also says so (`Stage.graph_safe`);
- ``run_by``: a hook that a core phase calls itself (on_extended: after each extrapolation), not
  the step; ``repeat_from``: a phase that runs the phases from that one up to itself again, once,
  when the void pass seeded trapped air this step (core/voids.py).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Phase:
    name: str
    when: str = ""  # hooks: the point of the step, as the docs' hook tables say it
    hook: bool = False
    timer: str | None = None
    writes_grid: bool = False
    reads_host: bool = False
    capturable: bool = True
    run_by: str | None = None
    repeat_from: str | None = None


def _hook(name, when, timer=None, writes_grid=False, capturable=True, run_by=None) -> Phase:
    return Phase(name, when, True, timer, writes_grid, False, capturable, run_by)


def _core(name, timer=None, writes_grid=True, reads_host=False, capturable=True, repeat_from=None) -> Phase:
    return Phase(name, "", False, timer, writes_grid, reads_host, capturable, None, repeat_from)


STEP: tuple[Phase, ...] = (
    # Stages add particles from the host here (emitters): outside any graph.
    _hook("begin_step", "before p2g", capturable=False),
    _core("sort", "p2g", writes_grid=False, capturable=False),  # reorders the particle arrays in place
    _core("region", "p2g", writes_grid=False, reads_host=True, capturable=False),  # the grid box, read on the host
    _core("p2g", "p2g"),
    _hook("after_p2g", "particle sums are on the grid", "p2g", writes_grid=True),
    _core("momentum", "grid"),  # u* = p/m + dt g
    _hook("on_momentum", "u* = p/m + dt g is on the faces", "grid", writes_grid=True),
    _core("classify", "grid"),
    _hook("on_cells", "cells are classified", "grid", writes_grid=True),
    _core("voids", "grid", reads_host=True, capturable=False),
    _core("face_density", "grid"),
    _hook("on_faces", "face densities are set", "grid", writes_grid=True),
    _core("resplat", writes_grid=False, capturable=False, repeat_from="region"),
    _hook("force", "on u* before the solve", writes_grid=True),
    _core("assemble", "grid"),
    _core("solve", "pressure", reads_host=True, capturable=False),  # cell counts, the CG's exit test
    _hook("before_extend", "u is projected", "extend", writes_grid=True),
    _core("extend", "extend"),
    _hook("on_extended", "a face field was extrapolated", writes_grid=True, run_by="extend"),
    _hook("before_g2p", "the grid is final", "g2p"),
    _core("g2p", "g2p", writes_grid=False),
    # Stages convert, seed and retire particles on the host here: outside any graph.
    _hook("after_g2p", "particles have moved", capturable=False),
    _hook("end_step", "last", capturable=False),
    _core("read_back", writes_grid=False, reads_host=True, capturable=False),  # the step's one read-back
)
PHASES = {p.name: p for p in STEP}
HOOKS = tuple(p.name for p in STEP if p.hook)
GRID_WRITING_HOOKS = tuple(p.name for p in STEP if p.hook and p.writes_grid)
RUN_BY = {p.run_by: [q.name for q in STEP if q.run_by == p.run_by] for p in STEP if p.run_by}  # phase: its hooks


@dataclass(frozen=True)
class Run:
    """Phases run together: one phase, or (captured) a stretch replayed as one CUDA graph."""

    phases: tuple[str, ...]
    captured: bool = False


def step_plan(stages_at: dict[str, list], graph: bool = False) -> list[Run]:
    """The step as runs of phases, for a scene whose stages at each hook are `stages_at[hook]`:
    hooks without a stage and hooks a core phase runs itself are left out. graph=False: one phase a
    run (Simulation.step). graph=True: each stretch of capturable phases between the others is one
    captured run, a hook captured only if all its stages are `graph_safe` (Simulation.step_graph)."""
    runs: list[Run] = []
    stretch: list[str] = []
    for phase in STEP:
        if phase.run_by or (phase.hook and not stages_at.get(phase.name)):
            continue
        capturable = phase.capturable and all(s.graph_safe for hook in [phase.name] + RUN_BY.get(phase.name, [])
                                              for s in stages_at.get(hook, ()))
        if graph and capturable:
            stretch.append(phase.name)
            continue
        if stretch:
            runs.append(Run(tuple(stretch), captured=True))
            stretch = []
        runs.append(Run((phase.name,)))
    if stretch:
        runs.append(Run(tuple(stretch), captured=True))
    return runs
