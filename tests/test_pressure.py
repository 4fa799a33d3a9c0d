"""The pressure solver on systems built directly from numpy: free surfaces, closed tanks, a 1000:1
density jump with compressible gas, odd grid sizes; the three preconditioners against each other
and against a dense float64 solve; symmetry of the multigrid preconditioner."""

import numpy as np
import pytest
import warp as wp

from warp_mpm_bubbles.core.grid import EMPTY, FLUID, SOLID_FREE_SLIP
from warp_mpm_bubbles.core.multigrid import MultigridPreconditioner
from warp_mpm_bubbles.core.pressure import PRECONDITIONERS, PressureSolver, PressureSystem

wp.config.quiet = True
DEVICE = "cpu"
RHO_L, RHO_G = 1000.0, 1.2


def make_problem(interior, dim, *, surface=None, bubble=None, dx=None, seed=0):
    """Cell types, face weights, extra_diag and a right-hand side for a box with solid walls.

    surface: fluid below this height (fraction of the box), empty above (None: a closed tank, all fluid).
    bubble: (centre, radius) as fractions of the box: gas (rho 1.2, extra_diag = kappa/dt^2) inside.
    Face weights: 1/rho of the face; liquid-gas faces 2/(rho_l + rho_g); surface faces 1/(rho theta)
    with theta random in [0.1, 1] (the ghost-fluid factor); solid faces 0.
    """
    rng = np.random.default_rng(seed)
    shape = tuple(n + 2 for n in interior[:dim]) + ((1,) if dim == 2 else ())
    n_max = max(interior[:dim])
    dx = dx or 1.0 / n_max
    centre = (np.indices(shape).transpose(1, 2, 3, 0) - 0.5) * dx  # ghost cell 0 is outside
    types = np.full(shape, FLUID, np.int32)
    if surface is not None:
        types[centre[..., 1] > surface * interior[1] * dx] = EMPTY
    gas = np.zeros(shape, bool)
    if bubble is not None:
        c, r = bubble
        d = centre[..., :dim] - np.asarray(c[:dim]) * n_max * dx
        gas = (np.sqrt((d * d).sum(-1)) < r * n_max * dx) & (types == FLUID)
    for a in range(dim):  # solid walls on the ghost layer
        idx = [slice(None)] * 3
        for end in (0, -1):
            idx[a] = end
            types[tuple(idx)] = SOLID_FREE_SLIP
    gas &= types == FLUID
    rho = np.where(gas, RHO_G, RHO_L)
    dt = 0.5 * dx / np.sqrt(9.81 * dx)
    extra = np.where(gas, 1.0 / (101325.0 * dt * dt), 0.0)
    faces = face_weights(types, rho, dim, rng)
    b = np.where(types == FLUID, rng.normal(size=shape), 0.0)
    return types, faces, extra, b, dx


def face_weights(types, rho, dim, rng):
    """make_problem's face weights of cells `types` with densities `rho`."""
    shape, faces = types.shape, []
    for a in range(3):
        fshape = list(shape)
        fshape[a] += 1
        w = np.zeros(fshape)
        if a < dim:
            lo = tuple(slice(0, -1) if b == a else slice(None) for b in range(3))
            hi = tuple(slice(1, None) if b == a else slice(None) for b in range(3))
            inner = tuple(slice(1, -1) if b == a else slice(None) for b in range(3))
            t_lo, t_hi = types[lo], types[hi]
            both = (t_lo == FLUID) & (t_hi == FLUID)
            surf = ((t_lo == FLUID) & (t_hi == EMPTY)) | ((t_lo == EMPTY) & (t_hi == FLUID))
            rho_face = 0.5 * (rho[lo] + rho[hi])
            rho_fluid = np.where(t_lo == FLUID, rho[lo], rho[hi])
            theta = rng.uniform(0.1, 1.0, size=both.shape)
            w[inner] = np.where(both, 1.0 / rho_face, np.where(surf, 1.0 / (rho_fluid * theta), 0.0))
        faces.append(w)
    return faces


def dense_matrix(system, dx, dim):
    """The solver's A (float32 coefficients: the ill-conditioned jump cases are sensitive to their
    rounding) as a float64 dense matrix on the fluid cells, and the cells' flat indices."""
    types = system.types.numpy()
    cells = np.flatnonzero(types == FLUID)
    index = np.full(types.size, -1)
    index[cells] = np.arange(cells.size)
    index = index.reshape(types.shape)
    A = np.diag(system.diag.numpy().astype(np.float64).ravel()[cells])
    for a in range(dim):
        w = system.inv_rho[a].numpy().astype(np.float64) / dx**2
        lo = tuple(slice(0, -1) if b == a else slice(None) for b in range(3))
        hi = tuple(slice(1, None) if b == a else slice(None) for b in range(3))
        inner = tuple(slice(1, -1) if b == a else slice(None) for b in range(3))
        i_lo, i_hi, w_in = index[lo].ravel(), index[hi].ravel(), w[inner].ravel()
        m = (i_lo >= 0) & (i_hi >= 0)
        np.add.at(A, (i_lo[m], i_hi[m]), -w_in[m])
        np.add.at(A, (i_hi[m], i_lo[m]), -w_in[m])
    return A, cells


def reference_solution(system, b, dx, dim, singular):
    """Float64 dense solve; for a closed tank the mean-zero solution of the projected system."""
    A, cells = dense_matrix(system, dx, dim)
    rhs = b.astype(np.float32).astype(np.float64).ravel()[cells]
    if singular:
        rhs = rhs - rhs.mean()
    # for a closed tank, A + c 11^T has the same solution on mean-zero right-hand sides, with mean zero
    x = np.zeros(b.size)
    x[cells] = np.linalg.solve(A + (singular * A.diagonal().mean() / len(cells)), rhs)
    return x.reshape(b.shape)


def solve_all(problem, dim, tol=1e-6, preconditioners=PRECONDITIONERS):
    types, faces, extra, b_np, dx = problem
    system, n_fluid, singular = PressureSystem.from_numpy(types, faces, extra, dx, dim, DEVICE)
    solver = PressureSolver(types.shape, dim, dx, DEVICE)
    out = {}
    for pc in preconditioners:
        b = wp.array(b_np.astype(np.float32), dtype=float, device=DEVICE)
        x = wp.zeros(types.shape, dtype=float, device=DEVICE)
        info = solver.solve(system, b, x, tol=tol, max_iter=20000, singular=singular, n_fluid=n_fluid,
                            preconditioner=pc)
        assert info.converged and info.residual <= tol, (pc, info)
        out[pc] = (x.numpy().astype(np.float64), info)
    return out, system, singular


def check_against_reference(problem, dim, tol=1e-6, jump=False, err=5e-4):
    """Every preconditioner converges to the dense float64 solution of the same system."""
    types, faces, extra, b, dx = problem
    results, system, singular = solve_all(problem, dim, tol)
    ref = reference_solution(system, b, dx, dim, singular)
    A, cells = dense_matrix(system, dx, dim)
    rhs = b.ravel()[cells] - (b.ravel()[cells].mean() if singular else 0.0)
    for pc, (x, _) in results.items():
        # measured: at most 7e-5 (the 1000:1 jump cases), 4e-6 otherwise
        assert np.abs(x - ref).max() < err * np.abs(ref).max(), pc
        if not jump:  # with the jump, float32 round-off in x alone gives ||b - A x|| ~ 1e-4 ||b||
            assert np.linalg.norm(rhs - A @ x.ravel()[cells]) < 20 * tol * np.linalg.norm(rhs), pc
    return results, singular


def test_dense_reference_2d():
    # 10 x 10 cells with a free surface (the multigrid has two levels here).
    _, singular = check_against_reference(make_problem((10, 10), 2, surface=0.7), 2)
    assert not singular


@pytest.mark.parametrize("dim, interior", [(2, (45, 37)), (3, (17, 13, 11))])
def test_free_surface_odd_sizes(dim, interior):
    _, singular = check_against_reference(make_problem(interior, dim, surface=0.6, seed=1), dim)
    assert not singular


@pytest.mark.parametrize("dim, interior", [(2, (30, 21)), (3, (12, 9, 10))])
def test_closed_tank_is_projected(dim, interior):
    problem = make_problem(interior, dim, seed=2)
    results, singular = check_against_reference(problem, dim)
    assert singular
    fluid = problem[0] == FLUID
    for pc, (x, _) in results.items():
        assert abs(x[fluid].mean()) < 1e-5 * np.abs(x[fluid]).max(), pc  # constant removed


@pytest.mark.parametrize("dim, interior", [(2, (41, 39)), (3, (15, 17, 13))])
def test_density_jump_with_gas(dim, interior):
    problem = make_problem(interior, dim, surface=0.8, bubble=((0.45, 0.4, 0.5), 0.22), seed=3)
    assert (problem[2] > 0).sum() > 20  # a real bubble
    _, singular = check_against_reference(problem, dim, jump=True)
    assert not singular


@pytest.mark.parametrize("dim, interior", [(2, (40, 33)), (3, (14, 13, 12))])
def test_closed_tank_with_gas_is_nearly_singular(dim, interior):
    # Only the gas's tiny kappa/dt^2 pins the constant (eigenvalue below 1e-6 of the largest), so the
    # solution's constant part is loose at a given residual: measured error up to 8e-4 (multigrid).
    problem = make_problem(interior, dim, bubble=((0.45, 0.4, 0.5), 0.22), seed=3)
    _, singular = check_against_reference(problem, dim, jump=True, err=3e-3)
    assert not singular


def test_multigrid_needs_far_fewer_iterations():
    # 1000:1 bubble in a 2D tank of 127 x 120 cells, random right-hand side. Measured: jacobi 525,
    # multigrid 9 iterations (58x). Asserted with a wide margin (round-off, future smoother changes): 20x.
    problem = make_problem((127, 120), 2, surface=0.8, bubble=((0.4, 0.4, 0.5), 0.2), seed=4)
    results, _, _ = solve_all(problem, 2, tol=1e-5, preconditioners=("jacobi", "multigrid"))
    it = {pc: info.iterations for pc, (_, info) in results.items()}
    assert it["multigrid"] * 20 <= it["jacobi"], it


@pytest.mark.parametrize("dim, interior, surface", [(2, (37, 29), 0.7), (3, (13, 11, 9), None)])
def test_multigrid_is_symmetric_positive_definite(dim, interior, surface):
    types, faces, extra, _, dx = make_problem(interior, dim, surface=surface,
                                              bubble=((0.5, 0.4, 0.5), 0.25), seed=5)
    system, _, _ = PressureSystem.from_numpy(types, faces, extra, dx, dim, DEVICE)
    mg = MultigridPreconditioner(types.shape, dim, dx, DEVICE)
    mg.build(system)
    assert len(mg.shapes) >= 3
    rng = np.random.default_rng(6)
    fluid = types == FLUID

    def apply(v):
        r = wp.array(np.where(fluid, v, 0.0).astype(np.float32), dtype=float, device=DEVICE)
        z = wp.zeros(types.shape, dtype=float, device=DEVICE)
        mg.apply(r, z)
        return z.numpy().astype(np.float64)

    for _ in range(3):
        x, y = (np.where(fluid, rng.normal(size=types.shape), 0.0) for _ in range(2))
        mx, my = apply(x), apply(y)
        assert abs((x * my).sum() - (y * mx).sum()) < 1e-5 * np.linalg.norm(x) * np.linalg.norm(my)
        assert (x * mx).sum() > 0.0
        assert np.all(mx[~fluid] == 0.0)


# Exact multigrid-PCG iteration counts on seeded problems. The solution alone cannot show a weaker
# preconditioner: a smoother relaxed to x += 0.9 (x_GS - x) converges to the same answer in one more
# iteration here (11-20% more), which the tests above (generous iteration bounds) let through. Each count below was
# measured with 1 and 2 threads (bit-identical solutions: core/threads.py) and every box is over
# threads.SPLIT_CELLS cells, so the 2-thread run really splits its launches. Margin: the relative
# residual is at least 1.45x below tol at the counted iteration and 1.45x above it one iteration
# earlier, so float rounding cannot move a count. Mutants measured (benchmarks/test_power/mutation_score.py):
# smoother weight 0.9 adds an iteration to all but the 2D closed tank; 1.03 saves one in the 3D
# closed tank and the 3D bubble, 0.97 costs one in the 3D free surface. A deliberate change of the
# smoother, transfers or coarse operators moves these counts: re-measure them and say why in the commit.
ITERATION_PINS = {  # id: (interior cells, dim, free surface height, bubble, seed, iterations)
    "2d_surface": ((160, 150), 2, 0.7, None, 22, 7),
    "2d_closed": ((130, 130), 2, None, None, 22, 5),
    "2d_bubble_surface": ((160, 150), 2, 0.75, ((0.45, 0.4, 0.5), 0.2), 20, 9),
    "2d_bubble_closed": ((130, 130), 2, None, ((0.5, 0.4, 0.5), 0.2), 22, 7),
    "3d_surface": ((28, 28, 28), 3, 0.75, None, 22, 5),
    "3d_closed": ((27, 26, 25), 3, None, None, 24, 5),
    "3d_bubble_surface": ((28, 28, 28), 3, 0.8, ((0.45, 0.4, 0.5), 0.25), 22, 9),
}


@pytest.mark.parametrize("case", list(ITERATION_PINS))
def test_multigrid_iteration_counts_are_pinned(case):
    from warp_mpm_bubbles.core.threads import SPLIT_CELLS, Parallel

    interior, dim, surface, bubble, seed, expected = ITERATION_PINS[case]
    types, faces, extra, b_np, dx = make_problem(interior, dim, surface=surface, bubble=bubble, seed=seed)
    system, n_fluid, singular = PressureSystem.from_numpy(types, faces, extra, dx, dim, DEVICE)
    assert singular == (surface is None and bubble is None)  # only an all-liquid closed tank is singular
    tol, solutions = 1e-6, []
    for threads in (1, 2):
        solver = PressureSolver(types.shape, dim, dx, DEVICE, parallel=Parallel(threads))
        b = wp.array(b_np.astype(np.float32), dtype=float, device=DEVICE)
        x = wp.zeros(types.shape, dtype=float, device=DEVICE)
        info = solver.solve(system, b, x, tol=tol, max_iter=200, singular=singular, n_fluid=n_fluid,
                            preconditioner="multigrid")
        assert np.prod([h - l for l, h in zip(*solver.box)]) >= SPLIT_CELLS  # 2 threads split the launches
        assert info.converged and info.residual <= tol, (threads, info)
        assert info.iterations == expected, (f"{case}: {info.iterations} multigrid-PCG iterations with {threads} "
                                             f"thread(s), pinned at {expected}")
        solutions.append(x.numpy())
    np.testing.assert_array_equal(solutions[0], solutions[1])


def test_recorded_launches_are_kept_between_solves_and_never_replayed_stale(monkeypatch):
    # One solver meets a sequence of systems, as a simulation's does from step to step: the same one
    # again (it records nothing: the launches of the last solve replay), a new surface written into the
    # same arrays (the fluid box grows), and a right-hand side in another array. Each answer must be
    # a fresh solver's, bit for bit: a launch replayed over the old, smaller box or the old array
    # would differ (over a larger box it would not: the box's result is the whole grid's).
    from warp_mpm_bubbles.core.threads import Parallel

    dim, tol = 2, 1e-6
    problems = [make_problem((40, 40), dim, surface=s, seed=3) for s in (0.5, 0.5, 0.8, 0.8)]
    system, n_fluid, singular = PressureSystem.from_numpy(*problems[0][:3], problems[0][4], dim, DEVICE)
    kept = PressureSolver(problems[0][0].shape, dim, problems[0][4], DEVICE, parallel=Parallel(2))
    records = []
    launch = wp.launch
    monkeypatch.setattr(wp, "launch", lambda *a, **kw: (records.append(kw.get("record_cmd", False)), launch(*a, **kw))[1])
    b_kept = wp.zeros(problems[0][0].shape, dtype=float, device=DEVICE)
    x_kept = wp.zeros(problems[0][0].shape, dtype=float, device=DEVICE)
    boxes = []
    for step, (types, faces, extra, b_np, dx) in enumerate(problems):
        fresh_system, n_fluid, singular = PressureSystem.from_numpy(types, faces, extra, dx, dim, DEVICE)
        for dst, src in zip((system.types, *system.inv_rho, system.diag, system.extra_diag),
                            (fresh_system.types, *fresh_system.inv_rho, fresh_system.diag, fresh_system.extra_diag)):
            wp.copy(dst, src)  # the simulation's arrays are written in place, step after step
        if step == 3:  # the right-hand side in another array
            b_kept = wp.zeros(types.shape, dtype=float, device=DEVICE)
        answers = []
        for solver, sys_, b, x in ((kept, system, b_kept, x_kept),
                                   (PressureSolver(types.shape, dim, dx, DEVICE), fresh_system, None, None)):
            b = b if b is not None else wp.zeros(types.shape, dtype=float, device=DEVICE)
            b.assign(b_np.astype(np.float32))
            x = x if x is not None else wp.zeros(types.shape, dtype=float, device=DEVICE)
            x.zero_()  # from rest: the fresh solver's start
            records.clear()
            info = solver.solve(sys_, b, x, tol=tol, max_iter=200, singular=singular, n_fluid=n_fluid,
                                preconditioner="multigrid")
            assert info.converged
            if solver is kept and step == 1:
                assert not any(records), f"the same system again recorded {sum(records)} launches"
            answers.append(x.numpy())
        boxes.append(kept.box)
        np.testing.assert_array_equal(answers[0], answers[1], err_msg=f"solve {step}")
    assert boxes[0] == boxes[1] and boxes[2] != boxes[1]  # the sequence moved the box once


def falling_block(shape, lo, hi, seed):
    """A liquid block [lo, hi) with a free surface all round, in a closed box of `shape` cells (walls
    on its outer layer): make_problem's face weights and a random right-hand side."""
    rng = np.random.default_rng(seed)
    types = np.full(shape, EMPTY, np.int32)
    types[tuple(slice(a, b) for a, b in zip(lo, hi))] = FLUID
    for a in range(3):
        for end in (0, -1):
            idx = [slice(None)] * 3
            idx[a] = end
            types[tuple(idx)] = SOLID_FREE_SLIP
    faces = face_weights(types, np.full(shape, RHO_L), 3, rng)
    b = np.where(types == FLUID, rng.normal(size=shape), 0.0)
    return types, faces, np.zeros(shape), b, 1.0 / (shape[0] - 2)


@pytest.mark.parametrize("by_reference", [True, False])
def test_recorded_launches_follow_a_moving_box(monkeypatch, by_reference):
    # The falling block of the peer benchmark moves the fluid's box every step: the solver keeps its
    # recorded launches (the CG's and every V-cycle level's) and moves them to the new box rather than
    # recording them again (core/launch.Slabs). Each answer must be a fresh solver's, bit for bit: a
    # launch left on the old box (its slab, its dims, the planes it sums, a level's box) would differ.
    # by_reference False: a Warp whose recorded launches copy their structs (core/launch.record) makes
    # a moved box record them again, and only a box that did not move replays.
    from warp_mpm_bubbles.core import launch as launch_module
    from warp_mpm_bubbles.core.threads import SPLIT_CELLS, Parallel

    monkeypatch.setattr(launch_module, "_structs_by_reference", by_reference)

    shape, size, tol = (34, 34, 34), 24, 1e-6
    # (low corner, extent): the first solve records; then a pure translation, one that also makes the
    # box 3 planes longer along x (the slabs' dims, the planes summed: the box's first and last planes
    # hold no fluid, so a count of planes off by one would not show), 1 shorter along x and 2 along y,
    # and the same box again.
    blocks = [((5, 8, 5), (24, 24, 24)), ((5, 7, 5), (24, 24, 24)), ((5, 6, 5), (27, 24, 24)),
              ((6, 5, 4), (26, 22, 24)), ((6, 5, 4), (26, 22, 24))]
    kept = PressureSolver(shape, 3, 1.0 / (shape[0] - 2), DEVICE, parallel=Parallel(2))
    system = None
    records = []
    launch = wp.launch
    monkeypatch.setattr(wp, "launch", lambda *a, **kw: (records.append(kw.get("record_cmd", False)), launch(*a, **kw))[1])
    b_kept, x_kept = (wp.zeros(shape, dtype=float, device=DEVICE) for _ in range(2))
    boxes = []
    for step, (lo, extent) in enumerate(blocks):
        types, faces, extra, b_np, dx = falling_block(shape, lo, tuple(l + e for l, e in zip(lo, extent)), seed=step)
        fresh_system, n_fluid, singular = PressureSystem.from_numpy(types, faces, extra, dx, 3, DEVICE)
        assert not singular
        if system is None:
            system = PressureSystem.from_numpy(types, faces, extra, dx, 3, DEVICE)[0]
        for dst, src in zip((system.types, *system.inv_rho, system.diag, system.extra_diag),
                            (fresh_system.types, *fresh_system.inv_rho, fresh_system.diag, fresh_system.extra_diag)):
            wp.copy(dst, src)  # the simulation's arrays are written in place, step after step
        answers = []
        for solver, sys_, b, x in ((kept, system, b_kept, x_kept),
                                   (PressureSolver(shape, 3, dx, DEVICE, parallel=Parallel(2)), fresh_system,
                                    wp.zeros(shape, dtype=float, device=DEVICE), wp.zeros(shape, dtype=float, device=DEVICE))):
            b.assign(b_np.astype(np.float32))
            x.zero_()  # from rest: the fresh solver's start
            records.clear()
            info = solver.solve(sys_, b, x, tol=tol, max_iter=200, singular=False, n_fluid=n_fluid,
                                preconditioner="multigrid")
            assert info.converged
            if solver is kept and step > 0 and (by_reference or blocks[step] == blocks[step - 1]):
                assert not any(records), f"solve {step} recorded {sum(records)} launches: the box's move was not kept"
            elif solver is kept and step > 0:
                kept_records = sum(records)
            if solver is not kept and not by_reference and 0 < step and blocks[step] != blocks[step - 1]:
                assert kept_records == sum(records), (f"solve {step} recorded {kept_records} launches, a fresh "
                                                      f"solver {sum(records)}: some replayed for another box")
            answers.append(x.numpy())
        boxes.append(kept.box)
        np.testing.assert_array_equal(answers[0], answers[1], err_msg=f"solve {step}")
    extents = [tuple(h - l for l, h in zip(*box)) for box in boxes]
    assert len(set(boxes[:4])) == 4 and boxes[4] == boxes[3]  # the box moved in every solve but the last
    assert extents[0] == extents[1] and extents[2][0] != extents[1][0] and extents[3][1] != extents[2][1]
    assert all(np.prod(e) >= SPLIT_CELLS for e in extents)  # 2 threads split the finest launches in slabs
    assert kept.slabs.launches[0] and len(kept.slabs.walks) == 2  # the slabs that moved held the launches
