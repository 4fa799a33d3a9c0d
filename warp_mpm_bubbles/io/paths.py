"""How long an output path may be: the file system's limits on one name (NAME_MAX, 255 bytes on
most) and on a whole path (PATH_MAX, 4096 on Linux), checked against the longest names a run derives
from the stage's name, so an over-long --stage-path or [output].path is refused before any work
instead of failing at the first frame. Imports nothing heavy: scene validation uses it.

The names a run writes for ``<folder>/<stem>.usdc`` (io/ownership.py and io/usd_output.py):
``<stem>.usdc.lock`` (and ``.lock.stale-<pid>-<id>`` while taking over a dead run's lock),
``<stem>_frames/``, and in it ``<stem>.<frame>.usdc`` written through ``<stem>.<frame>.tmp-<pid>-<id>.usdc``
and ``<stem>.tmp-<pid>-<id>.usdc`` (the top file's temp). The longest is the frame's temp.
"""

from __future__ import annotations

import os
from pathlib import Path

FRAME_DIGITS = 7  # frame numbers are padded to 6 digits; MAX_FRAMES (1,000,000) has 7
PID_DIGITS = 7  # Linux's largest pid_max is 4,194,304
NAME_MAX, PATH_MAX = 255, 4096  # where the file system does not say (os.pathconf)


def derived_names(stage) -> list[str]:
    """The longest names a run writes for `stage`, beside it and in its frames folder (worst-case
    pid and frame number; the last one is the longest)."""
    stage = Path(stage)
    stem, ext = stage.stem, (".usda" if stage.suffix == ".usda" else ".usdc")
    temp = f".tmp-{'9' * PID_DIGITS}-abcdef"  # ownership.temp_path: .tmp-<pid>-<6 hex>
    return [stage.name, f"{stage.name}.lock.stale-{'9' * PID_DIGITS}-abcdef", f"{stem}_frames",
            f"{stem}{temp}{stage.suffix}", f"{stem}.{'9' * FRAME_DIGITS}{temp}{ext}"]


def _limits(path: Path) -> tuple[int, int]:
    """NAME_MAX and PATH_MAX of the file system the output would go to (its nearest existing folder)."""
    folder = path.parent
    try:
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        return (os.pathconf(folder, "PC_NAME_MAX"), os.pathconf(folder, "PC_PATH_MAX"))
    except (OSError, ValueError, AttributeError):  # no pathconf (Windows), or a name too long to stat
        return NAME_MAX, PATH_MAX


def _short(name: str) -> str:
    return repr(name if len(name) <= 40 else f"{name[:20]}...{name[-16:]}")


def output_path_problem(path) -> str | None:
    """Why the output path `path` cannot be written on this file system (a name or the whole path
    too long, counting the names the run derives from it), with the fix; None if it can."""
    target = Path(os.path.abspath(os.fspath(path)))
    name_max, path_max = _limits(target)
    for part in target.parent.parts:
        if len(os.fsencode(part)) > name_max:
            return (f"the folder name {_short(part)} is {len(os.fsencode(part))} bytes, over this file system's "
                    f"limit of {name_max} bytes per name: choose a folder with a shorter name")
    names = derived_names(target)
    longest = max(len(os.fsencode(n)) for n in names)
    if longest > name_max:
        stem = len(os.fsencode(target.stem))
        extra = longest - stem
        return (f"the file name {_short(target.name)} is {len(os.fsencode(target.name))} bytes; the run writes "
                f"files named after it up to {extra} bytes longer (frame temps such as "
                f"'<stem>.000042.tmp-<pid>-<id>.usdc') and this file system allows {name_max} bytes per name: "
                f"shorten the name before its suffix to at most {name_max - extra} bytes")
    deepest = len(os.fsencode(str(target.parent / f"{target.stem}_frames" / names[-1])))
    if deepest >= path_max:
        return (f"the path is {len(os.fsencode(str(target)))} bytes and the deepest file the run writes under it "
                f"would be {deepest}, over this system's limit of {path_max - 1} bytes for a path: choose a "
                f"shorter folder or file name")
    return None
