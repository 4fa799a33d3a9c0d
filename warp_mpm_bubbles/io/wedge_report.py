"""What a wedge leaves beside its members: the summary table (CSV and Markdown), a contact sheet
of one frame per member, and wedge.usda (wedge_usd.py)."""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path

import numpy as np


COLUMNS = ("member", "values", "status", "wall_s", "cpu_s", "steps", "cg_iterations", "frames", "attempts", "resumed",
           "device", "message")


def write_reports(result, frame=None, log=None) -> dict:
    """summary.csv, summary.md, wedge.usda and (with matplotlib) contact_sheet.png."""
    from .wedge_usd import write_wedge_stage

    folder = Path(result.folder)
    files = dict(zip(("summary_csv", "summary_md"), write_summary(result.members, result.results, folder)))
    files["stage"] = write_wedge_stage(folder, result.members, result.results)
    try:
        files["contact_sheet"] = contact_sheet(result.members, result.results, folder / "contact_sheet.png", frame)
    except ImportError:
        if log:
            log.write("no contact sheet: it needs matplotlib (pip install 'warp-mpm-bubbles[plots]')\n")
    return files


def _rows(members, results):
    for m, r in zip(members, results):
        wall, cpu = r.get("wall_seconds"), r.get("cpu_seconds")
        yield {"member": m.name, "values": m.label, "status": r["status"],
               "wall_s": "" if wall is None else f"{wall:.2f}", "cpu_s": "" if cpu is None else f"{cpu:.2f}",
               "steps": _blank(r.get("steps")), "cg_iterations": _blank(r.get("cg_iterations")),
               "frames": _blank(r.get("frames")), "attempts": _blank(r.get("attempts")),
               "resumed": _blank(r.get("resumed")), "device": r.get("device") or "",
               "message": " ".join((r.get("message") or "").split())}


def _blank(v):
    return "" if v is None else v


def write_summary(members, results, folder) -> tuple[Path, Path]:
    """One row per member, in member order; written to temporary names and renamed."""
    folder = Path(folder)
    rows = list(_rows(members, results))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    md = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    md += ["| " + " | ".join(str(row[c]).replace("|", "\\|") for c in COLUMNS) + " |" for row in rows]
    ok = sum(r["status"] == "ok" for r in results)
    text = f"# Wedge: {ok}/{len(results)} members finished\n\n" + "\n".join(md) + "\n"
    paths = folder / "summary.csv", folder / "summary.md"
    for path, content in zip(paths, (buf.getvalue(), text)):
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(content)
        os.replace(tmp, path)
    return paths


def contact_sheet(members, results, png_path, frame=None, axes=(0, 1), dpi=100) -> Path:
    """One panel per member: its particles at `frame` (default: each member's last) projected on
    `axes`, coloured by material (as preview.py), all panels on the same extent; a member without
    that frame shows its status and message instead."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shots = [_frame_of(m, frame) for m in members]
    drawn = [p for p in shots if p is not None]
    if drawn:
        pos = np.concatenate([p["positions"][:, axes] for _, p in drawn])
        lo, hi = pos.min(axis=0), pos.max(axis=0)
    else:
        lo, hi = np.zeros(2), np.ones(2)
    pad = 0.02 * max(hi - lo)
    aspect = (hi[1] - lo[1] + 2 * pad) / max(hi[0] - lo[0] + 2 * pad, 1e-9)
    cols = math.ceil(math.sqrt(len(members)))
    rows = math.ceil(len(members) / cols)
    fig, axs = plt.subplots(rows, cols, figsize=(3.0 * cols, 3.0 * aspect * rows + 0.6), squeeze=False)
    palette = ("#3373e6", "#f2a81d", "#e64b3c", "#3cbf6e")
    for ax, m, r, shot in zip(axs.flat, members, results, shots):
        values = "\n".join(f"{k.rsplit('.', 1)[-1]} = {v}" for k, v in m.values.items())
        ax.set_title(f"{values}\n{r['status']}", fontsize=8)
        if shot is None:
            msg = (r.get("message") or f"no frame {frame}")[:120]
            ax.text(0.5, 0.5, msg, ha="center", va="center", wrap=True, fontsize=7, transform=ax.transAxes)
        else:
            f, p = shot
            size = float(np.clip(2e3 / max(len(p["positions"]), 1), 0.5, 8.0))  # few particles: bigger dots
            for mat in np.unique(p["proto_indices"]):  # later materials (gas, foam) on top, larger
                pts = p["positions"][p["proto_indices"] == mat][:, axes]
                ax.scatter(pts[:, 0], pts[:, 1], s=size * (1 if mat == 0 else 3), color=palette[mat % len(palette)],
                           linewidths=0)
            ax.text(0.02, 0.98, f"frame {f}", fontsize=7, va="top", transform=ax.transAxes)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    for ax in list(axs.flat)[len(members):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(png_path, dpi=dpi)
    plt.close(fig)
    return Path(png_path)


def _frame_of(member, frame):
    """(frame number, {"positions", "proto_indices"}) of a member's output at `frame` (default its
    last), or None if it has no such frame. Reads that one frame (one clip layer), where
    read_frames would load every frame of every member."""
    from pxr import Sdf, Usd, UsdGeom

    from .usd_output import INSTANCER, POINTS

    path = str(member.stage)
    if not Path(path).exists():
        return None
    cached = Sdf.Layer.Find(path)
    if cached:
        cached.Reload()  # as read_frames: the file is replaced on every frame
    stage = Usd.Stage.Open(path)
    inst = UsdGeom.PointInstancer.Get(stage, INSTANCER)
    prim = inst.GetPrim() if inst else UsdGeom.Points.Get(stage, POINTS).GetPrim()
    names = ("positions", "protoIndices") if inst else ("points", "primvars:materialIndex")
    if not prim:
        return None
    times = [int(t) for t in prim.GetAttribute(names[0]).GetTimeSamples()]
    f = (max(times) if times else None) if frame is None else frame
    if f not in times:
        return None
    return f, {"positions": np.asarray(prim.GetAttribute(names[0]).Get(f)),
               "proto_indices": np.asarray(prim.GetAttribute(names[1]).Get(f))}
