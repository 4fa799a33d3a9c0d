"""Wedges: one scene, many variations of it, each member a Dask task.

    warp-mpm-bubbles wedge pour.toml --vary materials.water.surface_tension=0,0.036,0.072 \
        --vary solver.cfl=0.3,0.5 --out pour_wedge

    from warp_mpm_bubbles.io.wedge import run_wedge
    run_wedge("pour.toml", {"solver.cfl": [0.3, 0.5]}, out="pour_wedge")

Every member is built and validated before anything runs. The members then go to Dask
(`pip install 'warp-mpm-bubbles[cluster]'`): by default a LocalCluster with one single-threaded
worker process per core (Warp runs CPU kernels on one thread), or a running cluster given by
its scheduler address (its workers must see the wedge folder at the same path). Dask schedules,
retries and reschedules after a lost worker; a member task always resumes from its own
checkpoint when one exists, so a retried member ends with the frames an uninterrupted run
writes, and a wedge run again over the same folder picks up where it stopped.

Layout of the wedge folder::

    DIR/.wedge.lock                    held while a wedge runs here (host and pid)
    DIR/wedge.json                     the members and their values
    DIR/<member>/<scene>.usdc          one output per member, folder named for its values
    DIR/<member>/member.log            each attempt's progress and summary
    DIR/summary.csv, summary.md        status, wall time, steps, CG iterations, message
    DIR/contact_sheet.png              one frame of every member (needs matplotlib)
    DIR/wedge.usda                     VariantSet "wedge" on /World: one variant per member
"""

from __future__ import annotations

import copy
import importlib.util
import inspect
import itertools
import json
import os
import re
import socket
import sys
import time
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path

from ..scene.checks import SceneError, _did_you_mean, underive
from ..scene.model import Scene, load_scene
from ..scene.quality import GOVERNED
from .checkpoint import checkpoint_path
from .wedge_lock import WedgeError, WedgeLock

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

MEMBER_MARK = ".wedge-member"  # in each member folder: the wedge made it, its outputs may be replaced
CLUSTER_HINT = "wedges run on Dask: pip install 'warp-mpm-bubbles[cluster]'"


@dataclass
class Member:
    index: int
    name: str  # its folder, named for its values
    values: dict  # dotted key -> value
    scene: dict  # Scene.to_dict shape, output path set to `stage`
    source: str
    stage: str  # absolute path of its USD output

    @property
    def label(self) -> str:
        return ", ".join(f"{k}={_show(v)}" for k, v in self.values.items())


@dataclass
class WedgeResult:
    folder: Path
    members: list[Member]
    results: list[dict]  # one per member, in member order (see run_member)
    wall_seconds: float
    files: dict = field(default_factory=dict)  # summary_csv, summary_md, stage, contact_sheet

    @property
    def ok(self) -> bool:
        return all(r["status"] == "ok" for r in self.results)


# ---------------------------------------------------------------------------- variations
def parse_vary(text: str) -> tuple[str, list]:
    """'solver.cfl=0.3,0.5' -> ('solver.cfl', [0.3, 0.5]). Values are TOML literals (numbers,
    true/false, "strings", [lists]); a bare word is a string."""
    key, sep, rest = text.partition("=")
    key = key.strip()
    if not sep or not key or not rest.strip():
        raise WedgeError(f"--vary {text!r}: expected KEY=V1,V2,... e.g. solver.cfl=0.3,0.5", "--vary", text)
    if not re.fullmatch(r"[A-Za-z0-9_\-]+(\.[A-Za-z0-9_\-]+)*", key):
        raise WedgeError(f"--vary {text!r}: {key!r} is not a dotted scene key like materials.water.surface_tension",
                         "--vary", text)
    return key, [parse_value(v) for v in _split_top(rest)]


def _split_top(text: str) -> list[str]:
    """Split on commas outside brackets and quotes: '[0,1],[0,2]' -> ['[0,1]', '[0,2]']."""
    parts, depth, quote, cur = [], 0, None, ""
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
            continue
        cur += ch
    return [p.strip() for p in parts + [cur]]


def parse_value(s: str):
    """A value given on a command line as a TOML literal (a number, true/false, "a string", [a list]);
    a bare word is a string. `--vary`'s values, and the convergence study's `--set`."""
    try:
        return tomllib.loads(f"v = {s}")["v"]
    except tomllib.TOMLDecodeError:
        return s  # a bare word: a string (e.g. quality=preview)


def combine(variations, zip_members: bool = False) -> list[dict]:
    """The members' values: the product of the variations, or their zip (equal lengths)."""
    items = list(variations.items()) if isinstance(variations, dict) else list(variations)
    if not items:
        raise WedgeError("a wedge needs at least one --vary KEY=V1,V2,...", "--vary", None)
    keys = [k for k, _ in items]
    dup = {k for k in keys if keys.count(k) > 1}
    if dup:
        raise WedgeError(f"--vary {sorted(dup)[0]} is given twice; put all its values in one --vary", "--vary", dup)
    for k, values in items:
        if not isinstance(values, (list, tuple)) or not values:
            raise WedgeError(f"--vary {k}: expected a non-empty list of values, got {values!r}", k, values)
    if zip_members:
        lengths = {k: len(v) for k, v in items}
        if len(set(lengths.values())) > 1:
            raise WedgeError(f"--zip needs the same number of values for every key, got "
                             f"{', '.join(f'{k}: {n}' for k, n in lengths.items())}", "--zip", lengths)
        rows = zip(*(v for _, v in items))
    else:
        rows = itertools.product(*(v for _, v in items))
    return [dict(zip(keys, row)) for row in rows]


def set_key(d: dict, key: str, value) -> None:
    """Set a dotted key (list items by index: shapes.0.max) in a scene dict. Every table on the
    way must exist (a typo is refused here); the last key may be new (a default being set) and
    from_dict refuses it if the table has no such setting."""
    parts = key.split(".")
    if parts[0] == "output" and len(parts) > 1 and parts[1] == "path":
        raise WedgeError(f"--vary {key}: the wedge sets each member's output path (use --out)", key, value)
    node, where = d, ""
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise WedgeError(f"--vary {key}: {where or 'the scene'} is a list of {len(node)}; "
                                 f"index it with 0..{len(node) - 1}, not {part!r}", key, value)
            part = int(part)
        elif not isinstance(node, dict):
            raise WedgeError(f"--vary {key}: {where} is a value, not a table", key, value)
        elif part not in node and not last:
            have = ", ".join(map(str, node)) or "nothing"
            raise WedgeError(f"--vary {key}: {where or 'the scene'} has no {part!r} (it has: {have})"
                             f"{_did_you_mean(part, list(node))}", key, value)
        if last:
            node[part] = copy.deepcopy(value)
        else:
            node, where = node[part], f"{where}.{part}" if where else str(part)


def _scene_dict(scene) -> tuple[dict, str]:
    """The base scene as a dict, with every default derived from other settings (particle radius,
    effect sizes) unset so that each member derives its own from its own values."""
    if isinstance(scene, dict):
        scene = Scene.from_dict(copy.deepcopy(scene))
    elif not isinstance(scene, Scene):
        scene = load_scene(scene)
    scene = copy.deepcopy(scene)
    for obj in _dataclasses(scene):
        underive(obj)
    return scene.to_dict(), scene.source


def _dataclasses(scene):
    for f in fields(scene):
        value = getattr(scene, f.name)
        for v in (value.values() if isinstance(value, dict) else value if isinstance(value, list) else [value]):
            if is_dataclass(v):
                yield v


def _show(v) -> str:
    if isinstance(v, (list, tuple)):
        return "x".join(_show(x) for x in v)
    return repr(v) if isinstance(v, float) else str(v)


def _member_names(rows: list[dict]) -> list[str]:
    """Folder names from the values: last key part (the full key where two share it), '=', value."""
    keys = list(rows[0])
    tails = [k.rsplit(".", 1)[-1] for k in keys]
    shown = {k: (t if tails.count(t) == 1 else k) for k, t in zip(keys, tails)}
    names = []
    for i, row in enumerate(rows):
        name = "_".join(f"{shown[k]}={_show(v)}" for k, v in row.items())
        name = re.sub(r"[^A-Za-z0-9.=+\-]+", "_", name).strip("._") or f"member{i}"
        if len(name) > 100 or name in names:  # long or clashing after cleaning: number it
            name = f"m{i:03d}_{name[:90]}"
        names.append(name)
    return names


def plan_wedge(scene, variations, out=None, zip_members: bool = False) -> tuple[Path, list[Member]]:
    """Build and validate every member; raises WedgeError/SceneError naming the member and key
    before anything runs. `scene`: a .toml path, a Scene or a scene dict."""
    base, source = _scene_dict(scene)
    rows = combine(variations, zip_members)
    stage_name = Path(base["output"]["path"]).name
    folder = Path(out) if out is not None else Path(base["output"]["path"]).with_suffix("").parent / (
        Path(stage_name).stem + "_wedge")
    folder = folder.absolute()
    members = []
    for i, (name, row) in enumerate(zip(_member_names(rows), rows)):
        d = copy.deepcopy(base)
        for key, value in row.items():
            set_key(d, key, value)
            if key == "solver.quality":  # as Scene.with_quality: the preset replaces its settings
                for g in GOVERNED:
                    if f"solver.{g}" not in row:
                        d["solver"].pop(g, None)
        stage = str(folder / name / stage_name)
        d["output"]["path"] = stage
        member = Member(i, name, row, d, source, stage)
        try:
            Scene.from_dict(copy.deepcopy(d), source=source)
        except SceneError as err:
            raise WedgeError(f"wedge member {i} '{name}' ({member.label}): {err}", err.key, err.value,
                             err.allowed) from None
        except (TypeError, ValueError) as err:  # a value of a type the scene cannot hold
            raise WedgeError(f"wedge member {i} '{name}' ({member.label}): {err}", "", None) from None
        members.append(member)
    return folder, members


# ---------------------------------------------------------------------------- the member task
def member_device(device, index: int):
    """The device of member `index`: a comma list is dealt round-robin; None or "cuda" with
    several GPUs on the worker gives member i GPU i mod n."""
    if device and "," in device:
        choices = [d.strip() for d in device.split(",") if d.strip()]
        return choices[index % len(choices)]
    if device in (None, "cuda"):
        import warp as wp

        n = wp.get_cuda_device_count()
        if n > 1 or (device == "cuda" and n == 1):
            return f"cuda:{index % n}"
    return device


def run_member(spec: dict) -> dict:
    """The Dask task of one member: run its scene, resuming from its checkpoint if one exists
    (a retried or re-run member continues rather than starts over). Bad physics and scene
    errors are returned as a failed result (retrying cannot fix them); anything else raises
    and Dask retries it."""
    import warp as wp

    wp.config.quiet = True  # older Warp; 1.19 reads log_level
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
    from ..core.simulation import SimulationError
    from .runner import run_scene

    scene = Scene.from_dict(copy.deepcopy(spec["scene"]), source=spec["source"])
    stage = Path(scene.output.path)
    stage.parent.mkdir(parents=True, exist_ok=True)
    resume = checkpoint_path(stage).exists()
    device = member_device(spec.get("device"), spec["index"])
    log_path = stage.parent / "member.log"
    with open(log_path, "a") as log:
        attempt = 1 + _attempts(log_path, spec["wedge"])
        log.write(f"== attempt {attempt} of wedge {spec['wedge']} on {socket.gethostname()} pid {os.getpid()}, "
                  f"device {device or 'default'}"
                  f"{', resuming from its checkpoint' if resume else ''}\n")
        log.flush()
        result = {"index": spec["index"], "member": spec["name"], "attempts": attempt, "resumed": resume,
                  "worker": f"{socket.gethostname()}:{os.getpid()}", "device": str(device), "steps": None,
                  "cg_iterations": None, "frames": None}
        undo = spec["before"](spec) if spec.get("before") else None  # a test hook (fault injection)
        start, cpu = time.perf_counter(), time.process_time()  # cpu < wall: other work shared the core
        try:
            run = run_scene(scene, device=device, progress=True, log=log, resume=resume, **_fresh(run_scene, resume))
        except (SimulationError, SceneError) as err:
            log.write(f"failed: {err}\n")
            return {**result, "status": "failed", "message": str(err), "wall_seconds": time.perf_counter() - start,
                    "cpu_seconds": time.process_time() - cpu}
        finally:
            if undo:
                undo()
    st = run.simulation.stats
    return {**result, "status": "ok", "message": "", "wall_seconds": run.wall_seconds,
            "cpu_seconds": time.process_time() - cpu, "steps": st.steps,
            "cg_iterations": st.cg_iterations, "frames": run.frames_written, "device": str(run.simulation.device)}


def _fresh(run_scene, resume) -> dict:
    """A member folder is the wedge's (MEMBER_MARK): a fresh attempt may replace what a killed one
    left before its first checkpoint, where run_scene refuses existing outputs (overwrite=)."""
    return {"overwrite": True} if not resume and "overwrite" in inspect.signature(run_scene).parameters else {}


def _attempts(log_path: Path, wedge: str) -> int:
    """Attempts at this member in this wedge run (a re-run wedge counts afresh)."""
    try:
        return sum(line.startswith("== attempt") and f" of wedge {wedge} " in line
                   for line in log_path.read_text().splitlines())
    except OSError:
        return 0


# ---------------------------------------------------------------------------- the wedge
def run_wedge(scene, variations, *, out=None, zip_members: bool = False, workers: int | None = None,
              scheduler=None, device: str | None = None, retries: int = 2, frame: int | None = None,
              progress: bool = True, before_member=None, log=None) -> WedgeResult:
    """Run every member of a wedge on Dask and write the summary, contact sheet and wedge.usda.

    scene: a .toml path, a Scene or a scene dict; variations: {dotted key: [values]} (or a list
    of (key, values)). scheduler: None (a LocalCluster of `workers` single-threaded processes,
    default one per core), a scheduler address "tcp://host:port", or a distributed.Client.
    before_member(spec), run in the worker before a member (tests use it to inject faults),
    may return a callable run after it.
    """
    log = log or sys.stderr
    folder, members = plan_wedge(scene, variations, out, zip_members)
    last = min(m.scene["output"]["frames"] for m in members)
    if frame is not None and not 0 <= frame <= last:
        raise WedgeError(f"--frame {frame}: the contact sheet frame must be within 0..{last} (the members' frames)",
                         "--frame", frame)
    _refuse_foreign_files(members)
    if importlib.util.find_spec("distributed") is None:
        raise WedgeError(CLUSTER_HINT, "scheduler", None)
    start = time.perf_counter()
    with WedgeLock(folder):
        with dask_client(workers, scheduler) as client:  # connected before anything is written
            _claim_member_folders(members)
            _write_manifest(folder, members)
            wedge = f"{time.strftime('%Y%m%dT%H%M%S')}-{os.urandom(3).hex()}"  # tells this run's attempts from earlier ones
            specs = [{"index": m.index, "name": m.name, "scene": m.scene, "source": m.source, "device": device,
                      "before": before_member, "wedge": wedge} for m in members]
            if progress:
                log.write(f"wedge of {len(members)} members to {folder} on {_describe(client)}\n")
            results = _gather(client, specs, members, retries, wedge, log if progress else None)
        result = WedgeResult(folder, members, results, time.perf_counter() - start)
        from .wedge_report import write_reports

        result.files = write_reports(result, frame=frame, log=log if progress else None)
    return result


def _refuse_foreign_files(members):
    """A member folder that holds files but no MEMBER_MARK holds someone else's files, which a
    member run would replace: refuse before anything runs."""
    for m in members:
        d = Path(m.stage).parent
        if d.exists() and any(d.iterdir()) and not (d / MEMBER_MARK).exists():
            raise WedgeError(f"wedge member {m.index} '{m.name}': {d} holds files this wedge did not write; "
                             f"move them or choose another --out", "--out", str(d))


def _claim_member_folders(members):
    for m in members:
        Path(m.stage).parent.mkdir(parents=True, exist_ok=True)
        (Path(m.stage).parent / MEMBER_MARK).touch()


def _write_manifest(folder: Path, members):
    data = {"members": [{"name": m.name, "values": m.values, "stage": os.path.relpath(m.stage, folder)}
                        for m in members]}
    tmp = folder / "wedge.json.tmp"
    tmp.write_text(json.dumps(data, indent=1, default=str))
    os.replace(tmp, folder / "wedge.json")


class dask_client:
    """A Client for the wedge (or any batch of runs: benchmarks/validation/accuracy_vs_time.py), and the
    LocalCluster it started, one single-threaded worker process per core (closed on exit).
    scheduler: None, an address, or a Client (used as is, left open)."""

    def __init__(self, workers=None, scheduler=None):
        self.workers, self.scheduler = workers, scheduler
        self.cluster = self.client = None

    def __enter__(self):
        import logging

        from distributed import Client, LocalCluster

        if self.scheduler is not None and hasattr(self.scheduler, "submit"):
            return self.scheduler  # the caller's Client: theirs to close
        if self.scheduler is not None:
            try:
                self.client = Client(self.scheduler, timeout="20s")
            except (OSError, TimeoutError) as err:
                raise WedgeError(f"--scheduler {self.scheduler}: cannot connect ({err}); start one with "
                                 f"`dask scheduler` and `dask worker ADDRESS --nthreads 1`",
                                 "--scheduler", self.scheduler) from None
            return self.client
        n = self.workers or os.cpu_count() or 1
        self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                    silence_logs=logging.ERROR)
        self.client = Client(self.cluster)
        return self.client

    def __exit__(self, *exc):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _describe(client) -> str:
    workers = client.scheduler_info().get("workers", {})
    threads = sum(w.get("nthreads", 0) for w in workers.values())
    return f"{len(workers)} Dask workers ({threads} threads) at {client.scheduler.address}"


def _gather(client, specs, members, retries, wedge, log) -> list[dict]:
    """Submit every member (Dask retries failed tasks and reschedules those of a lost worker);
    collect each as it finishes. A member whose task still errors is reported, not raised."""
    from distributed import as_completed

    futures = client.map(run_member, specs, retries=retries, pure=False,
                         key=[f"wedge-member-{m.name}-{os.urandom(4).hex()}" for m in members])
    index = {f.key: i for i, f in enumerate(futures)}
    results = [None] * len(members)
    for fut in as_completed(futures):
        m = members[index[fut.key]]
        try:
            r = fut.result()
        except Exception as err:  # noqa: BLE001 - out of retries, or its workers kept dying
            r = {"index": m.index, "member": m.name, "status": "error", "message": f"{type(err).__name__}: {err}",
                 "wall_seconds": None, "cpu_seconds": None, "steps": None, "cg_iterations": None, "frames": None,
                 "attempts": _attempts(Path(m.stage).parent / "member.log", wedge), "resumed": None, "worker": "",
                 "device": ""}
        r["values"] = m.values
        results[m.index] = r
        if log:
            wall = f"{r['wall_seconds']:.1f} s" if r["wall_seconds"] is not None else "-"
            log.write(f"  [{sum(x is not None for x in results)}/{len(members)}] {m.name}: {r['status']} "
                      f"({wall}{', attempt ' + str(r['attempts']) if (r['attempts'] or 1) > 1 else ''})"
                      f"{': ' + r['message'].splitlines()[0] if r['message'] else ''}\n")
            log.flush()
    return results


# ---------------------------------------------------------------------------- command line
def add_wedge_arguments(parser) -> None:
    parser.add_argument("scene", help="scene file (.toml)")
    parser.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                        help="a dotted scene key and its values, e.g. materials.water.surface_tension=0,0.072 "
                             "(repeat for more keys; members are the product of all)")
    parser.add_argument("--zip", action="store_true", help="pair the i-th values of every --vary instead of the product")
    parser.add_argument("--out", default=None, help="wedge folder (default: beside the scene's output, <name>_wedge)")
    parser.add_argument("--workers", type=int, default=None,
                        help="local Dask worker processes, one thread each (default: one per core)")
    parser.add_argument("--scheduler", default=None, help="address of a running Dask scheduler, tcp://HOST:PORT")
    parser.add_argument("--device", default=None,
                        help='Warp device per member: "cpu", "cuda" (member i on GPU i mod n) or a list cuda:0,cuda:1')
    parser.add_argument("--retries", type=int, default=2, help="Dask retries of a member whose task raises (default 2)")
    parser.add_argument("--frame", type=int, default=None, help="frame shown in the contact sheet (default: the last)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def wedge_command(args) -> int:
    """`warp-mpm-bubbles wedge`: 0 when every member finished, 1 when one failed, 2 on bad input."""
    if args.workers is not None and args.workers < 1:
        print(f"error: --workers {args.workers}: give at least 1", file=sys.stderr)
        return 2
    try:
        variations = [parse_vary(v) for v in args.vary]
        result = run_wedge(args.scene, variations, out=args.out, zip_members=args.zip, workers=args.workers,
                           scheduler=args.scheduler, device=args.device, retries=args.retries, frame=args.frame,
                           progress=not args.quiet)
    except SceneError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    failed = [r for r in result.results if r["status"] != "ok"]
    if not args.quiet and result.files.get("summary_md"):
        print(Path(result.files["summary_md"]).read_text())
    print(f"{len(result.members) - len(failed)}/{len(result.members)} members finished in "
          f"{result.wall_seconds:.1f} s; summary: {result.files.get('summary_md')}")
    return 1 if failed else 0
