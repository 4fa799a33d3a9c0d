"""Write docs/validation.md from the saved results in benchmarks/results/: every validation case with
its reference, our figures, the bound, the command that reproduces it, and the date and commit of
the run (from the result's provenance; files saved before provenance was recorded say so).

    python -m benchmarks.report            # rewrite docs/validation.md
    python -m benchmarks.report --check    # exit 1 if docs/validation.md is out of date

No figure on the page is typed by hand: each comes from a result file, so rerunning a benchmark and
then this script keeps the page true. tests/test_docs.py fails when the committed page differs from
what this script writes. The bounds are stated here, each with where it comes from (a test, or the
bar the work was held to).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from benchmarks.harness import RESULTS, ROOT, markdown_table
from benchmarks.validation.rising_bubble_leak import TANK_WIDTH, wall_factor

PAGE = ROOT / "docs" / "validation.md"
NOT_RECORDED = "not recorded"


def _load(rel: str) -> dict:
    return json.loads((RESULTS / rel).read_text())


def _pct(x: float, digits: int = 2) -> str:
    return f"{100 * x:+.{digits}f}%"


def provenance(data: dict) -> tuple[str, str]:
    """(date, commit) of a result: its harness provenance, else the older files' own fields."""
    prov = data.get("provenance") or {}
    date = prov.get("date") or data.get("date") or (data.get("meta") or {}).get("date") or NOT_RECORDED
    commit = prov.get("commit") or data.get("commit") or data.get("code") or NOT_RECORDED
    if prov.get("dirty"):
        commit += " with uncommitted changes"
    return str(date)[:10] if date != NOT_RECORDED else date, str(commit)


def section(title, reference, command, rel, table, note="") -> str:
    date, commit = provenance(_load(rel))
    lines = [f"## {title}", "", f"**Reference:** {reference}", "",
             f"**Command:** `{command}` (result: [`benchmarks/results/{rel}`](../benchmarks/results/{rel}); "
             f"date {date}, commit {commit})", "", table.rstrip("\n")]
    if note:
        lines += ["", note]
    return "\n".join(lines) + "\n"


def torricelli() -> str:
    from benchmarks.validation.torricelli import TESTED_CV, TESTED_DX

    d = _load("torricelli/cpu.json")
    rows = []
    low, high = TESTED_CV
    for c in d["cases"]:
        tested = math.isclose(c["dx"], TESTED_DX)
        bound = f"{low} to {high} (tests/test_open_walls.py)" if tested else "below 1"
        ok = low < c["cv"] < high if tested else c["cv"] < 1.0
        rows.append([f"{1000 * c['dx']:g} mm", f"{c['cv']:.4f}", _pct(c["cv"] - 1.0), bound, "yes" if ok else "NO"])
    limit = d.get("cv", {}).get("limit")
    note = f"Richardson extrapolation of the finest three: Cv = {limit:.4f}." if limit and math.isfinite(limit) else ""
    return section("Torricelli: a tank draining through a slot", "Bernoulli along the free jet, "
                   "v = sqrt(2 g h): the velocity coefficient Cv = 1", "python -m benchmarks.validation.torricelli",
                   "torricelli/cpu.json", markdown_table(["cell", "Cv", "error", "bound", "within"], rows), note)


def static_bubble() -> str:
    d = _load("static_bubble_laplace/cpu.json")
    rows = [[f"{r['cells_per_radius']:g}", _pct(r["jump_error_settled"]), f"{100 * r['jump_error_spread']:.2f}%",
             "none: a convergence study"] for r in d["rows"]]
    return section("Laplace jump of a bubble at rest (2D, Hysing's fluids, no gravity)",
                   "Laplace's law, the jump sigma / R", "python -m benchmarks.validation.static_bubble_laplace",
                   "static_bubble_laplace/cpu.json",
                   markdown_table(["cells per radius", "error, settled", "spread", "bound"], rows))


def cavity() -> str:
    d = _load("cavity_collapse/cpu.json")
    bounds = {8: 0.035, 16: 0.012}  # tests/test_cavity.py: COARSE_BOUND and GAS_BOUNDS[0.5]
    rows = []
    for r in d["2d"]["runs"]:
        b = bounds.get(r["cells_per_radius"])
        rows.append(["2D", r["cells_per_radius"], _pct(r["gas_0.5"]), _pct(r["flux_0.5"]),
                     f"within {100 * b:g}% (tests/test_cavity.py)" if b else "none",
                     ("yes" if abs(r["gas_0.5"]) <= b else "NO") if b else "-"])
    for r in d.get("3d", {}).get("runs", []):
        rows.append(["3D", r["cells_per_radius"], _pct(r["gas_0.5"]), "-", "none", "-"])
    note = f"Observed order of the 2D error by the gas's volume: {d['2d']['order_gas_0.5']:.2f}."
    return section("Near-vacuum cavity collapse (gas at 1 Pa)", "the Rayleigh-Plesset equation for the "
                   "cylinder in its annulus (2D) or Rayleigh's sphere (3D), integrated by RK4: the time to R0/2",
                   "python -m benchmarks.validation.cavity_collapse 2d", "cavity_collapse/cpu.json",
                   markdown_table(["dim", "cells per radius", "time error, by the gas", "by the liquid's flux",
                                   "bound", "within"], rows), note)


# The bar the convergence work was held to: the finest two grids agree within these, relative.
BAR = {"rise_speed_max": 0.02, "centroid_end": 0.01}


def convergence(case: str, title: str) -> str:
    d = _load("convergence/cpu.json")
    c = d["cases"][case]
    rows = []
    for name, m in c["metrics"].items():
        if "reference" not in m:
            continue
        bar = BAR.get(name)
        a, b = m["values"][-2:]
        gap = abs(b - a) / abs(b)
        rows.append([name.replace("_", " "), f"{m['reference']:g}",
                     " / ".join(f"{v:.4f}" for v in m["values"]), " / ".join(_pct(e, 1) for e in m["error"]),
                     f"{100 * gap:.2f}%", f"within {100 * bar:g}%" if bar else "none",
                     ("yes" if gap <= bar else "NO") if bar else "-"])
    source = next(m["source"] for m in c["metrics"].values() if "source" in m)
    levels = " / ".join(str(n) for n in c["levels"])
    return section(title, source, f"python -m benchmarks.validation.convergence --cases {case}", "convergence/cpu.json",
                   markdown_table(["metric", "reference", f"ours at {levels} {c['unit']}", "error against the reference",
                                   "finest two differ by", "bound", "within"], rows),
                   "The bound is on the grid convergence: the finest two grids' results agree within it.")


def leak() -> str:
    rows = []
    for rel in ("rising_bubble_leak/cpu_2d.json", "rising_bubble_leak/cpu_3d_cap_7.json"):
        d = _load(rel)
        r = next(x for x in d["results"] if x["variant"] == "own")
        d_e = r["frames"][0]["d_e"] if isinstance(r["frames"], list) else 0.02
        speed = ""
        if d["dim"] == 3:
            ref = 0.711 * math.sqrt(9.81 * d_e) * wall_factor(d_e / TANK_WIDTH[3])
            speed = f"{r['rise_speed']:.3f} m/s against {ref:.3f} ({_pct(r['rise_speed'] / ref - 1.0, 0)})"
        rows.append([f"{d['dim']}D, {d['cells_per_radius']} cells per radius", _pct(r["liquid_in_gas_max"]).lstrip("+"),
                     "under 1%", "yes" if r["liquid_in_gas_max"] < 0.01 else "NO",
                     f"{100 * r['largest_bubble_end']:.0f}%", speed or "-"])
    return section("A rising bubble keeps the water out", "no water inside the bubble; in 3D, Davies & Taylor's "
                   "rise speed 0.711 sqrt(g d_e) with the tank's wall factor 1.13 exp(-d/D) (Wallis)",
                   "python -m benchmarks.validation.rising_bubble_leak", "rising_bubble_leak/cpu_2d.json",
                   markdown_table(["run", "water in the gas, most", "bound", "within", "largest bubble at the end",
                                   "rise speed"], rows),
                   "The 3D row's result: [`benchmarks/results/rising_bubble_leak/cpu_3d_cap_7.json`]"
                   f"(../benchmarks/results/rising_bubble_leak/cpu_3d_cap_7.json), date "
                   f"{provenance(_load('rising_bubble_leak/cpu_3d_cap_7.json'))[0]}, command "
                   f"`{_load('rising_bubble_leak/cpu_3d_cap_7.json')['command']}`.")


def pour_voids() -> str:
    d = _load("pour_voids/cpu.json")
    most = max(d["voids_most_in_frame"])
    table = markdown_table(["frames", "void cells, most at any step", "bound", "within"],
                           [[d["frames"], most, "exactly 0", "yes" if most == 0 else "NO"]])
    return section("No voids in the pour", "a particle-free cell inside the liquid is a void; none should reach "
                   "the pressure solve", f"python -m benchmarks.validation.pour_voids --frames {d['frames']}",
                   "pour_voids/cpu.json", table)


def render() -> str:
    head = ("# Validation\n\n"
            "*Generated by `python -m benchmarks.report` from `benchmarks/results/`; do not edit by\n"
            "hand: rerun a benchmark, then the report.* Each case names its reference, our figures, the bound\n"
            "it is held to (where there is one), the command that reproduces it, and the date and commit of\n"
            "the saved run. A quick check on your machine: `warp-mpm-bubbles validate`. The methods and\n"
            "further measurements: [physics.md](physics.md), [convergence.md](convergence.md).\n")
    parts = [head, torricelli(), static_bubble(), cavity(),
             convergence("hysing_2d", "Rising bubble in a closed 2D tank (Hysing et al., test case 1)"),
             convergence("adelsberger_3d", "Rising bubble in a closed 3D tank (Adelsberger et al., test case 1)"),
             leak(), pour_voids()]
    return "\n".join(parts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/validation.md differs from what it would write")
    args = ap.parse_args(argv)
    text = render()
    if args.check:
        same = PAGE.exists() and PAGE.read_text() == text
        print(f"{PAGE.relative_to(ROOT)} is {'up to date' if same else 'out of date: run python -m benchmarks.report'}")
        return 0 if same else 1
    PAGE.write_text(text)
    print(f"wrote {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
