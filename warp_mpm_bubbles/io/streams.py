"""Where a run's messages go, so that none of them can stop it: stdout and stderr whose reader may
vanish (`run ... | head`, a closed terminal, a log reader that died), and the run log in the output
folder (<stem>_frames/run.log) that keeps the closing summary and any error whatever became of them.
Imports nothing heavy: the command line installs the guards before Warp loads.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path

RUN_LOG = "run.log"  # in <stem>_frames/, beside the frames and the checkpoint
_LOST = (OSError, ValueError)  # a broken pipe, a full disk, a closed file ("I/O operation on closed file")


class SafeStream:
    """A text stream that never raises: the first failed write or flush (EPIPE when the reader is
    gone, ENOSPC, a closed file) marks it lost, and later writes are dropped. The lost file
    descriptor is pointed at os.devnull so Python's own flush at exit, and native code writing to
    it (Warp's), fail no more either. Everything else is the wrapped stream's."""

    def __init__(self, stream):
        self._stream = stream
        self.lost = False

    def write(self, text: str) -> int:
        if not self.lost:
            try:
                return self._stream.write(text)
            except _LOST:
                self._lose()
        return len(text)

    def flush(self) -> None:
        if not self.lost:
            try:
                self._stream.flush()
            except _LOST:
                self._lose()

    def isatty(self) -> bool:
        try:
            return not self.lost and self._stream.isatty()
        except _LOST:
            return False

    def _lose(self) -> None:
        self.lost = True
        try:
            fd = self._stream.fileno()
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, fd)
            finally:
                os.close(devnull)
        except (OSError, ValueError, AttributeError):  # not a real file (StringIO), or already closed
            pass

    def __getattr__(self, name):  # encoding, fileno, closed, buffer...: the wrapped stream's
        if name == "_stream":  # not set yet (a copy made without __init__): no endless lookup
            raise AttributeError(name)
        return getattr(self._stream, name)


def safe_stream(stream):
    """`stream` wrapped in a SafeStream (once: an already safe one is returned as it is)."""
    return stream if isinstance(stream, SafeStream) or stream is None else SafeStream(stream)


@contextlib.contextmanager
def guarded_std_streams():
    """sys.stdout and sys.stderr as SafeStreams for the command line, where a closed pipe or
    terminal must change neither the run nor its exit code. On leaving, both are flushed through
    the guard (what `check ... | head` left buffered would otherwise fail in Python's flush at exit)
    and the originals put back."""
    saved = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = safe_stream(sys.stdout), safe_stream(sys.stderr)
    try:
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
        sys.stdout, sys.stderr = saved


def now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())


class RunLog:
    """<folder>/run.log, appended to: the run's start (or resume), its closing summary, any error.
    Nothing is written until ready() says the run has made the folder its own, so a refused run
    changes nothing; a failed write is ignored (the frames' own write reports a full disk)."""

    def __init__(self, folder, ready=lambda: True):
        self.path = Path(folder) / RUN_LOG
        self.ready = ready

    def write(self, text: str) -> bool:
        if not self.ready():
            return False
        try:
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(text.rstrip("\n") + "\n")
        except OSError:
            return False
        return True
