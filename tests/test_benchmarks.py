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

from hang import HANG_S

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
RESULTS = BENCHMARKS / "results"

#: Every script's smoke profile: ``--quick`` (a tiny scene or few vertices, 1-3 frames, few rays,
#: the smallest orders and grids, no optional sweeps; about 15 s or less on one core). Names starting
#: with ``_`` are modules the scripts share (``_dish.py``), not scripts.
SMOKE = sorted(p.stem for p in BENCHMARKS.glob("*.py") if not p.name.startswith("_"))
#: Smoke runs still over ~40 s on 2 shared CPU cores (measured alone), kept out of the default
#: suite (``-m "not slow"``). Their cost is precompute their parameters cannot shrink further:
#: bench_datadriven (70 s: training trace, fit and coefficient PCA), bench_shexp
#: (59 s: SHEXP tables and sphere blockers per order), bench_rpo (42 s: operator builds and
#: reference shading), run.py (41 s: one row of every method, SG's environment included),
#: bench_visibility (~120 s on a loaded machine: two training traces -- visibility and the 2007
#: model's transfer --, three graphs, glossy and diffuse truths and the three frame-kind fits),
#: bench_sg (52 s: SSDF bakes and the sky's prefiltered table) and bench_heightfield (21 s, kept
#: out so that the default suite stays within ten minutes on this CPU).
SLOW = {"bench_datadriven", "bench_rpo", "bench_shexp", "bench_visibility", "bench_sg", "bench_heightfield", "run"}
#: bench_sg_svbrdf (minutes on a loaded machine: the dish's SSDF bake and the sky's prefiltered table,
#: as bench_sg, then the quadrature with ray-traced visibility at 40 pixels).
SLOW.add("bench_sg_svbrdf")
#: bench_visibility_frame (a visibility training trace and fit in a fresh cache, then the figure's
#: frame and its traced baseline).
SLOW.add("bench_visibility_frame")
#: bench_visibility_clusters (25 s on a loaded machine: a 30-frame training trace, the auto fit with
#: its cross-validation, references and one cluster's refitted candidates).
SLOW.add("bench_visibility_clusters")
#: bench_visibility_stack (the same training trace and references, the auto and stacked fits).
SLOW.add("bench_visibility_stack")
#: Seconds one smoke run may take before it counts as hung (a hang guard: :mod:`hang`).
TIMEOUT_S = HANG_S


def test_every_benchmark_script_has_a_quick_profile():
    """Each script has ``--quick``, and refuses it without ``--out`` (a smoke run never writes
    into benchmarks/results)."""
    for name in SMOKE:
        text = (BENCHMARKS / f"{name}.py").read_text()
        assert '"--quick"' in text, f"{name}: add a --quick smoke profile"
        assert "--quick writes only into --out DIR" in text, f"{name}: refuse --quick without --out"


def test_no_script_or_test_edits_sys_path():
    """Benchmarks import the installed package, tests their helpers through pytest's pythonpath."""
    for path in [*BENCHMARKS.glob("*.py"), *(ROOT / "tests").glob("*.py")]:
        if path != Path(__file__).resolve():
            assert "sys.path." not in path.read_text(), f"{path.name}: import the installed package instead"


@pytest.mark.parametrize("script", [pytest.param(n, marks=(pytest.mark.slow,) if n in SLOW else ()) for n in SMOKE])
def test_quick_profile_writes_its_json(script, tmp_path):
    if script.startswith("validate_mitsuba") and importlib.util.find_spec("mitsuba") is None:
        pytest.skip("Mitsuba 3 not installed (pip install -e '.[validate]')")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    before = {p: p.stat().st_mtime_ns for p in RESULTS.rglob("*")}
    proc = subprocess.run([sys.executable, str(BENCHMARKS / f"{script}.py"), "--quick", "--out", str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert {p: p.stat().st_mtime_ns for p in RESULTS.rglob("*")} == before, f"{script} --quick wrote into benchmarks/results"
    assert proc.returncode == 0, f"{script} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    assert list(tmp_path.rglob("*.json")), f"{script} wrote no JSON into --out:\n{proc.stdout[-3000:]}"
