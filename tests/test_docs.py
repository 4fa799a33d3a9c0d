"""The documentation against the code: the scene reference lists exactly the keys the scene model
accepts, and docs/validation.md is what its generator writes from the saved results."""

from __future__ import annotations

import re
from dataclasses import fields
from pathlib import Path

import pytest

from warp_mpm_bubbles.scene import effects, model

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "docs" / "scenes.md"


def _model_tables() -> dict[str, set[str]]:
    """Each scene table's heading in docs/scenes.md -> the keys the model accepts in it."""
    def keys(cls, given=()):
        return {f.name for f in fields(cls) if f.name not in given}

    tables = {
        "Top level": {"name"},
        "[domain]": keys(model.Domain),
        "[solver]": keys(model.SolverSettings),
        "[materials.NAME]": keys(model.Material, given=("name",)),  # the table's name is the material's
        "[output]": keys(model.Output),
        "[[colliders]]": keys(model.Collider),
    }
    for kind, cls in model.SHAPE_TYPES.items():
        tables[f'[[shapes]] type = "{kind}"'] = keys(cls)
    for kind, cls in effects.EFFECT_TYPES.items():
        if cls.__module__.startswith("warp_mpm_bubbles."):  # not an effect an example registered from outside
            tables[f"[effects.{kind}]"] = keys(cls)
    for kind, cls in model.EMITTER_TYPES.items():
        tables[f'[[emitters]] type = "{kind}"'] = keys(cls)
    return tables


def _documented_tables(text: str) -> dict[str, set[str]]:
    """Each `##`/`###` heading -> the backticked keys in the first column of the table under it."""
    found, heading = {}, None
    for line in text.splitlines():
        m = re.match(r"#{2,3} (.+)$", line)
        if m:
            heading = m.group(1).strip()
            continue
        m = re.match(r"\| `([a-z_]+)` \|", line)
        if heading and m:
            found.setdefault(heading, set()).add(m.group(1))
    return found


def test_scene_reference_lists_every_key_the_model_accepts():
    documented = _documented_tables(SCENES.read_text())
    for table, accepted in _model_tables().items():
        assert table in documented, f"docs/scenes.md has no section '{table}' listing its keys"
        missing = accepted - documented[table]
        extra = documented[table] - accepted
        assert not missing, f"docs/scenes.md, {table}: keys the scene model accepts but the page omits: {sorted(missing)}"
        assert not extra, f"docs/scenes.md, {table}: keys the page lists but the scene model refuses: {sorted(extra)}"


def test_scene_reference_covers_every_table():
    """A table the model gains (a new effect, emitter or shape) needs its own section."""
    documented = _documented_tables(SCENES.read_text())
    assert set(_model_tables()) <= set(documented)


def test_validation_page_is_what_the_report_writes_from_the_saved_results():
    from benchmarks import report

    committed = (ROOT / "docs" / "validation.md").read_text()
    assert committed == report.render(), ("docs/validation.md is out of date with benchmarks/results/: "
                                          "run python -m benchmarks.report and commit the page")


def test_readme_quick_start_runs_the_same_tests_as_ci():
    """The README's test command is the one .ci/run calls, word for word."""
    ci = (ROOT / ".ci" / "run").read_text()
    command = next(line.strip() for line in ci.splitlines() if "pytest" in line and not line.startswith("#"))
    readme = (ROOT / "README.md").read_text()
    quick_start = readme.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    assert command in quick_start.splitlines(), (command, quick_start)
