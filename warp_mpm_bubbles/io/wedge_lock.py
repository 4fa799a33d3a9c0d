"""One wedge per folder: the lock file DIR/.wedge.lock, with the output lock's rules
(io/ownership.OutputLock: atomic creation, a dead holder on this host taken over, any other refused)."""

from __future__ import annotations

import socket
from pathlib import Path

from ..scene.checks import SceneError
from .ownership import OutputLocked, OutputLock

LOCK_NAME = ".wedge.lock"


class WedgeError(SceneError):
    """A wedge was refused before anything ran (bad --vary, a folder in use)."""


class WedgeLock(OutputLock):
    def __init__(self, folder):
        self.folder = Path(folder)
        super().__init__(self.folder / LOCK_NAME.removesuffix(".lock"))  # the lock of "DIR/.wedge"
        self.owner = {"host": socket.gethostname()}

    def _locked_message(self, h: dict) -> str:
        return (f"{self.folder} is in use by another wedge (host {h.get('host', '?')}, pid {h.get('pid', '?')}, "
                f"started {h.get('started', '?')}); wait for it to finish or choose another --out. If no wedge "
                f"runs there, delete {self.path}.")

    def __enter__(self):
        self.folder.mkdir(parents=True, exist_ok=True)
        try:
            return self.acquire()
        except OutputLocked as err:
            raise WedgeError(str(err), "--out", str(self.folder)) from None
