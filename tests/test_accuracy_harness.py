"""Smoke test of benchmarks/validation/accuracy_vs_time.py: --quick on its cheapest case (the 2D Laplace drop)."""

import csv
import math

import pytest

from benchmarks.validation import accuracy_vs_time
from benchmarks.validation.accuracy_cases import R0

EXPECTED_COLUMNS = [
    "case", "metric", "setting", "value", "is_default", "run_id", "batch", "quality", "resolution", "resolution_unit",
    "dx", "refine", "particles_per_cell", "cfl", "cg_tolerance", "interface", "seed", "particles", "cells", "steps",
    "cg_iterations_mean", "wall_s", "cpu_s", "measured", "reference", "error", "error_signed", "error_kind", "note",
]


def test_quick_laplace_writes_csv_with_finite_errors(tmp_path):
    study = accuracy_vs_time
    assert study.main(["--quick", "--cases", "laplace", "--out", str(tmp_path), "--no-plot"]) == 0
    stem = tmp_path / "accuracy_vs_time" / "cpu_quick"  # results/<benchmark>/<device>[_quick]
    with open(stem.with_suffix(".csv"), newline="") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == EXPECTED_COLUMNS
        rows = list(reader)
    assert rows and {r["case"] for r in rows} == {"laplace"}
    # every sweep of the quick plan is there, with the default run marked in each
    assert {r["setting"] for r in rows} == {"resolution", "particles_per_cell", "cg_tolerance", "quality", "seed"}
    assert sum(int(r["is_default"]) for r in rows) >= 5
    for r in rows:
        assert math.isfinite(float(r["error"])) and float(r["error"]) >= 0.0, r
        assert float(r["wall_s"]) > 0.0 and int(r["steps"]) > 0, r
    # the quick resolution levels (4 and 6 cells per radius) bound the Laplace jump within 15%
    assert max(float(r["error"]) for r in rows if r["setting"] == "resolution") < 0.15
    text = stem.with_suffix(".md").read_text()
    assert "Convergence with resolution" in text and "cpu" in text
    assert "| laplace: pressure_jump | preview |" in (tmp_path / "accuracy_vs_time" / "cpu_quick_presets.md").read_text()

    # --only presets reruns the quality and seed rows and keeps the others from the saved JSON
    assert study.main(["--quick", "--cases", "laplace", "--out", str(tmp_path), "--no-plot",
                         "--only", "presets"]) == 0
    with open(stem.with_suffix(".csv"), newline="") as f:
        merged = list(csv.DictReader(f))
    assert len(merged) == len(rows)
    assert {r["batch"] for r in merged if r["setting"] in ("quality", "seed")} == {"1"}
    assert {r["batch"] for r in merged if r["setting"] not in ("quality", "seed")} == {"0"}
    assert [r["error"] for r in merged] == [r["error"] for r in rows]  # the CPU runs are deterministic


def test_presets_apply_through_with_quality_and_refine_the_grid(tmp_path):
    study = accuracy_vs_time
    case = study.CASES["laplace"]
    scene = study.build_scene(case, {"quality": "reference", "resolution": 8}, tmp_path)
    assert scene.solver.refine == 2 and scene.solver.cfl == 0.25
    assert math.isclose(scene.domain.dx, R0 / 16)
    production = study.build_scene(case, {"quality": "production", "resolution": 8, "cfl": 1.0}, tmp_path)
    assert production.validate().solver.refine == 1 and production.solver.cfl == 1.0


def test_only_into_an_empty_folder_starts_a_new_file_and_render_only_there_is_refused(tmp_path, capsys):
    # --only merged into the saved run and raised FileNotFoundError where none was saved yet.
    study = accuracy_vs_time
    with pytest.raises(SystemExit) as refused:
        study.main(["--quick", "--cases", "laplace", "--out", str(tmp_path), "--render-only"])
    assert refused.value.code == 2 and "no saved run" in capsys.readouterr().err
    assert study.main(["--quick", "--cases", "laplace", "--out", str(tmp_path), "--no-plot", "--only", "presets"]) == 0
    with open(tmp_path / "accuracy_vs_time" / "cpu_quick.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and {r["setting"] for r in rows} == {"quality", "seed"} and {r["batch"] for r in rows} == {"0"}
