"""The implicit viscous solve's multigrid preconditioner (physics/viscous_multigrid.py) and warm start
(physics/viscous_solve.py): the V-cycle is a symmetric positive definite operator (so PCG stays
valid), the PCG's iteration counts on seeded problems are pinned for each preconditioner, cold and
warm, and a run resumed from a checkpoint continues the warm start bit for bit."""

import numpy as np
import pytest
import warp as wp

from test_viscosity import honey_drop
from test_viscosity_solver import dense, system

wp.config.quiet = True


def v_cycle_matrix(dim):
    """The multigrid preconditioner's M^-1 on the unknown faces of system(dim) (block diagonal: one
    V-cycle per component), probed column by column, and the matrix A."""
    g, solver, T, IR, inv_rho = system(dim, seed=4, size=(12, 10, 6))
    solver.prepare(T, IR, 1.0)
    A, unknowns = dense(g, solver, T, IR, inv_rho, dt=1.0)
    solver._build_multigrid(IR, 1.0)
    M_inv = np.zeros_like(A)
    for col, (a, idx) in enumerate(unknowns):
        r = np.zeros(g.face_shape(a), np.float32)
        r[idx] = 1.0
        solver.r[a].assign(r)
        solver.multigrid[a].apply(solver.r[a], solver.z[a])
        z = solver.z[a].numpy()
        for row, (b, idx2) in enumerate(unknowns):
            if b == a:
                M_inv[row, col] = z[idx2]
    return A, M_inv, unknowns


@pytest.mark.parametrize("dim", [2, 3])
def test_v_cycle_is_symmetric_positive_definite(dim):
    # Symmetric to float32 round-off (measured 3e-9 of its largest entry) and positive definite,
    # and close to the component blocks' inverse: the condition number of M^-1 A measured 2.1 (2D)
    # and 2.4 (3D), against 149 and 226 for A's own.
    A, M_inv, unknowns = v_cycle_matrix(dim)
    axis = np.array([a for a, _ in unknowns])
    assert np.all(M_inv[axis[:, None] != axis[None, :]] == 0.0)  # one V-cycle per component
    asym = np.abs(M_inv - M_inv.T).max() / np.abs(M_inv).max()
    sym = 0.5 * (M_inv + M_inv.T)
    assert asym < 1e-6, asym
    assert np.linalg.eigvalsh(sym).min() > 0.0
    ev = np.sort(np.real(np.linalg.eigvals(sym @ A)))
    print(f"{dim}D: asymmetry {asym:.1e}, cond(M^-1 A) {ev[-1] / ev[0]:.1f}, cond(A) {np.linalg.cond(A):.0f}")
    assert ev[0] > 0.0 and ev[-1] / ev[0] < 3.0


def solve_twice(dim, preconditioner, dt, warm, size, seed=5, max_iter=500):
    """An implicit solve on system(dim, seed, size) from a random velocity; with `warm`, a second one
    from that velocity slightly changed (1%), started from the first's change. Its SolveInfo and
    the velocity."""
    g, solver, T, IR, inv_rho = system(dim, seed=seed, size=size)
    solver.preconditioner = preconditioner
    solver.prepare(T, IR, dt)
    rng = np.random.default_rng(seed + 1)
    v0 = [rng.standard_normal(g.face_shape(a)).astype(np.float32) for a in range(3)]
    solver.warm_start = warm
    vel = [wp.array(v, dtype=float) for v in v0]
    info = solver.implicit(T, IR, vel, dt, 1e-6, max_iter if not warm else 500)
    if warm:
        vel = [wp.array((v + 0.01 * rng.standard_normal(v.shape)).astype(np.float32), dtype=float) for v in v0]
        info = solver.implicit(T, IR, vel, dt, 1e-6, max_iter)
    return info, [v.numpy() for v in vel]


# Exact PCG iteration counts on seeded problems (100:1 viscosities, densities 1 to 1000, random
# EMPTY cells, no-slip and free-slip walls), to a relative residual of 1e-6: dt 0.3 is the
# moderate case, dt 3 the stiff one (viscosity dominates rho/dt). The block preconditioners are
# capped by the cross terms they leave out (the exact inverse of the component blocks needs 10 and
# 14 iterations on the small 2D and 3D problems), so an error in a preconditioner moves a count by
# a few percent of the residual: these problems were chosen where the deliberate errors below move
# one. Margins (residual at the counted iteration below tol, and one iteration earlier above it):
# at least 1.05x, where float32 rounding moves a residual by about 1e-6 of itself. On the CPU the
# counts are deterministic. Deliberate errors measured (each fails at least one pin):
#   symmetric Gauss-Seidel update relaxed to 0.9 x its value (sgs_sweep): 2d_sgs_cold 8 -> 9,
#     2d_sgs_cold_stiff 16 -> 15;
#   the finest level's normal coupling 2 mu_c -> 1.8 mu_c (face_level): 2d_multigrid_cold_stiff 13 -> 14,
#     3d_multigrid_cold_stiff 19 -> 20, 3d_multigrid_warm_stiff 10 -> 9;
#   the V-cycle's restriction weighted 0.9 (core/multigrid.py restrict_residual): 2d_multigrid_cold_stiff
#     13 -> 14; its smoother's update relaxed to 0.9 (smooth): 3d_multigrid_cold_stiff 19 -> 20,
#     3d_multigrid_warm_stiff 10 -> 9 (and the V-cycle test above: asymmetry 1e-3);
#   the V-cycle's upward sweeps in the downward order (red, black: no longer symmetric): three pins
#     (19 -> 16 in 3D) and the V-cycle test above (asymmetry 1e-2).
ITERATION_PINS = {  # id: (dim, preconditioner, dt, warm start, seed, iterations)
    "2d_sgs_cold": (2, "sgs", 0.3, False, 7, 8),
    "2d_sgs_cold_stiff": (2, "sgs", 3.0, False, 5, 16),
    "2d_sgs_warm": (2, "sgs", 0.3, True, 5, 5),
    "2d_multigrid_cold_stiff": (2, "multigrid", 3.0, False, 5, 13),
    "2d_multigrid_warm_stiff": (2, "multigrid", 3.0, True, 5, 9),
    "3d_multigrid_cold_stiff": (3, "multigrid", 3.0, False, 5, 19),
    "3d_multigrid_warm_stiff": (3, "multigrid", 3.0, True, 7, 10),
    "3d_sgs_warm_stiff": (3, "sgs", 3.0, True, 5, 12),
}
SIZES = {2: (40, 30, 1), 3: (14, 12, 10)}


@pytest.mark.parametrize("case", list(ITERATION_PINS))
def test_iteration_counts_are_pinned(case):
    dim, preconditioner, dt, warm, seed, expected = ITERATION_PINS[case]
    info, _ = solve_twice(dim, preconditioner, dt, warm, SIZES[dim], seed=seed)
    assert info.converged
    assert info.iterations == expected, f"{case}: {info.iterations} PCG iterations, pinned at {expected}"


@pytest.mark.parametrize("dim", [2, 3])
def test_every_start_and_preconditioner_gives_the_same_answer(dim):
    # Each solve stops at a relative residual of 1e-6, so its error is at most 1e-6 times the
    # condition number of A (measured about 500 on the 2D problem at both dt): answers may differ
    # by 5e-4 of the velocity. Measured against Jacobi from the same start: at most 2e-5 cold,
    # 1.4e-4 warm (3D, dt 3; the second solve's right-hand side is smaller than its velocity).
    for dt in (0.3, 3.0):
        runs = {(pre, warm): solve_twice(dim, pre, dt, warm, SIZES[dim])
                for pre in ("jacobi", "sgs", "multigrid") for warm in (False, True)}
        for warm in (False, True):
            ref = runs[("jacobi", warm)][1]
            scale = max(np.abs(v).max() for v in ref)
            for pre in ("sgs", "multigrid"):
                diff = max(np.abs(v - w).max() for v, w in zip(runs[(pre, warm)][1], ref))
                print(f"{dim}D dt {dt} {pre} {'warm' if warm else 'cold'}: |u - u_jacobi| / max |u| = {diff / scale:.1e}")
                assert diff < 5e-4 * scale


def test_a_resumed_implicit_run_continues_the_warm_start(tmp_path):
    # The warm start's guess is the last solve's change: a checkpoint keeps it, so a resumed run
    # takes the iterations and gives the particles of one that never stopped. Deliberate errors:
    # load_guess returning at once (a cold start after the resume) or not loading the previous
    # change (another extrapolation) each fail it.
    from warp_mpm_bubbles.io.checkpoint import load_checkpoint, save_checkpoint

    whole, first, resumed = (honey_drop(tmp_path / name, "implicit", 0.0, fps=2500)[0] for name in "abc")
    for _ in range(4):  # a step a frame: the checkpoint after 3 solves, so the guess extrapolates two
        whole.advance_frame()
    for _ in range(3):
        first.advance_frame()
    assert first.stage("viscosity").solver.guess_arrays()["viscous_previous_dt"][0] > 0.0
    save_checkpoint(first, tmp_path / "c.npz")
    load_checkpoint(resumed, tmp_path / "c.npz")
    before = dict(resumed.stage("viscosity").counts)
    resumed.advance_frame()
    iterations = lambda sim: sim.stage("viscosity").counts["pcg_iterations"]  # noqa: E731
    assert iterations(resumed) - before["pcg_iterations"] == iterations(whole) - iterations(first) > 0
    assert np.array_equal(whole.particles_numpy()["positions"], resumed.particles_numpy()["positions"])
    assert np.array_equal(whole.particles_numpy()["velocities"], resumed.particles_numpy()["velocities"])
