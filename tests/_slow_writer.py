"""Subprocess for the kill test: writes deterministic frames until it is killed."""

import sys
import time

import numpy as np

MATERIALS = [("water", (0.2, 0.4, 1.0)), ("air", (1.0, 1.0, 1.0))]


def frame_data(frame: int, base: int):
    """Deterministic frame content, so the test can check what survived the kill."""
    n = base + 7 * frame  # counts change between frames
    ids = np.arange(n, dtype=np.int64) + 1000 * frame
    pos = (np.arange(3 * n, dtype=np.float32).reshape(n, 3) * 1e-3 + frame).astype(np.float32)
    vel = np.full((n, 3), float(frame), np.float32)
    mat = (ids % 2).astype(np.int32)
    return pos, vel, ids, mat


if __name__ == "__main__":
    from warp_mpm_bubbles.io.usd_output import StageWriter

    path, n_frames, sleep, base = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
    with StageWriter(path, fps=24, materials=MATERIALS, particle_radius=0.01, format="both") as w:
        for f in range(n_frames):
            w.write_frame(f, *frame_data(f, base))
            time.sleep(sleep)
