"""A closed stdout or stderr never stops a run or hides its result, and --quiet means quiet: the
command line in a subprocess (Warp's own output and a reader that goes away are process-wide)."""

import os
import pathlib
import subprocess
import sys

from scenes import SMALL_2D

from warp_mpm_bubbles.io.usd_output import read_frames

ROOT = pathlib.Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
CLI = [sys.executable, "-m", "warp_mpm_bubbles.cli"]


def scene_file(tmp_path, frames=3):
    path = tmp_path / "small.toml"
    path.write_text(SMALL_2D.format(out=(tmp_path / "small.usdc").as_posix(), frames=frames))
    return path


def closed_pipe() -> int:
    """The write end of a pipe whose reader is already gone: every write to it fails (EPIPE)."""
    read, write = os.pipe()
    os.close(read)
    return write


def test_a_reader_gone_from_stdout_and_stderr_stops_nothing(tmp_path):
    """`run ... --verbose | head -1` with stderr's reader dead too: the run writes every frame, exits
    0, and its summary is in the run log."""
    dead = closed_pipe()
    unbuffered = dict(ENV, PYTHONUNBUFFERED="1")  # each line reaches the pipe at once: it breaks mid-run
    proc = subprocess.Popen([*CLI, "run", str(scene_file(tmp_path, frames=6)), "--verbose"], env=unbuffered,
                            stdout=subprocess.PIPE, stderr=dead, text=True)
    os.close(dead)
    first = proc.stdout.readline()  # Warp's banner: --verbose shows it
    proc.stdout.close()  # head exits
    assert proc.wait(timeout=300) == 0
    assert first.startswith("Warp ")
    assert sorted(read_frames(tmp_path / "small.usdc")["frames"]) == list(range(7))
    log = (tmp_path / "small_frames" / "run.log").read_text()
    assert "small: 7 frames to" in log and "pressure CG" in log


def test_check_into_a_closed_pipe_exits_with_its_usual_code(tmp_path):
    good = scene_file(tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_text(good.read_text().replace("density = 1000.0", "densty = 1000.0"))
    buffered = {k: v for k, v in ENV.items() if k != "PYTHONUNBUFFERED"}  # as in a shell: fails at exit's flush
    for scene, code in ((good, 0), (bad, 2)):
        dead = closed_pipe()
        proc = subprocess.run([*CLI, "check", str(scene)], env=buffered, stdout=dead, stderr=subprocess.PIPE,
                              text=True, timeout=300)
        os.close(dead)
        assert proc.returncode == code, proc.stderr
        assert "internal error" not in proc.stderr and "Traceback" not in proc.stderr
        assert ("densty" in proc.stderr) == (code == 2)


def test_quiet_prints_nothing_at_all(tmp_path):
    """Not Warp's banner, nor the CUDA driver warning (where there is no driver), nor its module loads."""
    proc = subprocess.run([*CLI, "run", str(scene_file(tmp_path)), "--quiet"], env=ENV, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0
    assert proc.stdout + proc.stderr == ""
    assert sorted(read_frames(tmp_path / "small.usdc")["frames"]) == [0, 1, 2, 3]
