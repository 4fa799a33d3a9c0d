"""The run summary's table of timed phases keeps its columns aligned whatever the phases' names."""

from __future__ import annotations

from benchmarks.cases import subgrid_tank
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.io.runner import RunResult, summary
from warp_mpm_bubbles.scene.effects import SubgridBubbles


def test_phase_columns_line_up_with_a_long_phase_name(tmp_path):
    sim = Simulation(subgrid_tank(tmp_path, effects={"subgrid_bubbles": SubgridBubbles()}), "cpu")
    sim.advance_to(2 * sim.stable_dt())
    text = summary(RunResult(sim, str(tmp_path / "s.usdc"), 1, 1.0))
    lines = text.splitlines()
    head = next(i for i, line in enumerate(lines) if line.lstrip().startswith("phase "))
    table = lines[head:next(i for i in range(head, len(lines)) if lines[i].lstrip().startswith("total")) + 1]
    names = [line.split()[0] for line in table[1:]]
    assert any(len(n) > 10 for n in names), names  # the case this checks: a name past the old 10 columns
    # every row's seconds figure ends where the header's "seconds" ends
    seconds_end = table[0].index("seconds") + len("seconds")
    for line in table[1:]:
        name, seconds = line.split()[:2]
        assert line.index(seconds, line.index(name) + len(name)) + len(seconds) == seconds_end, text
