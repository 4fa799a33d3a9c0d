"""Wall time of one wedge on 1 Dask worker and on N (default 2) in the same run, outputs compared.

    python -m benchmarks.performance.wedge_workers                       # 4 members, 1 worker then 2
    python -m benchmarks.performance.wedge_workers --workers 1,2,4 --cells 24 --frames 12
    python -m benchmarks.performance.wedge_workers --quick               # 8 cells per a, 2 frames

The wedge: the 2D dam break of benchmarks/cases.py (column a = 0.1 m, --cells per a, 60 fps, --frames
frames) over solver.cfl = 0.3, 0.5 x materials.water.surface_tension = 0, 0.072 (4 members).
Each worker count gets its own LocalCluster (one single-threaded process per worker) and wedge
folder; the wall time covers everything run_wedge does (cluster start, Warp start in every
worker, the members, the summary, contact sheet and wedge.usda). The members' particle positions
must be identical, bit for bit, between worker counts. The machine's load average is printed:
other processes on the same cores share them with the workers.
Writes benchmarks/results/wedge_workers/<device>.{json,md}.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import harness
from benchmarks.cases import dam_break_2d

VARY = {"solver.cfl": [0.3, 0.5], "materials.water.surface_tension": [0.0, 0.072]}


def scene(cells: int, frames: int, out):
    s = dam_break_2d(a=0.1, cells_per_a=cells, length=4.0, out=out)
    s.output.fps, s.output.frames = 60.0, frames
    return s.validate()


def main(argv=None) -> int:
    ap = harness.parser(__doc__.split("\n")[0], quick="8 cells per a, 2 frames per member")
    ap.add_argument("--workers", default="1,2", help="comma-separated worker counts, run in this order")
    ap.add_argument("--cells", type=int, default=16, help="cells per column width a (default 16)")
    ap.add_argument("--frames", type=int, default=8, help="frames per member (default 8)")
    args = ap.parse_args(argv)
    if args.quick:
        args.cells, args.frames = 8, 2
    counts = [int(w) for w in args.workers.split(",")]
    from warp_mpm_bubbles.io.usd_output import read_frames
    from warp_mpm_bubbles.io.wedge import run_wedge

    rows, outputs = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        base = scene(args.cells, args.frames, Path(tmp) / "dam.usdc")
        for n in counts:
            load = os.getloadavg()[0]
            cpu0 = time.process_time()
            result = run_wedge(base, VARY, out=Path(tmp) / f"w{n}", workers=n, device=args.device, progress=False)
            if not result.ok:
                raise SystemExit(f"{n} workers: {[r['message'] for r in result.results if r['status'] != 'ok']}")
            member_s = [r["wall_seconds"] for r in result.results]
            member_cpu = sum(r["cpu_seconds"] for r in result.results)
            rows.append({"workers": n, "wall_s": result.wall_seconds, "member_s_sum": sum(member_s),
                         "member_s_max": max(member_s),
                         "member_cpu_s_sum": member_cpu, "load_before": load,
                         "steps": [r["steps"] for r in result.results]})
            outputs[n] = [read_frames(m.stage)["frames"] for m in result.members]
            print(f"{n} worker(s): {result.wall_seconds:6.1f} s wall for {len(result.members)} members "
                  f"(members {sum(member_s):.1f} s wall / {member_cpu:.1f} s CPU summed, longest {max(member_s):.1f} s; load average before "
                  f"{load:.1f}; client CPU {time.process_time() - cpu0:.1f} s)", flush=True)
    first = counts[0]
    for n in counts[1:]:
        for a, b in zip(outputs[first], outputs[n]):
            assert sorted(a) == sorted(b)
            for f in a:
                np.testing.assert_array_equal(a[f]["positions"], b[f]["positions"])
    for r in rows:
        r["speedup_vs_first"] = rows[0]["wall_s"] / r["wall_s"]
        print(f"  {r['workers']} worker(s): {r['wall_s']:.1f} s, speed-up {r['speedup_vs_first']:.2f}x over "
              f"{first} worker(s)")
    print("outputs identical bit for bit across worker counts")
    meta = {"cells_per_a": args.cells, "frames": args.frames, "members": 4}
    md = [f"4 members, 2D dam break {args.cells} cells per a, {args.frames} frames.\n",
          "| workers | wall (s) | members summed (s) | members' CPU summed (s) | longest member (s) | load before | "
          "speed vs the first row |", "|---|---|---|---|---|---|---|"]
    md += [f"| {r['workers']} | {r['wall_s']:.1f} | {r['member_s_sum']:.1f} | {r['member_cpu_s_sum']:.1f} | {r['member_s_max']:.1f} | "
           f"{r['load_before']:.1f} | {r['speedup_vs_first']:.2f} |" for r in rows]
    harness.write_result("wedge_workers", args, {"meta": meta, "rows": rows}, "\n".join(md),
                         title="Wedge wall time by worker count")
    return 0


if __name__ == "__main__":
    sys.exit(main())
