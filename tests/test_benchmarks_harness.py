"""benchmarks/ is one harness: every benchmark module imports, builds its command line and writes its
result through benchmarks/harness.py, edits no import path, and a cheap one run as a user runs it
writes its JSON and Markdown with the provenance of the figures."""

import ast
import datetime
import importlib
import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import benchmarks
from benchmarks import harness

ROOT = Path(benchmarks.__file__).resolve().parent.parent
FOLDERS = ("performance", "validation", "test_power")


def benchmark_modules() -> list[str]:
    names = []
    for folder in FOLDERS:
        package = importlib.import_module(f"benchmarks.{folder}")
        names += [f"benchmarks.{folder}.{m.name}" for m in pkgutil.iter_modules(package.__path__)]
    return sorted(names)


MODULES = benchmark_modules()


def source_tree(name: str) -> ast.Module:
    return ast.parse(Path(importlib.util.find_spec(name).origin).read_text())


def is_entry_point(tree: ast.Module) -> bool:
    """A script a user runs (it has `if __name__ == "__main__"`), not a helper module of one."""
    return any(isinstance(node, ast.If) and "__main__" in ast.unparse(node.test) for node in tree.body)


def calls(tree: ast.Module) -> list[str]:
    return [ast.unparse(node.func) for node in ast.walk(tree) if isinstance(node, ast.Call)]


def path_edits(tree: ast.Module) -> list[str]:
    """sys.path.insert/append/extend calls and assignments to sys.path, as source lines."""
    found = []
    for node in ast.walk(tree):
        target = None
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            target = node.func.value
        elif isinstance(node, (ast.Assign, ast.AugAssign)):
            target = node.targets[0] if isinstance(node, ast.Assign) else node.target
        if target is not None and ast.unparse(target).endswith("sys.path"):
            found.append(f"line {node.lineno}: {ast.unparse(node)}")
    return found


def test_the_folders_hold_the_benchmarks():
    # The three folders by purpose, each with its scripts: a script left at the top, or a folder
    # emptied by a bad move, shows here. At the top: the harness, the shared cases, and the report
    # that turns saved results into docs/validation.md (it runs no benchmark).
    assert {m.split(".")[1] for m in MODULES} == set(FOLDERS)
    loose = [p.name for p in (ROOT / "benchmarks").glob("*.py")]
    assert sorted(loose) == ["__init__.py", "cases.py", "harness.py", "report.py"], loose
    assert len([m for m in MODULES if is_entry_point(source_tree(m))]) >= 20


@pytest.mark.parametrize("name", MODULES)
def test_every_benchmark_imports(name):
    module = importlib.import_module(name)
    if is_entry_point(source_tree(name)):
        assert callable(getattr(module, "main", None)), f"{name}: no main() to run"


@pytest.mark.parametrize("name", MODULES)
def test_every_benchmark_uses_the_harness_and_edits_no_path(name):
    tree = source_tree(name)
    assert not path_edits(tree), f"{name} edits sys.path: {path_edits(tree)}"
    own = [c for c in calls(tree) if c.split(".")[-1] == "ArgumentParser"]
    assert not own, f"{name} builds its own parser ({own}); use harness.parser()"
    text = ast.unparse(tree)
    assert "rev-parse" not in text, f"{name} asks git itself; harness.provenance() does"
    if is_entry_point(tree):
        used = set(calls(tree))
        assert "harness.parser" in used, f"{name}: its flags are not built with harness.parser()"
        assert "harness.write_result" in used, f"{name}: its result is not written with harness.write_result()"


def test_a_cheap_benchmark_run_as_a_module_writes_its_result_with_provenance(tmp_path):
    # Torricelli's tank at its coarsest cell (a second or two), started as the docs tell a user to.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the -m run must find the package alone
    cmd = [sys.executable, "-m", "benchmarks.validation.torricelli", "--cells", "0.02", "--out", str(tmp_path)]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]

    result = json.loads((tmp_path / "torricelli" / "cpu.json").read_text())
    assert result["benchmark"] == "torricelli"
    prov = result["provenance"]
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    assert prov["commit"] == head.strip()
    assert isinstance(prov["dirty"], bool) and prov["dirty"] == bool(prov["changed_files"])
    assert prov["device"].startswith("cpu (") and prov["cpu_count"] == os.cpu_count()
    import numpy
    import warp

    assert prov["versions"]["warp"] == warp.config.version and prov["versions"]["numpy"] == numpy.__version__
    assert prov["versions"]["usd"]  # usd-core is a dependency
    age = datetime.datetime.now(datetime.timezone.utc) - datetime.datetime.fromisoformat(prov["date"])
    assert datetime.timedelta(0) <= age < datetime.timedelta(minutes=10)
    assert prov["command"] == f"python -m benchmarks.validation.torricelli --cells 0.02 --out {tmp_path}"
    # the measurement itself: one resolution, a jet slower than Torricelli's but of its order
    (case,) = result["cases"]
    assert case["dx"] == 0.02 and 0.5 < case["cv"] < 1.0 and case["steps"] > 0

    md = (tmp_path / "torricelli" / "cpu.md").read_text()
    assert harness.provenance_line(prov) in md
    assert "| 0.02 | 2 |" in md  # its row: cell size and cells across the slot


def test_quick_and_label_runs_keep_their_own_files(tmp_path):
    # A smoke run must never replace the measurement the docs cite, nor one configuration another.
    args = harness.parser("x").parse_args(["--out", str(tmp_path)])
    assert harness.result_stem("b", args) == tmp_path / "b" / "cpu"
    args = harness.parser("x").parse_args(["--out", str(tmp_path), "--quick", "--label", "g64", "--device", "cuda:0"])
    assert harness.result_stem("b", args) == tmp_path / "b" / "cuda0_g64_quick"
