"""The CPU's threads (core/threads.py): p2g in slabs of nodes, g2p in ranges of particles, the V-cycle's
and the CG's large launches in slabs of lines (the CG's dot products summed per plane). Results must
not depend on the thread count: the same bits with 1, 2 and 3 threads, in 2D and 3D, liquid and gas."""

import numpy as np
import pytest
import warp as wp

from scenes import dam_break_2d
from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, Sphere
from warp_mpm_bubbles.core import threads
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.core.threads import cpu_threads, split

wp.config.quiet = True


def splash_3d(out):
    """A falling 3D block with an air bubble inside: gas, tension, splashing (so voids and covered air)."""
    return Scene(domain=Domain(size=(0.1, 0.1, 0.1), cell_size=0.1 / 14),
                 materials={"water": Material("water", surface_tension=0.072), "air": Material("air", kind="gas")},
                 shapes=[Box("water", min=(0.02, 0.03, 0.02), max=(0.08, 0.08, 0.08)),
                         Sphere("air", center=(0.05, 0.055, 0.05), radius=0.015)],
                 output=Output(path=str(out / "s.usdc")), name="splash_3d")


def state_after(scene, n_threads, steps, monkeypatch):
    monkeypatch.setenv("WARP_MPM_CPU_THREADS", str(n_threads))
    sim = Simulation(scene, "cpu")
    assert sim.parallel.threads == n_threads
    for _ in range(steps):
        sim.step(sim.stable_dt())
    p = sim.particles_numpy()
    return np.concatenate([p["positions"].ravel(), p["velocities"].ravel(), p["J"]]), sim.pressure_numpy()


@pytest.mark.parametrize("case", ["dam_break_2d", "splash_3d"])
def test_results_do_not_depend_on_the_thread_count(case, tmp_path, monkeypatch):
    monkeypatch.setattr(threads, "SPLIT_CELLS", 0)  # split every box launch, even these small ones
    monkeypatch.setattr(threads, "SPLIT_PARTICLES", 0)  # and every per-particle launch that may be split
    scene = dam_break_2d(cells_per_a=8, out=tmp_path / "d.usdc") if case == "dam_break_2d" else splash_3d(tmp_path)
    one = state_after(scene, 1, 6, monkeypatch)
    for n in (2, 3):
        other = state_after(scene, n, 6, monkeypatch)
        assert np.array_equal(one[0], other[0]) and np.array_equal(one[1], other[1]), n


def test_thread_setting(monkeypatch):
    monkeypatch.setenv("WARP_MPM_CPU_THREADS", "3")
    assert cpu_threads() == 3
    monkeypatch.delenv("WARP_MPM_CPU_THREADS")
    assert 1 <= cpu_threads() <= 8
    for bad in ("0", "-2", "1.5", "many"):
        monkeypatch.setenv("WARP_MPM_CPU_THREADS", bad)
        with pytest.raises(ValueError, match="WARP_MPM_CPU_THREADS"):
            cpu_threads()
    assert split(3, 13, 3) == [3, 6, 9, 13] and split(0, 2, 4) == [0, 0, 1, 1, 2]
