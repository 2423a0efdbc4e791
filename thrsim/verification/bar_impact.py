"""A small elastic-plastic bar impact, run by thrsim and by CalculiX (ccx) for a cross-check.

A square bar (default 2 × 2 × 12 mm, 0.5 mm hex cells split into 6 tets: 2,304 C3D4) moves
along −x at v0 = 25 m/s and is stopped by a rigid wall at x = 0 (the wall nodes held, as in
ABAQUS's encastre). Cortical-bone elasticity and the thesis's JC hardening; the elastic precursor
(Hugoniot elastic limit about 108 MPa at 15.9 m/s) is followed by a plastic front. The end time
(2.5 µs) stops before the precursor reflects from the free end; strains stay below about 1 %, so
thrsim's small-strain kinematics and ccx's (geometrically nonlinear) explicit solution should
agree to the order of the strain. How ccx is set up alike: :func:`write_ccx_input`.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thrsim.config import BoneMaterial, JohnsonCookHardening
from thrsim.geometry.box_mesh import box_mesh
from thrsim.geometry.mesh import TetMesh
from thrsim.physics.explicit import ExplicitSolid
from thrsim.verification.base import no_damage

BAR_END_TIME_S = 2.5e-6
#: ccx 2.20's explicit step is its 'volumetric Courant' increment, measured as ≈ 0.0853·h_min/c_d on
#: these meshes (about 11 times below thrsim's 0.9·h_min/c_d); used only to space the printed output
CCX_COURANT_FRACTION = 0.0853


@dataclass(frozen=True)
class BarImpact:
    length_m: float = 12e-3
    side_m: float = 2e-3
    cell_m: float = 0.5e-3
    velocity_m_s: float = 25.0
    end_time_s: float = BAR_END_TIME_S

    def mesh(self) -> TetMesh:
        n_side = int(round(self.side_m / self.cell_m))
        n_len = int(round(self.length_m / self.cell_m))
        return box_mesh((n_len, n_side, n_side), (self.length_m, self.side_m, self.side_m), scheme="six", fixed="xmin")

    def probe_nodes(self, mesh: TetMesh) -> dict[str, int]:
        """Nodes on the bar's axis at a quarter, half and the full length."""
        probes = {}
        centre = 0.5 * self.side_m
        for name, fraction in (("quarter", 0.25), ("half", 0.5), ("tip", 1.0)):
            target = np.array([fraction * self.length_m, centre, centre])
            probes[name] = int(np.argmin(np.linalg.norm(mesh.nodes - target, axis=1)))
        return probes


def run_thrsim_bar(
    problem: BarImpact,
    material: BoneMaterial,
    hardening: JohnsonCookHardening,
    dt_factor: float = 1.0,
    dt_s: float | None = None,
    bulk_viscosity: float = 0.0,
    record_history: bool = True,
) -> dict:
    """Run the bar in thrsim; the end-time displacement is u_N and the stress/PEEQ those of u_N
    (one extra element pass: the solver's stress lags its displacement by one step)."""
    started = time.perf_counter()
    mesh = problem.mesh()
    probe = ExplicitSolid(mesh, material, hardening, no_damage(), target_dt_s=None, bulk_viscosity=bulk_viscosity)
    if dt_s is None:  # the largest step ≤ dt_factor × stable that ends exactly at the end time
        dt_s = problem.end_time_s / math.ceil(problem.end_time_s / (probe.scaling.stable_dt_s * dt_factor))
    dt = dt_s
    solid = ExplicitSolid(mesh, material, hardening, no_damage(), target_dt_s=dt, bulk_viscosity=bulk_viscosity)
    setup = time.perf_counter() - started
    solid.velocity[:, 0] = -problem.velocity_m_s
    solid.velocity[solid.held] = 0.0
    steps = int(round(problem.end_time_s / solid.dt))
    probes = problem.probe_nodes(mesh)
    history = []
    solve_start = time.perf_counter()
    for _ in range(steps):
        solid.step()
        if record_history:
            history.append([solid.time] + [solid.displacement[n, 0] for n in probes.values()])
    displacement = solid.displacement.copy()
    solid.step()  # stresses of u_N
    solve = time.perf_counter() - solve_start
    return {
        "dt_s": solid.dt,
        "steps": steps,
        "time_s": steps * solid.dt,
        "displacement": displacement,
        "stress": solid.stress.copy(),
        "peeq": solid.peeq.copy(),
        "history": np.array(history) if record_history else None,
        "probes": probes,
        "plastic_dissipation_j": solid.plastic_dissipation(),
        "tip_displacement_m": float(displacement[probes["tip"], 0]),
        "half_displacement_m": float(displacement[probes["half"], 0]),
        "setup_seconds": setup,
        "solve_seconds": solve,
        "mesh": mesh,
        "held": solid.held.copy(),
    }


# ------------------------------------------------------------------------------ CalculiX


def ccx_available() -> str | None:
    return shutil.which("ccx")


def tabulated_flow_curve(hardening: JohnsonCookHardening, points: int = 80, peeq_max: float = 2.0) -> np.ndarray:
    """(σ, εᵖ) pairs of the JC curve at the reference rate: εᵖ = 0 then a log grid 1e-9 … εᵖ_max
    (the power law with n = 0.08 is steepest at small εᵖ)."""
    peeq = np.concatenate([[0.0], np.logspace(-9, math.log10(peeq_max), points - 1)])
    sigma = hardening.a_pa + hardening.b_pa * peeq**hardening.n
    return np.column_stack([sigma, peeq])


def write_ccx_input(
    path: Path, problem: BarImpact, mesh: TetMesh, material: BoneMaterial, hardening: JohnsonCookHardening, frequency: int
) -> None:
    """The CalculiX deck: nodes, C3D4 elements, sets, material, initial velocity, wall, explicit step.

    The same mesh, explicit dynamics (*DYNAMIC, EXPLICIT) and the JC curve at the reference rate
    tabulated on a logarithmic grid of εᵖ (ccx's *PLASTIC has no rate term and interpolates
    linearly). ccx 2.20 picks its increment from its Courant estimate, about 11 times below
    thrsim's stable step (its DIRECT option selected a zero increment in our tests); thrsim runs at
    that increment, with C = 0 and no bulk viscosity, so both do the same number of steps and the
    wall-time ratio compares like with like.

    Numbers are written with 12 significant digits: ccx rejects longer fields (20 characters).
    """
    lines = ["*HEADING", "thrsim verification: elastic-plastic bar impact (C3D4, explicit)", "*NODE, NSET=NALL"]
    lines += [f"{i + 1}, {x:.12g}, {y:.12g}, {z:.12g}" for i, (x, y, z) in enumerate(mesh.nodes)]
    lines.append("*ELEMENT, TYPE=C3D4, ELSET=EALL")
    lines += [f"{e + 1}, {a + 1}, {b + 1}, {c + 1}, {d + 1}" for e, (a, b, c, d) in enumerate(mesh.tets)]

    def nset(name: str, ids: np.ndarray) -> list[str]:
        labels = [str(int(i) + 1) for i in ids]
        return [f"*NSET, NSET={name}"] + [", ".join(labels[k : k + 12]) for k in range(0, len(labels), 12)]

    wall = mesh.node_sets["xmin"]
    moving = np.setdiff1d(np.arange(mesh.n_nodes), wall)
    lines += nset("WALL", wall) + nset("MOVING", moving) + nset("PROBES", np.array(list(problem.probe_nodes(mesh).values())))
    lines += ["*MATERIAL, NAME=BONE", "*ELASTIC", f"{material.youngs_modulus_pa:.12g}, {material.poisson_ratio:.12g}",
              "*DENSITY", f"{material.density_kg_m3:.12g}", "*PLASTIC"]  # fmt: skip
    lines += [f"{s:.12g}, {p:.12g}" for s, p in tabulated_flow_curve(hardening)]
    lines += ["*SOLID SECTION, ELSET=EALL, MATERIAL=BONE", "*INITIAL CONDITIONS, TYPE=VELOCITY"]
    lines += [f"{int(n) + 1}, 1, {-problem.velocity_m_s:.12g}" for n in moving]
    lines += [
        "*BOUNDARY",
        "WALL, 1, 3",
        "*STEP, INC=10000000",
        "*DYNAMIC, EXPLICIT",
        f"{problem.end_time_s / 100:.12g}, {problem.end_time_s:.12g}",
    ]
    # FREQUENCY is global to a step's print requests; the step's last increment is always printed
    lines += [
        f"*NODE PRINT, NSET=NALL, FREQUENCY={frequency}",
        "U",
        f"*EL PRINT, ELSET=EALL, FREQUENCY={frequency}",
        "S, PEEQ",
        "*END STEP",
        "",
    ]
    path.write_text("\n".join(lines))


_BLOCK = re.compile(r"^\s*(displacements|stresses|equivalent plastic strain)\b.*?\btime\s+([-+0-9.Ee]+)\s*$")


def parse_ccx_dat(path: Path) -> dict[float, dict[str, dict[int, list[float]]]]:
    """{time: {"U"|"S"|"PEEQ": {id (1-based): values}}} from a ccx .dat file."""
    out: dict[float, dict[str, dict[int, list[float]]]] = {}
    kind, current = None, None
    for line in path.read_text().splitlines():
        match = _BLOCK.match(line)
        if match:
            kind = {"displacements": "U", "stresses": "S", "equivalent plastic strain": "PEEQ"}[match.group(1)]
            current = out.setdefault(float(match.group(2)), {}).setdefault(kind, {})
            continue
        parts = line.split()
        if not parts or current is None:
            continue
        try:
            numbers = [float(p) for p in parts]
        except ValueError:
            current = None
            continue
        key = int(numbers[0])
        values = numbers[2:] if kind in ("S", "PEEQ") else numbers[1:]  # elements: id, integration point, ...
        current[key] = values
    return out


def run_ccx_bar(
    problem: BarImpact,
    material: BoneMaterial,
    hardening: JohnsonCookHardening,
    timeout_s: float = 120.0,
    workdir: Path | None = None,
    outputs: int = 10,
) -> dict:
    """Write the deck, run ccx in a temporary directory with a timeout, parse the .dat output."""
    executable = ccx_available()
    if executable is None:
        raise FileNotFoundError("ccx (CalculiX) is not installed")
    mesh = problem.mesh()
    with tempfile.TemporaryDirectory(prefix="thrsim-ccx-") as tmp:
        folder = Path(workdir) if workdir is not None else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        deck = folder / "bar.inp"
        from thrsim.geometry.tet_metrics import minimum_altitudes

        estimate = CCX_COURANT_FRACTION * float(minimum_altitudes(mesh.nodes, mesh.tets).min()) / material.dilatational_wave_speed_m_s
        frequency = max(1, int(problem.end_time_s / estimate / outputs))
        write_ccx_input(deck, problem, mesh, material, hardening, frequency)
        env = dict(os.environ, OMP_NUM_THREADS="1", CCX_NPROC_EQUATION_SOLVER="1", CCX_NPROC_RESULTS="1")
        started = time.perf_counter()
        completed = subprocess.run([executable, "-i", "bar"], cwd=folder, capture_output=True, text=True, timeout=timeout_s, env=env)
        seconds = time.perf_counter() - started
        log = completed.stdout + completed.stderr
        dat = folder / "bar.dat"
        if completed.returncode != 0 or not dat.exists() or "Job finished" not in log:
            raise RuntimeError(f"ccx failed (exit {completed.returncode}): {log[-800:]}")
        parsed = parse_ccx_dat(dat)
    times = np.array(sorted(parsed))
    n, e = mesh.n_nodes, mesh.n_tets
    selected = re.search(r"SELECTED time increment:\s*([-+0-9.Ee]+)", log)
    if selected is None:
        raise RuntimeError(f"could not read ccx's time increment from its log: {log[-400:]}")
    full = max(t for t in times if len(parsed[t].get("U", {})) == n)
    last = parsed[full]
    displacement = np.array([last["U"][i + 1] for i in range(n)])
    stress = np.array([last["S"][i + 1] for i in range(e)])  # xx, yy, zz, xy, xz, yz
    peeq = np.array([last["PEEQ"][i + 1][0] for i in range(e)])
    probes = problem.probe_nodes(mesh)
    history = np.array([[t] + [parsed[t]["U"][node + 1][0] for node in probes.values()] for t in times if "U" in parsed[t]])
    return {
        "time_s": float(full),
        "dt_s": float(selected.group(1)),
        "printed_times": int(len(times)),
        "displacement": displacement,
        "stress": stress[:, [0, 1, 2, 3, 5, 4]],  # to thrsim's Voigt order xx, yy, zz, xy, yz, zx
        "peeq": peeq,
        "history": history,
        "seconds": seconds,
        "log_tail": log[-400:],
    }
