"""`warp-mpm-bubbles validate`: run the validation cases (validation_cases.py) on this machine and
print one table, case by case: the reference, our figure, the error, the bound, pass or FAIL.

    warp-mpm-bubbles validate            # the quick set: seconds once Warp's kernels are compiled
    warp-mpm-bubbles validate --full     # the same cases on finer grids: about a minute on two cores
    warp-mpm-bubbles validate --cases free_fall,hydrostatic

Exit 0 when every case passes, 1 when any fails, 2 for a case name it does not know.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path


def add_validate_arguments(parser: argparse.ArgumentParser) -> None:
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="the quick cases at their small size (the default)")
    size.add_argument("--full", action="store_true", help="the same cases on finer grids (about a minute on two CPU cores)")
    parser.add_argument("--cases", default=None,
                        help="comma-separated case names to run (default: all); --cases list names them")
    parser.add_argument("--device", default="cpu", help='Warp device, e.g. "cpu" or "cuda:0" (default cpu)')


def format_error(row) -> str:
    return f"{100 * row.error:+.2f}%" if row.unit == "%" else f"{row.error:.3f} {row.unit}"


def format_bound(row) -> str:
    if row.unit != "%":
        return f"{row.low:g} to {row.high:g} {row.unit}" if row.low else f"under {row.high:g} {row.unit}"
    if row.low == -row.high:
        return f"within {100 * row.high:g}%"
    return f"{100 * row.low:+g}% to {100 * row.high:+g}%"


def table(rows) -> str:
    """The rows as an aligned plain-text table (every column as wide as its widest entry)."""
    head = ["case", "reference", "ours", "error", "bound", "pass"]
    body = [[r.case, r.reference, r.ours, format_error(r), format_bound(r), "pass" if r.passed else "FAIL"] for r in rows]
    widths = [max(len(line[i]) for line in [head, *body]) for i in range(len(head))]
    fmt = lambda line: "  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip()  # noqa: E731
    return "\n".join([fmt(head), fmt(["-" * w for w in widths]), *map(fmt, body)])


def chosen_cases(names: str | None, cases: dict) -> list[str]:
    """The case names --cases asks for, in the table's order; ValueError names an unknown one."""
    if names is None:
        return [n for n, (_, quick, _) in cases.items() if quick]
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    unknown = [n for n in wanted if n not in cases]
    if unknown or not wanted:
        raise ValueError(f"--cases {names!r}: unknown case {', '.join(unknown) or '(none given)'}; "
                         f"choose from {', '.join(cases)}")
    return [n for n in cases if n in wanted]


def validate_command(args) -> int:
    from .cli import start_warp
    from .core.simulation import SimulationError
    from .validation_cases import CASES, Row

    if args.cases is not None and args.cases.strip() == "list":
        for name, (fn, _, _) in CASES.items():
            print(f"{name:12s} {(fn.__doc__ or '').split(chr(10))[0]}")
        return 0
    try:
        names = chosen_cases(args.cases, CASES)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    start_warp(quiet=True)
    from .io.devices import DeviceError, check_device

    try:  # a device this machine lacks is refused before any case runs, naming the ones it has
        check_device(args.device)
    except DeviceError as err:
        print(f"error: --device: {err}", file=sys.stderr)
        return 2
    rows, start = [], time.perf_counter()
    size = "full" if args.full else "quick"
    print(f"validating {len(names)} cases ({size}) on {args.device}: {', '.join(names)}", flush=True)
    with tempfile.TemporaryDirectory(prefix="warp_mpm_validate_") as work:
        for name in names:
            t0 = time.perf_counter()
            try:
                new = CASES[name][0](Path(work), args.device, fine=args.full)
            except SimulationError as err:  # the case's run stopped (a NaN, a step limit): it fails
                new = [Row(name, "-", f"stopped: {' '.join(str(err).split())[:60]}", float("nan"), 0.0, 0.0)]
            rows.extend(new)
            print(f"  {name}: {time.perf_counter() - t0:.1f} s, "
                  + ", ".join("pass" if r.passed else "FAIL" for r in new), flush=True)
    print()
    print(table(rows))
    failed = [r for r in rows if not r.passed]
    print(f"\n{len(rows) - len(failed)} of {len(rows)} passed in {time.perf_counter() - start:.0f} s"
          + (f"; FAILED: {', '.join(r.case for r in failed)}" if failed else ""))
    return 1 if failed else 0
