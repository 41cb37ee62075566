"""Smoke runs of the benchmark scripts: each one's quick profile exits 0 and writes its JSON.

Every script runs in a subprocess exactly as documented (``python benchmarks/<script>.py
--quick --out DIR``), with ``PYTHONPATH`` set to this checkout so the subprocess imports the tree
under test, and writes into a temporary directory (never benchmarks/results). The numbers are not
checked here: the point is that the scripts keep up with the library's names and signatures.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"

#: script -> extra arguments of its smoke profile (``--quick`` unless the full run already takes
#: seconds), and its marks. Measured on 2 shared CPU cores with a warm kernel cache: bench_rays
#: 3 s, bench_sg_basis 9 s, bench_sh 10 s; bench_ssdf 16 s, bench_frame 32 s, bench_zh 51 s,
#: bench_sg_fit 62 s, bench_heightfield 146 s; the others' quick profiles are minutes (slow).
SLOW = (pytest.mark.slow,)
SMOKE = {
    "bench_rays": (["--quick"], ()),
    "bench_sg_basis": ([], ()),
    "bench_sh": (["--quick"], ()),
    "bench_ssdf": (["--quick"], SLOW),
    "bench_frame": (["--quick"], SLOW),
    "bench_zh": (["--quick"], SLOW),
    "bench_sg_fit": (["--quick"], SLOW),
    "bench_heightfield": (["--quick"], SLOW),
    "bench_spheres": (["--quick"], SLOW),
    "bench_ldprt": (["--quick"], SLOW),
    "bench_rpo": (["--quick"], SLOW),
    "bench_datadriven": (["--quick"], SLOW),
    "bench_shexp": (["--quick"], SLOW),
    "bench_sg": (["--quick"], SLOW),
    "run": (["--quick"], SLOW),
    "validate_mitsuba": (["--quick"], SLOW),
}
#: Seconds one smoke run may take before it counts as hung.
TIMEOUT_S = 600


def test_every_benchmark_script_has_a_smoke_run():
    scripts = {p.stem for p in BENCHMARKS.glob("*.py") if p.stem != "__init__"}
    assert scripts == set(SMOKE), f"add a smoke profile for {sorted(scripts - set(SMOKE))}"


def test_no_script_or_test_edits_sys_path():
    """Benchmarks import the installed package, tests their helpers through pytest's pythonpath."""
    for path in [*BENCHMARKS.glob("*.py"), *(ROOT / "tests").glob("*.py")]:
        if path != Path(__file__).resolve():
            assert "sys.path." not in path.read_text(), f"{path.name}: import the installed package instead"


@pytest.mark.parametrize("script", [pytest.param(name, marks=marks) for name, (_, marks) in SMOKE.items()])
def test_quick_profile_writes_its_json(script, tmp_path):
    if script == "validate_mitsuba" and importlib.util.find_spec("mitsuba") is None:
        pytest.skip("Mitsuba 3 not installed (pip install -e '.[validate]')")
    args, _ = SMOKE[script]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    proc = subprocess.run([sys.executable, str(BENCHMARKS / f"{script}.py"), *args, "--out", str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 0, f"{script} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    assert list(tmp_path.rglob("*.json")), f"{script} wrote no JSON into --out:\n{proc.stdout[-3000:]}"
