"""Mutation score of the test suite: small deliberate physics errors, one at a time, each
applied to a temporary copy of the repository, and the tests that should notice run there.

    python -m benchmarks.test_power.mutation_score              # all mutations (slow: an hour or more on 2 cores)
    python -m benchmarks.test_power.mutation_score --list       # the mutations, and where each snippet is found
    python -m benchmarks.test_power.mutation_score --only gravity_x1.05,theta_half --jobs 2
    python -m benchmarks.test_power.mutation_score --measured   # what the tests measure, to one file
    python -m benchmarks.test_power.mutation_score --only sigma_x0.97 --tests tests/test_physics_3d.py   # one file's power
    python -m benchmarks.test_power.mutation_score --quick      # one mutant (runner_ids_shifted), into <device>_quick.*

Each mutation is (id, module, old snippet, new snippet, tests). The snippet is searched in every .py
file of the package, not only in `module` (the file it lived in when written): code moves, and a
mutation should follow it. A snippet found zero times or more than once is an ERROR of the harness,
reported and not counted. "caught": the selected tests fail (pytest exit 1) or stop (exit 2, e.g.
the mutant does not import) or run past --timeout; "escaped": they pass. Score = caught / counted.

Results go to benchmarks/results/mutation_score/<device>.{json,md} (--measured: <device>_measured.*);
a run with --only updates its rows and keeps the others (each row records the commit it was measured at). Not in CI: every mutant
recompiles a Warp module (shared WARP_CACHE_PATH keeps the unmutated ones).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from benchmarks import harness

ROOT = harness.ROOT
PACKAGE = "warp_mpm_bubbles"
QUICK = "runner_ids_shifted"  # --quick's one mutant: a Python line, so no Warp module recompiles

# Test selections (pytest node ids, relative to the repository root).
P3D = "tests/test_physics_3d.py"
DROP3D = P3D + "::test_3d_drop_pressure_is_two_sigma_over_r"
BUBBLE3D = P3D + "::test_3d_bubble_jump_is_two_sigma_over_r"
DIV3D = P3D + "::test_3d_projection_is_divergence_free_in_x_y_and_z"
VOL3D = P3D + "::test_3d_collapsing_block_keeps_its_volume"
GL = "tests/test_gas_laws.py"
KAPPA = GL + "::test_gas_compresses_by_its_law_in_each_step"
MINNAERT_AD = GL + "::test_adiabatic_bubble_breathes_at_the_minnaert_frequency_with_gamma"
RISING_LAW = GL + "::test_rising_bubble_volume_follows_its_gas_law"
LAYERED = GL + "::test_layered_column_pressure_needs_the_face_weight_theta"
EN = "tests/test_energy.py"
VORTEX = EN + "::test_inviscid_vortex_energy_budget_is_the_transfers_dissipation"
FREEFALL = EN + "::test_free_fall_follows_g_and_keeps_kinetic_plus_potential_energy"
VOLCORR = EN + "::test_volume_correction_asks_its_rate_of_the_overfill"
HYDROSTATIC = "tests/test_solver.py::test_tank_pressure_is_hydrostatic"
MINNAERT_2D = "tests/test_gas.py::test_bubble_breathes_at_the_2d_minnaert_frequency"
TENSION = "tests/test_tension.py"
VISCOSITY = "tests/test_viscosity.py"
STEP = "tests/test_time_step.py"
WS = "tests/test_walls_and_sources.py"
CAVITY_FILE = "tests/test_cavity.py"
CAVITY = CAVITY_FILE + "::test_a_near_vacuum_cavity_collapses_on_the_cylindrical_rayleigh_time"
TANK = WS + "::test_resting_tank_pressure_has_slope_rho_g_and_its_zero_at_the_surface"
POCKET = "tests/test_voids.py::test_a_void_of_pocket_cells_is_trapped_air_and_one_cell_less_is_liquid"
MG_PINS = "tests/test_pressure.py::test_multigrid_iteration_counts_are_pinned"

# (id, module it lives in today, exact old snippet, new snippet, tests). The table rows are
# curvature_3d_no_z, divergence_z_x0.95, theta_half, kappa_x0.9, gamma_x1.1, volume_correction_x2,
# foam_lifetime_x1.1, runner_ids_shifted, sigma_x0.97, sigma_x1.03, gravity_x1.05, apic_dropped_p2g,
# velocity_gain_0.2pct.
TK, GK, TE = "core/transfer_kernels.py", "core/grid_kernels.py", "physics/tension.py"
SIM = "core/simulation.py"
_SMOOTH = "x[i, j, k] = (b[i, j, k] + L.scale * n) / d"  # the red-black Gauss-Seidel update
_GAS_RATE_LIMIT = "limit = min(limit, max(GAS_EXPANSION_SHARE / rate, floor))"
_POCKET = "large = sizes[inverse] >= POCKET_CELLS"
_P2G_GAS = ("pg = gas_pressure(law[p], J[p], gamma[p], p_atm)\n"
            "    kappa = gas_compressibility(law[p], J[p], gamma[p], p_atm)")
_G2P_MOVE = "moved = xp + dt * vp\n        code = open_wall_exit(moved, geo, phase[p])"  # g2p's, not foam's
MUTATIONS = [
    # --- transfers
    ("apic_dropped_p2g", TK, "wp.vec2(wm * (vel + wp.dot(grad, dpos)), wm)", "wp.vec2(wm * vel, wm)", [VORTEX, VISCOSITY]),
    ("velocity_gain_0.2pct", TK, "xn, vn = keep_in_domain(moved, vp, code, geo)",
     "xn, vn = keep_in_domain(moved, vp, code, geo)\n        vn = 1.002 * vn", [VORTEX, FREEFALL]),
    ("apic_gradient_x0.9", TK, "grad += (4.0 / (dx * dx)) * w * g * dpos", "grad += (3.6 / (dx * dx)) * w * g * dpos",
     [VORTEX, VISCOSITY]),
    ("bspline_centre_weight", TK, "0.75 - (f - 1.0) * (f - 1.0)", "0.76 - (f - 1.0) * (f - 1.0)", [FREEFALL, VORTEX]),
    ("advection_x1.03", TK, _G2P_MOVE, _G2P_MOVE.replace("xp + dt * vp", "xp + 1.03 * dt * vp"), [FREEFALL]),
    ("liquid_volume_splat_x1.03", TK, "sc.base[2] + k, wp.vec2(w * m, w * vol))",
     "sc.base[2] + k, wp.vec2(w * m, 1.03 * w * vol))", [HYDROSTATIC, LAYERED]),
    ("gas_volume_rate_x1.05", TK, "J[p] = J[p] * wp.exp(wp.clamp(dt * r, -1.0, 1.0))",
     "J[p] = J[p] * wp.exp(wp.clamp(1.05 * dt * r, -1.0, 1.0))", [KAPPA, MINNAERT_2D]),
    # --- gas law
    ("kappa_x0.9", TK, "return 1.0 / p_abs", "return 0.9 / p_abs", [KAPPA, MINNAERT_2D]),
    ("kappa_x0.97", TK, "return 1.0 / p_abs", "return 0.97 / p_abs", [KAPPA, MINNAERT_2D]),
    ("gamma_x1.1", TK, _P2G_GAS, _P2G_GAS.replace("gamma[p]", "1.1 * gamma[p]"), [KAPPA, MINNAERT_AD]),
    ("gamma_x1.03", TK, _P2G_GAS, _P2G_GAS.replace("gamma[p]", "1.03 * gamma[p]"), [KAPPA, MINNAERT_AD]),
    ("isothermal_pressure_x1.03", TK, "return p_atm * (1.0 / J - 1.0)", "return 1.03 * p_atm * (1.0 / J - 1.0)",
     [KAPPA, RISING_LAW]),
    ("incompressible_gas_compresses", TK, "        return 1.0 / (gamma * p_abs)\n    return 0.0",
     "        return 1.0 / (gamma * p_abs)\n    return 1.0 / p_abs", [RISING_LAW]),
    ("seeded_gamma_x1.03", SIM, "J0 = (p_atm / (p_atm + gauge)) ** (1.0 / gamma)",
     "J0 = (p_atm / (p_atm + gauge)) ** (1.0 / (1.03 * gamma))", [MINNAERT_AD]),
    # --- grid
    ("gravity_x1.05", GK, "vel[i, j, k] = mom[i, j, k] / m + dt * accel", "vel[i, j, k] = mom[i, j, k] / m + 1.05 * dt * accel",
     [FREEFALL, LAYERED, HYDROSTATIC]),
    ("gravity_x1.03", GK, "vel[i, j, k] = mom[i, j, k] / m + dt * accel", "vel[i, j, k] = mom[i, j, k] / m + 1.03 * dt * accel",
     [FREEFALL, LAYERED]),
    ("gravity_x0.97", GK, "vel[i, j, k] = mom[i, j, k] / m + dt * accel", "vel[i, j, k] = mom[i, j, k] / m + 0.97 * dt * accel",
     [FREEFALL, LAYERED]),
    ("rho_liquid_x1.03", GK, "if two_phase == 0:  # liquid-only scenes never read the gas arrays\n        rho = ml / vl",
     "if two_phase == 0:  # liquid-only scenes never read the gas arrays\n        rho = 1.03 * ml / vl", [HYDROSTATIC, TANK]),
    ("rho_liquid_with_gas_x0.97", GK, "elif vl > 0.0:\n                rho = ml / vl",
     "elif vl > 0.0:\n                rho = 0.97 * ml / vl", [LAYERED]),
    # --- near-vacuum cavities (physics/cavity.py): the collapse time, and the cavity's own rules
    ("cavity_liquid_density_x0.97", GK, "elif vl > 0.0:\n                rho = ml / vl",
     "elif vl > 0.0:\n                rho = 0.97 * ml / vl", [CAVITY]),
    ("cavity_edge_keeps_compressibility", "physics/cavity.py", "    if cavity[i, j, k] == CAVITY_EDGE:\n        gas_kv[i, j, k] = 0.0",
     "    if cavity[i, j, k] == CAVITY_EDGE:\n        gas_kv[i, j, k] = gas_kv[i, j, k]", [CAVITY_FILE]),
    ("free_surface_fraction_shift", GK, "theta = (phi_fluid - 0.5) / (phi_fluid - phi_empty)",
     "theta = (phi_fluid - 0.4) / (phi_fluid - phi_empty)", [HYDROSTATIC, TANK]),
    ("divergence_z_x0.95", GK, "div += vel_w[i, j, k + 1] - vel_w[i, j, k]\n    return div",
     "div += 0.95 * (vel_w[i, j, k + 1] - vel_w[i, j, k])\n    return div", [DIV3D, VOL3D]),
    ("volume_correction_x2", "core/volume_correction.py", "return rate * cell_excess(splat, two_phase, c, enclosed, inv_dx2, dx, band)",
     "return 2.0 * rate * cell_excess(splat, two_phase, c, enclosed, inv_dx2, dx, band)",
     [VOLCORR, VOL3D, "tests/test_volume_shift.py::test_the_shift_asks_the_rate_and_the_flow_is_left_alone"]),
    ("pressure_gradient_x0.97", GK, "vel[i, j, k] = vel[i, j, k] - dt * inv_rho[i, j, k] * (p_hi - p_lo) / dx",
     "vel[i, j, k] = vel[i, j, k] - 0.97 * dt * inv_rho[i, j, k] * (p_hi - p_lo) / dx", [DIV3D, HYDROSTATIC]),
    # --- interface (sharp liquid-gas faces, Wood mixture)
    ("theta_half", GK, "theta = wp.clamp(psi_l / (psi_l - psi_g), 0.0, 1.0)", "theta = 0.5", [LAYERED]),
    ("wood_mixture_dropped", "core/gas_law.py", "kappa = kappa * vg / cell_volume", "kappa = kappa", [KAPPA, MINNAERT_2D]),
    ("system_kappa_x0.97", GK, "kappa = kv / vg", "kappa = 0.97 * kv / vg", [KAPPA, MINNAERT_2D]),
    # --- pressure solve
    ("cg_step_x0.97", "core/pressure.py", "x[i, j, k] = x[i, j, k] + alpha * d[i, j, k]",
     "x[i, j, k] = x[i, j, k] + 0.97 * alpha * d[i, j, k]", [HYDROSTATIC, "tests/test_pressure.py"]),
    ("operator_offdiagonal_x1.03", "core/pressure.py", "Ap = diag[i, j, k] * p[i, j, k] - n * inv_dx2",
     "Ap = diag[i, j, k] * p[i, j, k] - 1.03 * n * inv_dx2", ["tests/test_pressure.py", HYDROSTATIC]),
    ("multigrid_smoother_damped", "core/multigrid.py", _SMOOTH, "x[i, j, k] = (b[i, j, k] + 0.5 * L.scale * n) / d",
     ["tests/test_pressure.py"]),
    # a relaxed (or over-relaxed) Gauss-Seidel: the same answer, in more (or fewer) iterations
    ("multigrid_smoother_weight_0.9", "core/multigrid.py", _SMOOTH,
     "x[i, j, k] = 0.9 * (b[i, j, k] + L.scale * n) / d + 0.1 * x[i, j, k]", [MG_PINS]),
    ("multigrid_smoother_weight_1.03", "core/multigrid.py", _SMOOTH,
     "x[i, j, k] = 1.03 * (b[i, j, k] + L.scale * n) / d - 0.03 * x[i, j, k]", [MG_PINS]),
    ("multigrid_prolongation_x0.5", "core/multigrid.py", "x[i, j, k] = x[i, j, k] + x_coarse[i // 2, j // 2, k // 2]",
     "x[i, j, k] = x[i, j, k] + 0.5 * x_coarse[i // 2, j // 2, k // 2]", ["tests/test_pressure.py"]),
    # --- voids: a region of POCKET_CELLS cells is trapped air, one cell less is liquid
    ("void_pocket_threshold_exclusive", "core/voids.py", _POCKET, _POCKET.replace(">=", ">"), [POCKET]),
    ("void_pocket_threshold_minus_one", "core/voids.py", _POCKET, _POCKET + " - 1", [POCKET]),
    # --- surface tension
    ("curvature_3d_no_z", "physics/curvature.py", "        if a < dim:\n            ea = unit(a)",
     "        if a < wp.min(dim, 2):\n            ea = unit(a)", [DROP3D, BUBBLE3D]),
    ("sigma_x0.97", TE, "orient * sigma * kappa / dx", "orient * 0.97 * sigma * kappa / dx", [DROP3D, BUBBLE3D, TENSION]),
    ("sigma_x1.03", TE, "orient * sigma * kappa / dx", "orient * 1.03 * sigma * kappa / dx", [DROP3D, BUBBLE3D, TENSION]),
    ("curvature_interpolation_swapped", TE,
     "kappa = (1.0 - theta) * curvature[cl[0], cl[1], cl[2]] + theta * curvature[cn[0], cn[1], cn[2]]",
     "kappa = theta * curvature[cl[0], cl[1], cl[2]] + (1.0 - theta) * curvature[cn[0], cn[1], cn[2]]",
     [DROP3D, BUBBLE3D, TENSION]),
    ("film_retraction_half_speed", TE, "step = wp.min(capillary_speed * dt, 0.25 * dx)",
     "step = wp.min(0.5 * capillary_speed * dt, 0.25 * dx)", [TENSION]),
    ("film_speed_sigma_x0.95", TE, "math.sqrt(2.0 * self.sigma / (self.rho_liquid * g.dx))",
     "math.sqrt(1.9 * self.sigma / (self.rho_liquid * g.dx))", [BUBBLE3D]),
    ("capillary_dt_limit_x2", TE, "(4.0 * math.pi * self.sigma)", "(1.0 * math.pi * self.sigma)", [STEP, TENSION]),
    # --- viscosity (the stress form, physics/viscosity.py and physics/viscous_solve.py)
    ("mu_x0.97", "physics/viscosity.py", 'self.mu_liquid = mu([m for m in materials if m.kind == "liquid"])',
     'self.mu_liquid = 0.97 * mu([m for m in materials if m.kind == "liquid"])', [VISCOSITY]),
    ("mu_x1.03", "physics/viscosity.py", 'self.mu_liquid = mu([m for m in materials if m.kind == "liquid"])',
     'self.mu_liquid = 1.03 * mu([m for m in materials if m.kind == "liquid"])', [VISCOSITY]),
    ("no_slip_mirror_weakened", "physics/viscous_solve.py", "        v_lo = 2.0 * v_lo - v_hi\n",
     "        v_lo = 2.0 * v_lo - 0.5 * v_hi\n", [VISCOSITY]),
    ("viscous_dt_limit_x2", "physics/viscosity.py", "return 2.0 / rate if rate > 0.0",
     "return 4.0 / rate if rate > 0.0", [STEP, VISCOSITY]),
    ("gas_expansion_limit_x1.1", "physics/gas.py", _GAS_RATE_LIMIT,
     _GAS_RATE_LIMIT.replace("GAS_EXPANSION_SHARE / rate", "1.1 * GAS_EXPANSION_SHARE / rate"), [STEP]),
    ("gas_expansion_limit_x1.03", "physics/gas.py", _GAS_RATE_LIMIT,
     _GAS_RATE_LIMIT.replace("GAS_EXPANSION_SHARE / rate", "1.03 * GAS_EXPANSION_SHARE / rate"), [STEP]),
    ("cfl_x2", SIM, '"cfl": s.cfl * self.grid.dx / speed', '"cfl": 2.0 * s.cfl * self.grid.dx / speed',
     [STEP, "tests/test_solver.py::test_time_steps_land_on_frames_and_respect_cfl"]),
    # --- effects
    ("foam_lifetime_x1.1", "effects/foam.py", "life[p] = -mean_life * wp.log(1.0 - wp.randf(state))",
     "life[p] = -1.1 * mean_life * wp.log(1.0 - wp.randf(state))", ["tests/test_foam.py"]),
    ("foam_rise_speed_half", "effects/foam.py", "lift = rise_speed * wp.clamp(", "lift = 0.5 * rise_speed * wp.clamp(",
     ["tests/test_foam.py", WS + "::test_foam_under_the_surface_floats_up_at_its_rise_speed"]),
    ("subgrid_buoyancy_x1.1", "effects/subgrid.py", "- dt * (rho_l - rho_g) * vol * gravity",
     "- 1.1 * dt * (rho_l - rho_g) * vol * gravity", ["tests/test_subgrid.py"]),
    ("subgrid_drag_x1.1", "effects/subgrid.py", "return 0.5 * rho_l * cd_s * PI * r * r",
     "return 0.55 * rho_l * cd_s * PI * r * r", ["tests/test_subgrid.py"]),
    ("entrainment_rate_half", "effects/entrainment.py", "expected = rate * phi * dt", "expected = 0.5 * rate * phi * dt",
     ["tests/test_subgrid.py"]),
    ("stream_speed_x1.1", "effects/emitters.py", "state[i, 0] += e.speed * overlap", "state[i, 0] += 1.1 * e.speed * overlap",
     ["tests/test_emitters.py"]),
    ("air_stone_rate_x1.1", "effects/emitters.py", "state[i, 0] += e.rate * overlap", "state[i, 0] += 1.1 * e.rate * overlap",
     ["tests/test_emitters.py", WS + "::test_air_stone_count_follows_its_rate_at_every_moment"]),
    ("collider_acceleration_x2", "effects/colliders.py", "s.velocity * tau + 0.5 * tau * tau * s.acceleration",
     "s.velocity * tau + 1.0 * tau * tau * s.acceleration", ["tests/test_colliders.py"]),
    ("collider_face_velocity_x0.9", "effects/colliders.py", "vel[i, j, k] = shape_velocity(shapes[c], t)[axis]",
     "vel[i, j, k] = 0.9 * shape_velocity(shapes[c], t)[axis]", ["tests/test_colliders.py"]),
    # --- output
    ("usd_velocities_x0.5", "io/usd_output.py", "Vt.Vec3fArray.FromNumpy(vel)", "Vt.Vec3fArray.FromNumpy(vel * 0.5)",
     ["tests/test_usd_output.py", "tests/test_runner_output.py"]),
    ("usd_extent_without_radius", "io/usd_output.py",
     "lo, hi = pos.min(axis=0) - self.radius, pos.max(axis=0) + self.radius",
     "lo, hi = pos.min(axis=0), pos.max(axis=0)", ["tests/test_usd_output.py"]),
    ("runner_ids_shifted", "io/runner.py", 'p["velocities"], p["ids"], p["material"], radii,',
     'p["velocities"], p["ids"] + 1, p["material"], radii,', ["tests/test_runner_output.py"]),
]


@dataclass
class Outcome:
    id: str
    status: str  # caught | escaped | timeout | error
    seconds: float
    detail: str  # the first failing test, or why it is an error
    file: str = ""
    commit: str = ""


def find_snippet(tree: Path, old: str) -> tuple[list[Path], int]:
    """The package files holding `old`, and how many times it occurs in all of them."""
    hits, count = [], 0
    for path in sorted((tree / PACKAGE).rglob("*.py")):
        n = path.read_text().count(old)
        if n:
            hits.append(path)
            count += n
    return hits, count


def copy_tree(dest: Path):
    ignore = shutil.ignore_patterns(".git", "__pycache__", "*.usd*", "*_frames", "scratch", ".pytest_cache", "results")
    shutil.copytree(ROOT, dest, ignore=ignore)


def first_failure(output: str) -> str:
    for line in output.splitlines():
        if line.startswith(("FAILED ", "ERROR ")):
            return line.split(" - ")[0][:160]
    m = re.search(r"(\w+Error: [^\n]{0,120})", output)
    return m.group(1) if m else output.strip().splitlines()[-1][:160] if output.strip() else ""


def run_mutation(m, timeout: float, commit: str) -> Outcome:
    mid, module, old, new, tests = m
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=f"mut_{mid}_") as tmp:
        tree = Path(tmp) / "repo"
        copy_tree(tree)
        hits, count = find_snippet(tree, old)
        if count != 1:
            where = ", ".join(str(h.relative_to(tree)) for h in hits) or "nowhere"
            return Outcome(mid, "error", 0.0, f"snippet found {count} times ({where}); expected in {module}", "", commit)
        target = hits[0]
        target.write_text(target.read_text().replace(old, new))
        env = dict(os.environ, PYTHONPATH=str(tree), PYTHONDONTWRITEBYTECODE="1")
        cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *tests]
        try:
            proc = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return Outcome(mid, "timeout", time.perf_counter() - start, f"over {timeout:.0f} s",
                           str(target.relative_to(tree)), commit)
        seconds = time.perf_counter() - start
        output = proc.stdout + proc.stderr
        rel = str(target.relative_to(tree))
        if proc.returncode == 0:
            return Outcome(mid, "escaped", seconds, "all selected tests pass", rel, commit)
        if proc.returncode in (1, 2):
            return Outcome(mid, "caught", seconds, first_failure(output), rel, commit)
        return Outcome(mid, "error", seconds, f"pytest exit {proc.returncode}: {first_failure(output)}", rel, commit)


def load_previous(args) -> dict:
    try:
        return {row["id"]: row for row in (harness.read_result("mutation_score", args) or {}).get("mutations", [])}
    except (ValueError, KeyError):
        return {}


def score(rows) -> tuple[int, int, float]:
    counted = [r for r in rows if r["status"] in ("caught", "escaped", "timeout")]
    caught = sum(r["status"] != "escaped" for r in counted)
    return caught, len(counted), (caught / len(counted) if counted else 0.0)


def write_results(rows, args):
    caught, counted, frac = score(rows)
    lines = [f"**{caught} of {counted} caught ({100 * frac:.0f}%)**; errors of the harness are not counted. "
             "Command: `python -m benchmarks.test_power.mutation_score` (rows from `--only` runs keep their commit).", "",
             "| mutation | module | status | first failing test / note | s | commit |",
             "|---|---|---|---|---:|---|"]
    for r in rows:
        detail = r["detail"].replace("|", "\\|")
        lines.append(f"| `{r['id']}` | {r['file'] or r['module']} | {r['status']} | {detail} | "
                     f"{r['seconds']:.0f} | {r['commit']} |")
    harness.write_result("mutation_score", args, {"score": frac, "caught": caught, "counted": counted,
                                                  "mutations": rows}, "\n".join(lines), title="Mutation score")


# Tests that print what they measure: --measured collects those lines.
MEASURED_TESTS = [P3D, GL, EN, WS, "tests/test_runner_output.py", TENSION, VISCOSITY,
                  "tests/test_foam.py::test_each_foam_particle_lives_its_own_drawn_lifetime",
                  "tests/test_gas.py::test_rising_bubble_stays_finite_bounded_and_inside",
                  "tests/test_gas.py::test_rising_bubble_rises"]


WARP_NOISE = re.compile(r"^(Warp \d|Module |\s+(CUDA Toolkit|Devices:|\"cpu\"|Kernel cache:|/))")  # Warp's start-up lines


def parse_captured(output: str) -> dict[str, list[str]]:
    """pytest -rP's report: '____ test name ____' then '---- Captured stdout call ----' and the lines."""
    found, name, capturing = {}, None, False
    for line in output.splitlines():
        header = re.match(r"^_{3,} (.+?) _{3,}$", line)
        if header:
            name, capturing = header.group(1), False
        elif re.match(r"^-{3,} Captured stdout call -{3,}$", line):
            capturing = name is not None
        elif re.match(r"^(-{3,}|={3,}) ", line):
            capturing = False
        elif capturing and line.strip() and not WARP_NOISE.match(line):
            found.setdefault(name, []).append(line.rstrip())
    return found


def collect_measured(tests, args) -> int:
    """Run the measuring tests on the unmutated tree and write what they print, one place for the README."""
    cmd = [sys.executable, "-m", "pytest", "-q", "-rP", "-p", "no:cacheprovider", *tests]
    proc = subprocess.run(cmd, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True)
    found = parse_captured(proc.stdout)
    lines = ["Printed by the tests themselves (`python -m benchmarks.test_power.mutation_score --measured`); each "
             "test's bound and its reason are beside it in the test file.", ""]
    for name, printed in found.items():
        lines += [f"- `{name}`"] + [f"  - {p}" for p in printed]
    args.label = "_".join(filter(None, ["measured", args.label]))
    harness.write_result("mutation_score", args, {"tests": found}, "\n".join(lines), title="What the tests measure")
    tail = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else proc.stderr[-300:]
    print(f"{len(found)} tests printed measurements ({tail})")
    return proc.returncode


def list_mutations(selected):
    bad = 0
    for mid, module, old, _new, tests in selected:
        hits, count = find_snippet(ROOT, old)
        where = ", ".join(str(h.relative_to(ROOT)) for h in hits) or "-"
        status = "ok" if count == 1 else f"ERROR: found {count} times"
        bad += count != 1
        print(f"{mid:32s} {status:20s} {where:42s} tests: {' '.join(tests)}")
    print(f"{len(selected)} mutations, {bad} harness errors")
    return bad


def main(argv=None):
    ap = harness.parser(__doc__.split("\n\n")[0], quick=f"one mutant ({QUICK}), its rows kept apart")
    ap.add_argument("--only", help="comma-separated mutation ids")
    ap.add_argument("--list", action="store_true", help="list the mutations and check their snippets; run nothing")
    ap.add_argument("--jobs", type=int, default=1, help="mutants run at once (each a pytest process)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per mutant before it counts as caught")
    ap.add_argument("--tests", help="comma-separated tests to run instead of each mutation's own (to show one "
                    "test's power); printed only, not recorded in the results")
    ap.add_argument("--measured", action="store_true",
                    help="run the measuring tests unmutated and write <device>_measured.{md,json}")
    args = ap.parse_args(argv)
    if args.measured:
        return collect_measured(MEASURED_TESTS, args)
    if args.quick:
        args.only = args.only or QUICK
    ids = [m[0] for m in MUTATIONS]
    if len(set(ids)) != len(ids):
        sys.exit("error: duplicate mutation ids in MUTATIONS")
    selected = list(MUTATIONS)
    if args.only:
        wanted = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = [w for w in wanted if w not in ids]
        if unknown:
            sys.exit(f"error: --only: unknown mutation ids {unknown}; see --list")
        selected = [m for m in MUTATIONS if m[0] in wanted]
    if args.list:
        return 1 if list_mutations(selected) else 0
    if args.jobs < 1:
        sys.exit("error: --jobs must be >= 1")
    if args.tests:
        override = [t.strip() for t in args.tests.split(",") if t.strip()]
        selected = [(mid, module, old, new, override) for mid, module, old, new, _ in selected]
    commit = harness.provenance(args.device)["commit"]
    previous = load_previous(args)
    print(f"{len(selected)} mutations, {args.jobs} at a time, commit {commit}", flush=True)

    def one(m):
        o = run_mutation(m, args.timeout, commit)
        print(f"{o.id:32s} {o.status:8s} {o.seconds:6.0f} s  {o.detail}", flush=True)
        return o

    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        outcomes = list(pool.map(one, selected))
    if args.tests:
        return 0  # a power check of chosen tests: not the suite's score
    modules = {m[0]: m[1] for m in MUTATIONS}
    for o in outcomes:
        previous[o.id] = {"id": o.id, "module": modules[o.id], "status": o.status, "seconds": round(o.seconds, 1),
                          "detail": o.detail, "file": o.file, "commit": o.commit}
    rows = [previous[i] for i in ids if i in previous]  # in the list's order; dropped ids disappear
    write_results(rows, args)
    caught, counted, frac = score(rows)
    errors = [r["id"] for r in rows if r["status"] == "error"]
    escaped = [r["id"] for r in rows if r["status"] == "escaped"]
    print(f"\nscore: {caught}/{counted} = {100 * frac:.1f}% (all recorded rows); escaped: {escaped or 'none'}; "
          f"harness errors: {errors or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
