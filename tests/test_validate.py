"""`warp-mpm-bubbles validate`: its table, its exit code, and that a wrong physics fails it."""

from __future__ import annotations

import numpy as np
import pytest

from warp_mpm_bubbles import cli, validation_cases
from warp_mpm_bubbles.core.simulation import Simulation

SMALLEST = "free_fall,hydrostatic"  # the cases that take seconds


def _rows(out: str) -> dict[str, list[str]]:
    lines = out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("case "))
    cols = [lines[head].index(name) for name in ("case", "reference", "ours", "error", "bound", "pass")]
    rows = {}
    for line in lines[head + 2:]:
        if not line.strip():
            break
        cells = [line[a:b].strip() for a, b in zip(cols, cols[1:] + [None])]
        rows[cells[0]] = cells
    return rows


def test_validate_prints_the_table_and_passes(capsys):
    assert cli.main(["validate", "--cases", SMALLEST]) == 0
    out = capsys.readouterr().out
    rows = _rows(out)
    assert len(rows) == 2, out
    for cells in rows.values():
        assert cells[5] == "pass", out
        assert all(cells), out  # every column filled, in its column
    assert "2 of 2 passed" in out


def test_the_quick_set_passes_with_the_defaults(capsys):
    # What a user runs first after installing (the README's table): every quick case within its
    # bound with the default settings, so a change to a default that moves one past it fails here.
    assert cli.main(["validate"]) == 0, capsys.readouterr().out
    out = capsys.readouterr().out
    rows = _rows(out)
    quick = [name for name, (_, in_quick, _) in validation_cases.CASES.items() if in_quick]
    assert len(rows) >= len(quick) and all(cells[5] == "pass" for cells in rows.values()), out


def test_a_gravity_three_percent_off_fails_validate(capsys, monkeypatch):
    class WrongGravity(Simulation):  # the simulator's gravity 3% too strong; the references keep g
        def __init__(self, scene, *a, **k):
            g = scene.domain.gravity
            scene.domain.gravity = tuple(1.03 * np.asarray(g, dtype=float)) if g is not None else g
            super().__init__(scene, *a, **k)

    monkeypatch.setattr(validation_cases, "Simulation", WrongGravity)
    assert cli.main(["validate", "--cases", SMALLEST]) == 1
    out = capsys.readouterr().out
    rows = _rows(out)
    assert [cells[5] for cells in rows.values()] == ["FAIL", "FAIL"], out
    assert "FAILED" in out


def test_an_unknown_case_is_refused_by_name(capsys):
    assert cli.main(["validate", "--cases", "free_fal"]) == 2
    err = capsys.readouterr().err
    assert "--cases" in err and "free_fal" in err and "free_fall" in err


@pytest.mark.parametrize("name", sorted(validation_cases.CASES))
def test_every_case_has_a_docstring_and_a_bound(name):
    fn, quick, smallest = validation_cases.CASES[name]
    assert fn.__doc__ and "ound" in fn.__doc__  # its bound and where it comes from


def test_a_device_this_machine_lacks_is_refused_before_any_case(capsys):
    assert cli.main(["validate", "--cases", "free_fall", "--device", "nonsense"]) == 2
    captured = capsys.readouterr()
    assert "--device" in captured.err and "nonsense" in captured.err and "cpu" in captured.err
    assert "free fall" not in captured.out  # no case ran


def test_a_case_whose_run_stops_fails_with_its_message(capsys, monkeypatch):
    from warp_mpm_bubbles.core.simulation import SimulationError

    def stops(work, device, fine=False):
        raise SimulationError("NaN in the particles at step 3")

    monkeypatch.setitem(validation_cases.CASES, "free_fall", (stops, True, True))
    assert cli.main(["validate", "--cases", "free_fall"]) == 1
    out = capsys.readouterr().out
    assert "stopped: NaN in the particles" in out and "FAIL" in out
