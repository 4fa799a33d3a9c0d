"""The implicit viscous solve's preconditioner (physics/viscous_solve.py): the red-black symmetric
Gauss-Seidel sweep is exactly that of each velocity component's block of the matrix, and it cuts
the PCG's iterations by the counts pinned here (deterministic on the CPU) with the same answer as
the diagonal (Jacobi) preconditioner."""

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles.core.grid import EMPTY, FLUID, SOLID_FREE_SLIP, SOLID_NO_SLIP, MacGrid
from warp_mpm_bubbles.physics.viscous_solve import OPERATOR, RED, ViscousSolver

from test_viscosity import active_faces

wp.config.quiet = True


def system(dim, seed=0, size=(6, 5, 4)):
    """A small grid with no-slip and free-slip walls, EMPTY cells, two phases with a 100:1 viscosity
    ratio and densities from 1 to 1000; the solver prepared for dt = 0.01."""
    rng = np.random.default_rng(seed)
    interior = (size[0], size[1], size[2] if dim == 3 else 1)
    g = MacGrid(dim=dim, dx=0.1, interior=interior, domain_size=tuple(0.1 * n for n in interior))
    types = np.full(g.cells, FLUID, np.int32)
    for a in range(dim):
        for side in (0, -1):
            idx = [slice(None)] * 3
            idx[a] = side
            types[tuple(idx)] = SOLID_NO_SLIP if a == 1 else SOLID_FREE_SLIP
    inner = types[g.interior_slice()]
    inner[rng.random(inner.shape) < 0.1] = EMPTY
    liquid = (rng.random(g.cells) < 0.6).astype(np.float32)
    volumes = [wp.array(liquid, dtype=float), wp.array(1.0 - liquid, dtype=float)]
    inv_rho = [np.where(m, 1.0 / (1.0 + 999.0 * rng.random(m.shape)), 0.0).astype(np.float32)
               for m in active_faces(types, g)]
    solver, T = ViscousSolver(g, "cpu"), wp.array(types, dtype=wp.int32)
    solver.set_viscosity(T, *volumes, 1, 1.0, 0.01)
    IR = [wp.array(x, dtype=float) for x in inv_rho]
    solver.prepare(T, IR, 0.01)
    return g, solver, T, IR, inv_rho


def dense(g, solver, T, IR, inv_rho, dt=0.01):
    """The matrix on the unknown faces, probed column by column, and the unknowns (axis, index)."""
    unknowns = [(a, idx) for a in range(g.dim) for idx in zip(*np.nonzero(inv_rho[a]))]
    row = {u: i for i, u in enumerate(unknowns)}
    A = np.zeros((len(unknowns), len(unknowns)))
    for col, (a, idx) in enumerate(unknowns):
        x = [np.zeros(g.face_shape(b), np.float32) for b in range(g.dim)]
        x[a][idx] = 1.0
        out = [wp.zeros(g.face_shape(b), dtype=float) for b in range(g.dim)]
        solver.apply(OPERATOR, T, IR, [wp.array(v, dtype=float) for v in x], dt, out)
        for b in range(g.dim):
            o = out[b].numpy()
            for idx2 in zip(*np.nonzero(o)):
                A[row[(b, idx2)], col] = o[idx2]
    return A, unknowns


def block_sgs(A, unknowns, r):
    """M^-1 r, M the red-black symmetric Gauss-Seidel of each axis's diagonal block of A: red, black,
    red, each colour solved with the other's latest values."""
    z = np.zeros_like(r)
    axis = np.array([a for a, _ in unknowns])
    red = np.array([sum(idx) % 2 == 0 for _, idx in unknowns])
    for colour in (red, ~red, red):
        for a in set(axis):
            rows = np.nonzero(colour & (axis == a))[0]
            block = np.nonzero(axis == a)[0]
            off = A[np.ix_(rows, block)] @ z[block] - np.diag(A)[rows] * z[rows]
            z[rows] = (r[rows] - off) / np.diag(A)[rows]
    return z


@pytest.mark.parametrize("dim", [2, 3])
def test_preconditioner_is_the_block_symmetric_gauss_seidel_sweep(dim):
    # Within an axis's block no two faces of one colour are coupled (so the half-sweeps are exact
    # Gauss-Seidel in red-black order), and the kernels' z = M^-1 r matches the dense sweep to
    # float32 round-off (measured 3e-8 in 2D, 1e-7 in 3D, relative). Halving the normal stress's
    # weight 2 mu_c in block_neighbours gives 5e-3 and 1e-3 (and changes every pinned count below).
    g, solver, T, IR, inv_rho = system(dim)
    A, unknowns = dense(g, solver, T, IR, inv_rho)
    axis = np.array([a for a, _ in unknowns])
    red = np.array([sum(idx) % 2 == 0 for _, idx in unknowns])
    for a in range(dim):
        for colour in (red, ~red):
            rows = np.nonzero(colour & (axis == a))[0]
            same = A[np.ix_(rows, rows)]
            assert np.abs(same - np.diag(np.diag(same))).max() == 0.0
    rng = np.random.default_rng(1)
    r = rng.standard_normal(len(unknowns))
    for a in range(dim):
        host = np.zeros(g.face_shape(a), np.float32)
        for i, (b, idx) in enumerate(unknowns):
            if b == a:
                host[idx] = r[i]
        solver.r[a].assign(host)
        solver.z[a].zero_()
    solver._sweeps(0.01, (RED,))
    rz = solver._last_sweeps(0.01)
    z = np.array([solver.z[a].numpy()[idx] for a, idx in unknowns], np.float64)
    expected = block_sgs(A, unknowns, r)
    error = np.abs(z - expected).max() / np.abs(expected).max()
    print(f"{dim}D: {len(unknowns)} unknowns, |z - dense SGS| / |z| = {error:.2e}")
    assert error < 1e-5
    assert rz == pytest.approx(float(r @ expected), rel=1e-5)
    # M is symmetric positive definite: PCG's requirement
    M_inv = np.column_stack([block_sgs(A, unknowns, e) for e in np.eye(len(unknowns))])
    assert np.abs(M_inv - M_inv.T).max() <= 1e-9 * np.abs(M_inv).max()
    assert np.linalg.eigvalsh(0.5 * (M_inv + M_inv.T)).min() > 0.0


def solve(dim, preconditioner, sweeps=1):
    """One implicit solve from a random velocity on the grid of system(dim, seed 2) at dt = 10 s
    (viscosity dominates rho/dt by 1e2-1e5: the stiff case); its SolveInfo and the velocity."""
    g, solver, T, IR, inv_rho = system(dim, seed=2, size=(12, 10, 6))
    solver.preconditioner, solver.sweeps = preconditioner, sweeps
    solver.prepare(T, IR, 10.0)
    rng = np.random.default_rng(3)
    vel = [wp.array(rng.standard_normal(g.face_shape(a)).astype(np.float32), dtype=float) for a in range(3)]
    info = solver.implicit(T, IR, vel, 10.0, 1e-6, 500)
    return info, [v.numpy() * (m > 0) for v, m in zip(vel, inv_rho)]


@pytest.mark.parametrize("dim, counts", [(2, {"jacobi": 28, "sgs": 17, "sgs2": 13}),
                                         (3, {"jacobi": 34, "sgs": 20, "sgs2": 16})])
def test_gauss_seidel_cuts_the_iterations_with_the_same_answer(dim, counts):
    # Iteration counts are deterministic on the CPU: pinned. Both converge to 1e-6 of the
    # residual and give the same velocity (measured: within 8e-6 in 2D, 5e-5 in 3D of its largest
    # value, the residual tolerance 1e-6 times the stiff system's conditioning).
    runs = {"jacobi": solve(dim, "jacobi"), "sgs": solve(dim, "sgs"), "sgs2": solve(dim, "sgs", 2)}
    got = {name: info.iterations for name, (info, _) in runs.items()}
    print(f"{dim}D iterations: {got}")
    assert all(info.converged for info, _ in runs.values())
    assert got == counts
    ref = runs["jacobi"][1]
    scale = max(np.abs(v).max() for v in ref)
    for name in ("sgs", "sgs2"):
        diff = max(np.abs(v - w).max() for v, w in zip(runs[name][1], ref))
        print(f"{dim}D {name}: |u - u_jacobi| / max |u_jacobi| = {diff / scale:.1e}")
        assert diff < 1e-4 * scale, (name, diff / scale)


def test_slabs_on_threads_give_the_same_bits(monkeypatch):
    # The PCG's kernels in slabs along x at once on two threads (every array split) against one
    # launch each: each line adds its dot products to its plane's row and the host adds the rows
    # in order, so the iterations and every bit of the velocity are the same. (Launching all
    # slabs but the last fails it.)
    from warp_mpm_bubbles.core.threads import Parallel
    from warp_mpm_bubbles.physics import viscous_solve

    parallel = Parallel(2)

    def launch_parts(kernel, parts):
        parallel.run([lambda d=d, inputs=inputs: wp.launch(kernel, dim=d, inputs=inputs) for d, inputs in parts])

    one = solve(3, "sgs")
    monkeypatch.setattr(viscous_solve, "SPLIT_FACES", 1)
    original = ViscousSolver.__init__
    monkeypatch.setattr(ViscousSolver, "__init__", lambda self, g, device, *args, **kw: original(
        self, g, device, launch_parts=launch_parts, threads=2))
    two = solve(3, "sgs")
    assert two[0].iterations == one[0].iterations
    assert all(np.array_equal(a, b) for a, b in zip(one[1], two[1]))
