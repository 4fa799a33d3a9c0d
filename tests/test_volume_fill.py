"""[solver].volume_fill = "smoothed": the volume correction reads a neighbourhood's mean fill, with no
noise band (core/volume_correction.smoothed_excess; docs/design.md, #volume-correction)."""

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles import Box, Domain, Material, Output, Scene, SolverSettings
from warp_mpm_bubbles.core.grid import EMPTY, FLUID, SOLID_FREE_SLIP
from warp_mpm_bubbles.core.kernel_args import CellPhases, Splat
from warp_mpm_bubbles.core.simulation import Simulation
from warp_mpm_bubbles.core.volume_correction import smoothed_excess
from warp_mpm_bubbles.scene.checks import SceneError

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _excess_of_every_cell(cells: CellPhases, splat: Splat, dx: float, out: wp.array2d(dtype=float)):
    i, j = wp.tid()
    out[i, j] = smoothed_excess(cells, splat, 0, wp.vec3i(i, j, 0), 2, 1, 1.0 / (dx * dx), dx)


def _excess(types, fill):
    """smoothed_excess of every cell of a 2D liquid-only field (fill as fractions of the cell)."""
    dx = 1.0
    cells = CellPhases()
    cells.types = wp.array(types[:, :, None].astype(np.int32), dtype=wp.int32)
    cells.phase = wp.zeros(cells.types.shape, dtype=wp.int32)
    splat = Splat()
    splat.liq_volume = wp.array(fill[:, :, None].astype(np.float32), dtype=float)
    for name in ("liq_mass", "gas_mass", "gas_volume", "gas_pv", "gas_kv"):
        setattr(splat, name, wp.zeros(cells.types.shape, dtype=float))
    out = wp.zeros(types.shape, dtype=float)
    wp.launch(_excess_of_every_cell, dim=types.shape, inputs=[cells, splat, dx, out])
    return out.numpy()


def test_the_smoothed_excess_is_the_weighted_mean_with_no_band():
    # One cell over-full by 0.4 in liquid at rest fill 1: it and its neighbours see 0.4 times their
    # weight for it, (1 2 1)/4 along each axis (centre 4/16, sides 2/16, corners 1/16), with no band
    # taken off (a band of even 0.01 leaves the corners at 0). A cell two away sees none of it.
    types = np.full((7, 7), FLUID)
    fill = np.ones((7, 7))
    fill[3, 3] = 1.4
    e = _excess(types, fill)
    assert e[3, 3] == pytest.approx(0.4 * 4 / 16, rel=1e-5)
    assert e[2, 3] == e[4, 3] == e[3, 2] == pytest.approx(0.4 * 2 / 16, rel=1e-5)
    assert e[2, 2] == e[4, 4] == pytest.approx(0.4 * 1 / 16, rel=1e-5)
    assert e[1, 3] == 0.0 and e[3, 5] == 0.0


def test_cells_at_a_surface_count_as_full_and_solid_or_empty_cells_not_at_all():
    # Water at rest fill 1 below a free surface: the top row of water is half full (its room is
    # air, not a lower density), then empty cells; a solid wall on the left. No cell may read an
    # excess from that room or from the wall: the row under the surface and the column beside the
    # wall are at rest. Under-filled surface cells themselves are not enclosed, so they ask nothing
    # (volume_excess); an over-full one is still seen by its neighbours.
    types = np.full((7, 7), FLUID)
    fill = np.ones((7, 7))
    fill[:, 5] = 0.5
    types[:, 6] = EMPTY
    fill[:, 6] = 0.0
    types[0, :] = SOLID_FREE_SLIP
    fill[0, :] = 0.2  # what the particles splat into a wall cell
    e = _excess(types, fill)
    assert np.all(e[1:, :5] == 0.0), e
    fill[3, 5] = 1.3  # a surface cell over-full
    e = _excess(types, fill)
    assert e[3, 4] == pytest.approx(0.3 * 2 / 16, rel=1e-5)


@pytest.mark.parametrize("tau,dt,share", [(1 / 300, 1e-3, 0.3), (1e-3, 2e-3, 1.0)], ids=["rate", "capped"])
def test_the_smoothed_correction_asks_its_rate_of_the_mean_overfill(tmp_path, tau, dt, share):
    # As test_energy's test of the cell correction: water squeezed into 90% of its box side and at
    # rest with no gravity; after one step each deep cell's projected divergence is its smoothed
    # over-fill (the weighted mean of its block, computed here independently) / max(tau, dt), to the
    # CG tolerance. Bound 1% on every cell: one-cell weights (the cell correction, with its band)
    # are off by 25-60%, a box mean instead of (1 2 1) by several %.
    scene = Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.1 / 16, gravity=(0.0, 0.0)),
                  materials={"water": Material("water")}, shapes=[Box("water", (0.0, 0.0), (0.1, 0.1))],
                  solver=SolverSettings(volume_relaxation_time=tau, volume_fill="smoothed"),
                  output=Output(path=str(tmp_path / "c.usdc")))
    sim = Simulation(scene, "cpu")
    x = sim.particles.x.numpy()
    x[:, :2] = 0.05 + 0.9 * (x[:, :2] - 0.05)
    sim.particles.x = wp.array(x, dtype=wp.vec3, device=sim.device)
    sim.step(dt)
    dx = sim.grid.dx
    u, v = sim.fields.vel[0].numpy(), sim.fields.vel[1].numpy()
    div = ((u[1:] - u[:-1]) + (v[:, 1:] - v[:, :-1]))[:, :, 0] / dx
    phi = sim.fields.liq_volume.numpy()[:, :, 0] / dx**3
    w = np.array([1.0, 2.0, 1.0])
    smoothed = np.zeros_like(phi)
    smoothed[1:-1, 1:-1] = sum(w[a] * w[b] * phi[a:a + phi.shape[0] - 2, b:b + phi.shape[1] - 2]
                               for a in range(3) for b in range(3)) / 16.0
    deep = np.zeros_like(phi, dtype=bool)
    deep[5:-5, 5:-5] = True  # every cell of the block enclosed in the squeezed water
    ratio = div[deep] * dt / (smoothed[deep] - 1.0)
    print(f"smoothed correction: div dt / excess over {deep.sum()} cells = {ratio.mean():.4f} "
          f"(min {ratio.min():.4f}, max {ratio.max():.4f}); asked {share}")
    assert deep.sum() >= 20
    assert np.all(np.abs(ratio / share - 1.0) < 0.01), (ratio.min(), ratio.max())


def test_an_unknown_volume_fill_is_refused_by_name(tmp_path):
    with pytest.raises(SceneError, match=r"\[solver\]\.volume_fill"):
        Scene(domain=Domain(size=(0.1, 0.1), cell_size=0.01), materials={"water": Material("water")},
              shapes=[Box("water", (0.0, 0.0), (0.1, 0.05))], solver=SolverSettings(volume_fill="mean"),
              output=Output(path=str(tmp_path / "c.usdc"))).validate()
