"""Who owns an output: the lock a run holds on it, the marker naming the files the project wrote,
and the errors that refuse to touch anything else.

An output is ``<stem>.usdc`` (any USD suffix) plus its ``<stem>_frames/`` folder. While a run writes
it, ``<stem>.usdc.lock`` beside the stage holds the writer's host, pid and start time. The folder
carries a marker (``.warp_mpm_bubbles``, the run id) and the top layer records the same run id, so
a later run knows which files are the project's: only those are ever deleted, and only when asked
(``--overwrite``). Every temporary file has a per-process name, so two writers can never rename
each other's half-written files.
"""

from __future__ import annotations

import errno
import json
import os
import re
import secrets
import shutil
import socket
import sys
import time
from pathlib import Path

from ..core.simulation import SimulationError
from .streams import RUN_LOG

MARKER = ".warp_mpm_bubbles"
LAYER_KEY = "warp_mpm_bubbles"  # customLayerData key of the top layer and of every frame layer
# Our temp names, and USD's own temp beside them (Export writes <stem>.XXXXXX, then renames).
_TEMP = re.compile(r".+\.tmp-\d+-[0-9a-f]{6}\.(usdc|usda|usd|npz|json|[A-Za-z0-9]{6})$")
_CHOICES = ("choose one: --overwrite to replace it (overwrite=True in run_scene), --resume to continue "
            "it from its last checkpoint, or another --stage-path")


class OutputError(SimulationError):
    """The output cannot be written as asked; nothing was changed unless the message says so."""

    exit_code = 2  # a refusal before any work, like a bad scene


class OutputLocked(OutputError):
    """Another run holds the output's lock."""


class OutputExists(OutputError):
    """The output exists and neither overwrite nor resume was asked for."""


class ForeignFiles(OutputError):
    """The output holds files this project did not write; they are never deleted."""


class OutputWriteError(OutputError):
    """Writing a frame or checkpoint failed (a full disk, a quota, an I/O error)."""

    exit_code = 1


def frames_dir(stage_path) -> Path:
    stage_path = Path(stage_path)
    return stage_path.with_name(stage_path.stem + "_frames")


def lock_path(stage_path) -> Path:
    stage_path = Path(stage_path)
    return stage_path.with_name(stage_path.name + ".lock")


def temp_path(path: Path) -> Path:
    """A name no other process uses; the suffix is kept (USD picks the file format from it)."""
    return path.with_name(f"{path.stem}.tmp-{os.getpid()}-{secrets.token_hex(3)}{path.suffix}")


def is_own_file(name: str, stem: str) -> bool:
    """Names the project writes in <stem>_frames/: frame layers, manifest, checkpoints, run log, marker, temps."""
    return (name in (MARKER, "manifest.usdc", "manifest.usda", "checkpoint.npz", "checkpoint.previous.npz", RUN_LOG)
            or re.fullmatch(re.escape(stem) + r"\.\d{6,}\.(usdc|usda)", name) is not None
            or _TEMP.fullmatch(name) is not None)


def frame_number(name: str, stem: str) -> int | None:
    m = re.fullmatch(re.escape(stem) + r"\.(\d{6,})\.(usdc|usda)", name)
    return int(m.group(1)) if m else None


def new_run_id() -> str:
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + "-" + secrets.token_hex(4)


def _now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())


def _proc_start(pid: int) -> int | None:
    """The process's start time in clock ticks (Linux), to tell a reused pid from the lock holder."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return None if fields[0] == "Z" else int(fields[19])  # a zombie has finished
    except (OSError, IndexError, ValueError):
        return None


def pid_alive(pid: int, proc_start: int | None = None) -> bool:
    if os.name == "nt":
        return True  # os.kill(pid, 0) would terminate it there: never judge a lock stale
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's live process
    except OverflowError:
        return False
    if os.path.exists(f"/proc/{pid}"):
        now = _proc_start(pid)
        return now is not None and (proc_start is None or now == proc_start)
    return True


def _read_json(path: Path) -> dict | None:
    try:
        data = json.loads(Path(path).read_text())
        return data if isinstance(data, dict) else None
    except (OSError, ValueError):
        return None


def describe_holder(h: dict) -> str:
    return f"pid {h.get('pid', '?')} on host {h.get('host', '?')}, running since {h.get('started', '?')}"


class OutputLock:
    """The lock file <stage>.lock, created with O_CREAT|O_EXCL; a holder that died on this host is
    detected (pid gone, or reused by another process) and its lock taken over."""

    def __init__(self, stage_path, run_id: str | None = None, log=None):
        self.path = lock_path(stage_path)
        self.run_id = run_id or new_run_id()
        self.log = log
        self.held = False
        self.created_dirs: list = []  # set by acquire

    def _info(self) -> dict:
        pid = os.getpid()
        return {"host": socket.gethostname(), "pid": pid, "proc_start": _proc_start(pid),
                "started": _now(), "run_id": self.run_id}

    def acquire(self) -> "OutputLock":
        # the folders this lock makes, deepest first: a run refused before it wrote anything removes them
        self.created_dirs = [d for d in (self.path.parent, *self.path.parent.parents) if not d.exists()]
        for _ in range(5):  # each retry follows a lock that vanished or a stale one removed
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is None:
                    continue  # released between our open and our read
                if not self._is_stale(holder):
                    raise OutputLocked(self._locked_message(holder)) from None
                self._take_over(holder)
                continue
            except OSError as err:  # the first write of a run: an unwritable place shows here
                raise OutputError(f"cannot create the lock {self.path}: {err.strerror or err}; choose a "
                                  f"writable --stage-path") from None
            try:
                os.write(fd, json.dumps(self._info()).encode())
                os.fsync(fd)
            except OSError:
                os.close(fd)
                self.path.unlink(missing_ok=True)
                raise
            os.close(fd)
            self.held = True
            return self
        raise OutputLocked(f"could not lock {self.path}: other runs keep creating and removing it")

    def _holder(self) -> dict | None:
        """The holder's record; a lock still being written (empty for a moment) is read again."""
        for _ in range(20):
            if not self.path.exists():
                return None
            data = _read_json(self.path)
            if data is not None:
                return data
            time.sleep(0.05)
        return {"host": "?", "pid": "?", "started": "?", "unreadable": True}

    def _is_stale(self, h: dict) -> bool:
        if h.get("unreadable") or h.get("host") != socket.gethostname() or not isinstance(h.get("pid"), int):
            return False  # cannot tell if it runs: the user decides
        return not pid_alive(h["pid"], h.get("proc_start"))

    def _locked_message(self, h: dict) -> str:
        if h.get("unreadable"):
            return (f"{self.path} exists but holds no readable lock record (a run killed while taking "
                    f"it?); if no run is writing {self.path.with_suffix('')}, delete that file")
        msg = f"{self.path.with_suffix('')} is being written by another run ({describe_holder(h)}; lock {self.path})"
        if h.get("host") != socket.gethostname():
            msg += "; that host cannot be checked from here: if that run has stopped, delete the lock file"
        return msg + "; wait for it to finish, or write elsewhere with another --stage-path"

    def _take_over(self, h: dict) -> None:
        """Move the stale lock aside (atomic), check it is the one judged stale, then drop it."""
        aside = self.path.with_name(f"{self.path.name}.stale-{os.getpid()}-{secrets.token_hex(3)}")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return  # another process took it over first
        if _read_json(aside) != h:  # a live lock created meanwhile: put it back untouched
            try:
                os.link(aside, self.path)
            except OSError:
                pass
            aside.unlink(missing_ok=True)
            return
        aside.unlink(missing_ok=True)
        (self.log or sys.stderr).write(f"taking over the stale lock {self.path}: {describe_holder(h)}, "
                                       f"which is no longer running\n")

    def release(self) -> None:
        if self.held:
            self.held = False
            if (_read_json(self.path) or {}).get("run_id") == self.run_id:
                self.path.unlink(missing_ok=True)

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def stage_run_id(stage: Path) -> str | None:
    """The run id recorded in a top layer this project wrote; None for any other file."""
    from pxr import Sdf, Tf

    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(stage), metadataOnly=True)
    except Tf.ErrorException:
        return None
    data = layer.customLayerData.get(LAYER_KEY) if layer else None
    return str(data.get("run_id")) if isinstance(data, dict) and data.get("run_id") else None


def _foreign_message(what: str, files: list[str]) -> str:
    shown = ", ".join(files[:6]) + (f" and {len(files) - 6} more" if len(files) > 6 else "")
    return (f"{what}: {shown}. Files the project did not write are never replaced or deleted, even with "
            f"--overwrite; move them away or choose another --stage-path")


def check_output(stage_path, *, overwrite: bool, resume: bool) -> dict | None:
    """Refuse (raise) unless the output may be written as asked; returns the marker if there is one."""
    stage, fdir = Path(stage_path), frames_dir(stage_path)
    if overwrite and resume:
        raise OutputError("--overwrite and --resume exclude each other: --resume continues the existing "
                          "output, --overwrite replaces it")
    if fdir.exists() and not fdir.is_dir():
        raise ForeignFiles(_foreign_message(f"{fdir} is not a folder this project made", [fdir.name]))
    if stage.exists() and not stage.is_file():
        raise ForeignFiles(_foreign_message(f"{stage} is not a file", [stage.name]))
    entries = sorted(e.name for e in fdir.iterdir()) if fdir.is_dir() else []
    marker = _read_json(fdir / MARKER) if MARKER in entries else None
    if entries and marker is None:
        raise ForeignFiles(_foreign_message(f"{fdir} has no {MARKER} marker, so this project did not make "
                                            f"it; it holds", [f"{fdir.name}/{n}" for n in entries]))
    foreign = [f"{fdir.name}/{name}" for name in entries
               if not is_own_file(name, stage.stem) or (fdir / name).is_dir()]
    if stage.exists() and stage_run_id(stage) is None:
        foreign.insert(0, stage.name)
    if resume:
        if marker is None or not stage.exists():
            raise SimulationError(f"nothing to resume: no output this project wrote at {stage}; "
                                  f"run without --resume")  # exit code 1, as before ownership
        if foreign[:1] == [stage.name]:  # resuming rewrites the top file: it must be ours
            raise ForeignFiles(_foreign_message(f"{stage} cannot be resumed: it was not written by this "
                                                f"project", [stage.name]))
        return marker  # resuming deletes only the project's frames past the checkpoint
    if foreign:
        raise ForeignFiles(_foreign_message(f"{stage} cannot be written: {fdir.parent} holds files "
                                            f"this project did not write", foreign))
    if (stage.exists() or entries) and not overwrite:
        frames = sorted(n for n in entries if frame_number(n, stage.stem) is not None)
        held = f" ({len(frames)} frames of run {marker.get('run_id')}, started {marker.get('started')})" \
            if marker else ""
        raise OutputExists(f"{stage} already exists{held}; nothing was changed; {_CHOICES}")
    return marker


def clear_output(stage_path, run_id: str) -> None:
    """Remove the project's own files of the previous output and mark the folder for run_id.
    Called under the lock after check_output; still deletes only names the project writes."""
    stage, fdir = Path(stage_path), frames_dir(stage_path)
    if stage.exists() and stage_run_id(stage) is not None:
        stage.unlink()  # first, so the top file never points at missing frames
    fdir.mkdir(parents=True, exist_ok=True)
    for entry in fdir.iterdir():
        if entry.name != MARKER and is_own_file(entry.name, stage.stem) and entry.is_file():
            entry.unlink()
    write_marker(fdir, stage, run_id)


def trim_for_resume(stage_path, resume_after: int) -> None:
    """A resumed run goes on after its checkpoint: drop the project's frames past it and stale temps."""
    stage, fdir = Path(stage_path), frames_dir(stage_path)
    for entry in fdir.iterdir():
        n = frame_number(entry.name, stage.stem)
        if (n is not None and n > resume_after) or _TEMP.fullmatch(entry.name):
            entry.unlink(missing_ok=True)


def write_marker(fdir: Path, stage: Path, run_id: str) -> None:
    info = {"run_id": run_id, "stage": stage.name, "host": socket.gethostname(), "pid": os.getpid(),
            "started": _now(), "written_by": "warp_mpm_bubbles"}
    path = fdir / MARKER
    tmp = temp_path(fdir / "marker.json")
    tmp.write_text(json.dumps(info, indent=1) + "\n")
    os.replace(tmp, path)


class OutputClaim:
    """The lock and the ownership check together, held from before the simulation is built until
    the last frame: a refused run has done no work and changed nothing."""

    def __init__(self, stage_path, *, overwrite: bool = False, resume: bool = False, log=None):
        self.stage = Path(stage_path)
        self.overwrite, self.resume = overwrite, resume
        self.lock = OutputLock(stage_path, log=log)
        self.run_id = self.lock.run_id
        self.prepared = False

    def __enter__(self) -> "OutputClaim":
        self.lock.acquire()
        try:
            marker = check_output(self.stage, overwrite=self.overwrite, resume=self.resume)
        except BaseException:
            self.lock.release()
            raise
        if self.resume and marker and marker.get("run_id"):
            self.run_id = str(marker["run_id"])  # a resumed run is the same run
        return self

    def prepare(self, resume_after: int | None) -> None:
        """Make the folder ready: trim a resumed output, or clear the project's old files."""
        if resume_after is not None:
            trim_for_resume(self.stage, resume_after)
        else:
            clear_output(self.stage, self.run_id)
        self.prepared = True

    def __exit__(self, *exc):
        self.lock.release()
        if not self.prepared:  # refused or stopped before the folder was ours: leave no empty folder behind
            for folder in self.lock.created_dirs:
                try:
                    folder.rmdir()
                except OSError:  # not empty (someone else's file), or gone
                    break


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def write_failed(err: OSError, stage_path, last_frame: int | None, checkpoint_frame: int | None) -> OutputWriteError:
    """The message for a failed frame or checkpoint write: which file, the space left, what is kept."""
    fdir = frames_dir(stage_path)
    where = err.filename or fdir
    try:
        free = f"{_size(shutil.disk_usage(fdir if fdir.exists() else Path(stage_path).parent).free)} free"
    except OSError:
        free = "free space unknown"
    reason = "no space left on device" if err.errno == errno.ENOSPC else \
        ("disk quota exceeded" if err.errno == errno.EDQUOT else (err.strerror or str(err)))
    msg = f"could not write {where}: {reason} ({free} on the disk holding {fdir})"
    if last_frame is None or checkpoint_frame is None:
        return OutputWriteError(msg + "; no frame was finished: free some space and run again with "
                                      "--overwrite, or choose another --stage-path")
    return OutputWriteError(msg + f"; frames up to {last_frame} are finished and kept; free some space and "
                                  f"run the same command with --resume to continue after frame {checkpoint_frame}")
