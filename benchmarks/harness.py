"""What every benchmark shares: its command-line flags, the provenance of a result, and where and how
the result is written.

A benchmark builds its parser with `parser()` (the common flags --device, --quick, --out, --label are
already on it; it adds its own), and ends with `write_result()`, which writes

    <out>/<benchmark>/<device>[_<label>][_quick].json    {"benchmark", "provenance", ...the data}
    <out>/<benchmark>/<device>[_<label>][_quick].md      provenance line, then the benchmark's table

<out> is benchmarks/results/ unless --out names another folder. One file per benchmark, device and
configuration: a rerun replaces the file, and the earlier figures stay in git's history. A --quick
(smoke) run writes its own `_quick` file so it never replaces a full measurement.

Run a benchmark as a module from the repository root, `python -m benchmarks.performance.throughput`:
the package imported is then this checkout's, with no path editing.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"


def parser(description: str | None, quick: str = "a smaller run, for a smoke check",
           device: str = "cpu") -> argparse.ArgumentParser:
    """The benchmark's argument parser with the common flags; `quick` says what --quick shrinks."""
    ap = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    common = ap.add_argument_group("common benchmark flags")
    common.add_argument("--device", default=device, help=f'Warp device, e.g. "cpu", "cuda:0" (default {device})')
    common.add_argument("--quick", action="store_true", help=quick)
    common.add_argument("--out", type=Path, default=RESULTS,
                        help="results folder (default benchmarks/results); the file is <benchmark>/<device>.json")
    common.add_argument("--label", default=None,
                        help="a name for this configuration, appended to the file name (<device>_<label>.json)")
    return ap


def device_tag(device: str) -> str:
    """A Warp device alias as a file name: cpu, cuda0."""
    return str(device).replace(":", "")


def result_stem(benchmark: str, args, device: str | None = None) -> Path:
    """<out>/<benchmark>/<device>[_<label>][_quick], without a suffix."""
    name = device_tag(device or args.device)
    if getattr(args, "label", None):
        name += f"_{args.label}"
    if getattr(args, "quick", False):
        name += "_quick"
    return Path(args.out) / benchmark / name


def _git(*a, cwd: Path = ROOT) -> str:
    try:
        return subprocess.run(["git", *a], cwd=cwd, capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return ""


def checkout_commit(root: Path) -> str:
    """The commit of another checkout (a benchmark's --before DIR), and whether its tracked files differ
    from it: the code an "ours before" row measured."""
    sha = _git("rev-parse", "--short", "HEAD", cwd=root) or "unknown"
    return sha + (" (+ uncommitted changes)" if _git("status", "--porcelain", "--untracked-files=no", cwd=root) else "")


def last_change(*paths: str) -> str:
    """The last commit that changed `paths` (git pathspecs), and whether they differ from it now: the
    code a saved run measured, when runs made at several commits are merged into one report."""
    sha = _git("log", "-1", "--format=%h", "--", *paths) or "unknown"
    dirty = _git("status", "--porcelain", "--", *paths)
    return sha + (f" (+ uncommitted changes to {paths[0]})" if dirty else "")


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def describe_device(device: str) -> str:
    """The GPU's name, or the CPU model and core count (as the package's timer notes name them)."""
    import warp as wp

    from warp_mpm_bubbles.core.timing import describe_device as describe

    return describe(wp.get_device(device))


def provenance(device: str = "cpu") -> dict:
    """What produced a result: the code (commit, and which tracked files differed from it), the machine,
    the library versions and the command, so a figure can be traced and rerun."""
    changed = [line[3:] for line in _git("status", "--porcelain", "--untracked-files=no").splitlines()]
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "commit": _git("rev-parse", "--short", "HEAD") or "unknown",
        "dirty": bool(changed),
        "changed_files": changed,
        "device": describe_device(device),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "versions": {name: _version(dist) for name, dist in
                     (("warp", "warp-lang"), ("numpy", "numpy"), ("usd", "usd-core"))},
        "command": command_line(),
    }


def command_line() -> str:
    """How this process was started, as a user would retype it (`python -m benchmarks....` for a module)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    head = ["-m", spec.name] if spec is not None else sys.argv[:1]
    return "python " + shlex.join([*head, *sys.argv[1:]])


def provenance_line(prov: dict) -> str:
    """One Markdown line naming the code, device, versions, date and command of a result."""
    code = prov["commit"] + (" with uncommitted changes" if prov["dirty"] else "")
    versions = ", ".join(f"{k} {v}" for k, v in prov["versions"].items() if v)
    return (f"*{prov['date']} on {prov['device']}; code {code}; {versions}, python {prov['python']}; "
            f"`{prov['command']}`*")


def markdown_table(header: list[str], rows: list[list], align: str | None = None) -> str:
    """A Markdown table; `align` is one character per column, 'l' or 'r' (default: first left, rest right)."""
    align = align or "l" + "r" * (len(header) - 1)
    lines = ["| " + " | ".join(map(str, header)) + " |",
             "|" + "|".join("---" if a == "l" else "---:" for a in align) + "|"]
    lines += ["| " + " | ".join(map(str, row)) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def records_table(records: dict, first: str = "run") -> str:
    """A Markdown table of named records ({name: {field: value}}): one row each, a column per scalar
    field (numbers to 4 significant digits); nested values are left to the JSON."""
    scalar = (int, float, str, bool, type(None))
    fields = list(dict.fromkeys(k for r in records.values() if isinstance(r, dict)
                                for k, v in r.items() if isinstance(v, scalar)))
    fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
    rows = [[name, *(fmt(r.get(k, "")) if isinstance(r, dict) else "" for k in fields)] for name, r in records.items()]
    return markdown_table([first, *fields], rows)


def write_result(benchmark: str, args, data: dict, markdown: str | None = None, *,
                 device: str | None = None, title: str | None = None) -> Path:
    """Write the result's JSON (with provenance) and, given a table, its Markdown; returns the JSON path."""
    device = device or args.device
    stem = result_stem(benchmark, args, device)
    stem.parent.mkdir(parents=True, exist_ok=True)
    prov = provenance(device)
    path = stem.with_suffix(".json")
    path.write_text(json.dumps({"benchmark": benchmark, "provenance": prov, **data}, indent=1, default=float) + "\n")
    if markdown is not None:
        head = f"# {title or benchmark}\n\n{provenance_line(prov)}\n\n"
        stem.with_suffix(".md").write_text(head + markdown.rstrip("\n") + "\n")
    print(f"wrote {path}" + (" and .md" if markdown is not None else ""), file=sys.stderr)
    return path


def read_result(benchmark: str, args, device: str | None = None) -> dict | None:
    """The stored result this configuration would replace (benchmarks that merge into it), or None."""
    path = result_stem(benchmark, args, device).with_suffix(".json")
    return json.loads(path.read_text()) if path.exists() else None


def module_command(module: str, *args) -> list[str]:
    """The command that runs a benchmark module in a fresh interpreter (its workers), from ROOT."""
    return [sys.executable, "-m", module, *map(str, args)]
