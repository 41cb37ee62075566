"""Smoke runs of the benchmark scripts: each one's quick profile exits 0 and writes its JSON.

Every script runs in a subprocess exactly as documented (``python benchmarks/<script>.py
--quick --out DIR``), with ``PYTHONPATH`` set to this checkout so the subprocess imports the tree
under test, and writes into a temporary directory (never benchmarks/results). The numbers are not
checked here: the point is that the scripts keep up with the library's names and signatures.
"""

from __future__ import annotations

import ast
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
#: What a script's module-level ``PROFILE`` dict may say about its smoke run: ``"slow": True`` --
#: over ~40 s on 2 shared CPU cores (the script says why), kept out of the default suite (``-m "not
#: slow"``); ``"requires": [module, ...]`` -- optional packages without which it is skipped. A script
#: without ``PROFILE`` is quick and needs only the core install.
PROFILE_KEYS = {"slow": bool, "requires": list}


def profile(script: str) -> dict:
    """The ``PROFILE`` a benchmark script declares (read from its source, not imported), or ``{}``."""
    tree = ast.parse((BENCHMARKS / f"{script}.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "PROFILE" for t in node.targets):
            return ast.literal_eval(node.value)
    return {}


#: Seconds one smoke run may take before it counts as hung (a hang guard: :mod:`hang`).
TIMEOUT_S = HANG_S


def test_every_benchmark_script_has_a_quick_profile():
    """Each script has ``--quick``, and refuses it without ``--out`` (a smoke run never writes
    into benchmarks/results)."""
    for name in SMOKE:
        text = (BENCHMARKS / f"{name}.py").read_text()
        assert '"--quick"' in text, f"{name}: add a --quick smoke profile"
        assert "--quick writes only into --out DIR" in text, f"{name}: refuse --quick without --out"
        declared = profile(name)
        assert isinstance(declared, dict) and all(isinstance(declared[k], t) for k, t in PROFILE_KEYS.items()
                                                  if k in declared), f"{name}: PROFILE must be a dict of {PROFILE_KEYS}"
        assert set(declared) <= set(PROFILE_KEYS), f"{name}: PROFILE has unknown keys {sorted(set(declared) - set(PROFILE_KEYS))}"


def test_no_script_or_test_edits_sys_path():
    """Benchmarks import the installed package, tests their helpers through pytest's pythonpath."""
    for path in [*BENCHMARKS.glob("*.py"), *(ROOT / "tests").glob("*.py")]:
        if path != Path(__file__).resolve():
            assert "sys.path." not in path.read_text(), f"{path.name}: import the installed package instead"


@pytest.mark.parametrize("script", [pytest.param(n, marks=(pytest.mark.slow,) if profile(n).get("slow") else ())
                                    for n in SMOKE])
def test_quick_profile_writes_its_json(script, tmp_path):
    missing = [m for m in profile(script).get("requires", []) if importlib.util.find_spec(m) is None]
    if missing:
        pytest.skip(f"{script} needs {missing}, not installed (pip install -e '.[validate]')")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    before = {p: p.stat().st_mtime_ns for p in RESULTS.rglob("*")}
    proc = subprocess.run([sys.executable, str(BENCHMARKS / f"{script}.py"), "--quick", "--out", str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert {p: p.stat().st_mtime_ns for p in RESULTS.rglob("*")} == before, f"{script} --quick wrote into benchmarks/results"
    assert proc.returncode == 0, f"{script} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    assert list(tmp_path.rglob("*.json")), f"{script} wrote no JSON into --out:\n{proc.stdout[-3000:]}"
