"""One wedge per folder: the lock file DIR/.wedge.lock (see wedge.py)."""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

from ..scene.checks import SceneError

LOCK_NAME = ".wedge.lock"


class WedgeError(SceneError):
    """A wedge was refused before anything ran (bad --vary, a folder in use)."""


class WedgeLock:
    """One wedge per folder: an O_CREAT|O_EXCL file holding host and pid. A lock left by a
    dead process on this host is stale and taken over; any other is refused."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.owner = {"host": socket.gethostname(), "pid": os.getpid(), "started": time.time()}

    def __enter__(self):
        self.folder.mkdir(parents=True, exist_ok=True)
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._read()
                if holder is not None and self._stale(holder) and self._break(holder):
                    continue
                who = (f"host {holder.get('host')}, pid {holder.get('pid')}, started "
                       f"{time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(holder.get('started', 0)))}"
                       if holder else "an unreadable lock")
                raise WedgeError(f"{self.folder} is in use by another wedge ({who}); wait for it to finish or "
                                 f"choose another --out. If no wedge runs there, delete {self.path}.",
                                 "--out", str(self.folder)) from None
            with os.fdopen(fd, "w") as f:
                json.dump(self.owner, f)
            return self
        raise WedgeError(f"could not take {self.path}: other processes keep replacing it", "--out", str(self.folder))

    def __exit__(self, *exc):
        if self._read() == self.owner:
            self.path.unlink()

    def _read(self):
        try:
            return json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None

    @staticmethod
    def _stale(holder) -> bool:
        if holder.get("host") != socket.gethostname():
            return False  # cannot see another host's processes: assume it runs
        try:
            os.kill(int(holder["pid"]), 0)
        except ProcessLookupError:
            return True
        except (PermissionError, KeyError, ValueError, TypeError):
            return False
        return False

    def _break(self, holder) -> bool:
        """Move the stale lock aside; if a fresh one was moved instead (a race), put it back."""
        aside = self.path.with_name(f"{LOCK_NAME}.stale.{os.getpid()}")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return True
        try:
            moved = json.loads(aside.read_text())
        except (OSError, ValueError):
            moved = None
        if moved != holder:
            try:
                os.link(aside, self.path)  # no clobber: fails if yet another lock appeared
            except FileExistsError:
                pass
        aside.unlink()
        return moved == holder
