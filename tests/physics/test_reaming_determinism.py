"""The same case gives the same bits on any x86-64 machine, BLAS kernel and thread count.

A reaming trajectory is chaotic: a 1e-12 relative change of the push force changed the frame-4
reamer position by ±0.25 mm in solver 0.2.0. Three things pick code by the CPU they run on and
differ in the last bit: OpenBLAS kernels, glibc's libm (FMA / AVX2 / AVX-512 variants of exp,
log, pow, sin, cos, atan2, also inside gmsh) and NumPy's SIMD loops. So nothing that feeds the
solver state uses BLAS or a library transcendental function (``thrsim.portable_math``), gmsh's
node coordinates are snapped to a 1 nm grid, and this test runs a short coarse case in fresh
interpreters that emulate other CPUs: OpenBLAS kernels (``OPENBLAS_CORETYPE``), glibc without
AVX/FMA (``GLIBC_TUNABLES``), NumPy without AVX (``NPY_DISABLE_CPU_FEATURES``), Numba compiling
for a generic x86-64, one and two Numba threads; a digest of every recorded frame must be the
same in all and equal the one pinned here.

``PINNED_DIGEST`` changes whenever the solver's results change on purpose: update it in the same
commit, with the reason in the message. A change that was not meant to alter results and still
changes the digest is a regression.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

PINNED_DIGEST = "9620f6df634415921344e6c553ac81c8a97f07fe911556c2a9204bfdbf097828"
ROOT = Path(__file__).resolve().parents[2]

_CASE = """
import hashlib, numpy as np
from thrsim.config import BonePatchConfig, ReamingCaseConfig
from thrsim.physics.reaming_case import ReamingCase
case = ReamingCaseConfig(inclination_deg=15.0, anteversion_deg=30.0, force_n=460.0, frames=4,
                         bone=BonePatchConfig(element_size_mm=1.2))
simulation = ReamingCase(case)
log, summary = simulation.run(case.frames)
records = log.arrays()
digest = hashlib.sha256()
for name in ("status", "peeq", "von_mises", "reamer_position", "reamer_axial", "energy"):
    digest.update(np.ascontiguousarray(records[name]).tobytes())
print(summary["removed"], digest.hexdigest())
"""


#: a CPU without AVX, FMA or AVX-512, as far as glibc, NumPy, Numba and OpenBLAS can be told
_OLD_CPU = {
    "OPENBLAS_CORETYPE": "Prescott",
    "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX512F,-AVX2,-FMA,-AVX",
    "NPY_DISABLE_CPU_FEATURES": "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR AVX2 FMA3 F16C AVX",
    "NUMBA_CPU_NAME": "generic",
}
_MACHINES = {
    "Haswell BLAS, 1 thread": {"OPENBLAS_CORETYPE": "Haswell", "NUMBA_NUM_THREADS": "1"},
    "SkylakeX BLAS, 2 threads": {"OPENBLAS_CORETYPE": "SkylakeX", "NUMBA_NUM_THREADS": "2"},
    "no AVX/FMA anywhere, 1 thread": {**_OLD_CPU, "NUMBA_NUM_THREADS": "1"},
}


def _digest(machine: dict[str, str]) -> tuple[int, str]:
    env = {**os.environ, **machine, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", _CASE], capture_output=True, text=True, env=env, cwd=ROOT, timeout=1200)
    assert result.returncode == 0, result.stderr
    removed, digest = result.stdout.split()
    return int(removed), digest


@pytest.mark.timeout(2400)
def test_results_are_identical_across_emulated_cpus_and_thread_counts():
    runs = {name: _digest(machine) for name, machine in _MACHINES.items()}
    removed = {r for r, _ in runs.values()}
    digests = {d for _, d in runs.values()}
    assert len(digests) == 1, f"results differ between emulated CPUs or thread counts: {runs}"
    assert removed.pop() > 0, "the pinned case must cut bone, or the digest pins nothing of interest"
    assert digests.pop() == PINNED_DIGEST, "the solver's results changed: if on purpose, pin the new digest (see the module docstring)"
