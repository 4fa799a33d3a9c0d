"""The step declared once (core/step.py): the docs' hook tables agree with it, and both the CPU
step and the CUDA-graph step are cut from it (the graph plan is built and checked here on the CPU)."""

import pathlib
import re

import warp as wp

from scenes import tank_2d
from warp_mpm_bubbles import Material, Sphere
from warp_mpm_bubbles.core import stage as stage_module
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.core.step import HOOKS, PHASES, STEP, Run, step_plan

wp.config.quiet = True
ROOT = pathlib.Path(__file__).parents[1]


def hook_rows(lines, pattern):
    return [m.groups() for m in (re.match(pattern, line) for line in lines) if m]


def test_the_hook_table_of_new_effect_md_is_the_step():
    text = (ROOT / "docs" / "new_effect.md").read_text().splitlines()
    rows = hook_rows(text, r"^\| `(\w+)[^`]*` \| ([^|]+?) \|")
    assert rows == [(p.name, p.when) for p in STEP if p.hook]


def test_the_hook_table_of_the_stage_protocol_is_the_step():
    rows = hook_rows(stage_module.__doc__.splitlines(), r"^ {6}(\w+) {2,}(.+?) {2,}\S")
    assert rows == [(p.name, p.when) for p in STEP if p.hook]


def test_design_md_walks_the_hooks_in_step_order():
    text = (ROOT / "docs" / "design.md").read_text()
    section = text[text.index("## 6. The step"):text.index("## 7. The time step")]
    seen = [h for h in re.findall(r"`(?:\w+\.)?(\w+)`", section) if h in HOOKS]
    assert list(dict.fromkeys(seen)) == list(HOOKS)


class FakeStage:
    def __init__(self, graph_safe):
        self.graph_safe = graph_safe


def test_the_graph_plan_captures_only_what_reads_no_host():
    safe, unsafe = FakeStage(True), FakeStage(False)
    stages_at = {"after_p2g": [safe], "on_cells": [safe, unsafe], "force": [safe], "on_extended": [unsafe],
                 "after_g2p": [safe]}
    eager, graph = step_plan(stages_at), step_plan(stages_at, graph=True)
    assert all(len(r.phases) == 1 and not r.captured for r in eager)
    flat = [name for r in eager for name in r.phases]
    assert flat == [p.name for p in STEP if not p.run_by and (not p.hook or p.name in stages_at)]
    assert [name for r in graph for name in r.phases] == flat  # the same step, the same order
    for r in graph:
        if r.captured:
            assert not any(PHASES[n].reads_host or not PHASES[n].capturable for n in r.phases), r
    assert Run(("on_cells",)) in graph  # a stage that is not graph-safe runs between the graphs
    assert Run(("extend",)) in graph  # its on_extended runs inside extend: extend is not captured
    assert Run(("p2g", "after_p2g", "momentum", "classify"), captured=True) in graph
    assert Run(("force", "assemble"), captured=True) in graph  # after the re-splat's test
    assert Run(("resplat",)) in graph and Run(("solve",)) in graph and Run(("after_g2p",)) in graph


def test_a_scenes_graph_plan_is_built_on_the_cpu(tmp_path):
    scene = tank_2d(cells=16, depth=0.6, out=tmp_path / "g.usdc")
    scene.materials["water"] = Material("water", surface_tension=0.072)
    scene.materials["air"] = Material("air", kind="gas")
    scene.shapes.append(Sphere("air", center=(0.5, 0.3), radius=0.12))
    sim = Simulation(scene.validate(), "cpu")
    graph = sim.step_plan(graph=True)
    captured = [r.phases for r in graph if r.captured]
    # The gas stage is not graph-safe (it picks kernels from the last read-back): its hooks run
    # between the graphs; surface tension's force is captured with the assembly.
    assert captured == [("p2g",), ("momentum", "classify"), ("face_density",), ("force", "assemble"), ("extend",),
                        ("g2p",)]
    assert Run(("after_p2g",)) in graph and Run(("before_g2p",)) in graph
    assert [n for r in graph for n in r.phases] == [n for r in sim.step_plan() for n in r.phases]
