"""The README matches the code (issue 26, item 5; issue 37, item 6): its Python blocks run as they
are, and each command of its ```bash blocks is tested in one of five ways (:func:`how_tested`):

* **in full**: ``warpshade`` commands other than ``run`` (``demo``, ``list-stages``, ``info``), run
  in-process (``warpshade.cli.main``) exactly as written;
* **shortened**: ``warpshade run`` of a graph whose work takes seconds, run in-process with quick
  settings given only through documented flags (:func:`quick`): ``--frames`` narrowed to the first
  validated frame, ``--validate-samples`` lowered to :data:`QUICK_SAMPLES`;
* **started**: ``warpshade run`` of a graph whose precompute takes minutes (its ``[graph]
  long_precompute`` says why: :func:`long_precompute`), run up to the start of its work (graph, scene, frames, outputs and cache checked), then stopped;
* **parsed**: commands that need a Dask cluster at ``tcp://HOST:8786``: their flags are parsed by
  the CLI's own parser and the graph file checked;
* **checked**: commands that cannot run inside the suite: ``pip install`` (the extras must exist),
  the test suite itself, starting a Dask scheduler or worker, and the examples (run headless by
  ``tests/test_examples.py``; here their flags are parsed by the example's own parser).

Each Python block and each command runs in a fresh temporary folder that holds the checkout's
``stages/`` (the README's commands run from the checkout's root), with a private
``$WARPSHADE_CACHE``. The README's sentence about this test gives the count of each kind, and
:func:`test_the_readme_says_how_its_commands_are_tested` keeps it true.
"""

import os
import re
import runpy
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from hang import HANG_S

from warpshade import cli
from warpshade.graph import GraphSpec

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

#: Ground-truth rays of a quick --validate (noisy, but every step of measuring runs).
QUICK_SAMPLES = "16"


def long_precompute(graph: str) -> str:
    """Why the graph file ``graph`` (relative to the checkout) takes minutes to precompute on a CPU (SSDF
    bakes, a sky's prefiltered table, glossy ZH fits, training data over hundreds of poses): its
    ``[graph] long_precompute``, or "" when it takes seconds. Such a graph runs up to the start of its
    work only."""
    return str(tomllib.loads((ROOT / graph).read_text()).get("graph", {}).get("long_precompute", ""))


def fenced_blocks(language: str) -> list[str]:
    """The bodies of the README's fenced blocks of one language, in order."""
    return re.findall(rf"^```{language}\n(.*?)^```", README.read_text(), flags=re.M | re.S)


def commands() -> list[str]:
    """Every command of the ```bash blocks: comments dropped, ``&&`` chains split."""
    out = []
    for block in fenced_blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            while words:
                cut = words.index("&&") if "&&" in words else len(words)
                out.append(shlex.join(words[:cut]))
                words = words[cut + 1:]
    return out


class _WorkStarted(BaseException):
    """Raised where a shape-only run would start its work (not an Exception: the CLI lets it through)."""


def plan(command: str) -> tuple[str, list[str], str]:
    """How a README command is tested: ``("run", argv, "")`` runs ``warpshade argv`` (quick
    settings added), ``("shape", argv, reason)`` runs it up to the start of its work,
    ``("parse", argv, reason)`` parses its flags, ``("check", words, reason)`` checks it otherwise."""
    words = shlex.split(command)
    env = [w for w in words if re.match(r"^[A-Z_]+=", w)]
    words = words[len(env):]
    if words[:2] == ["pip", "install"]:
        return "check", words, "installs packages"
    if words[:3] == ["python", "-m", "pytest"]:
        return "check", words, "the test suite this test is part of"
    if words[:1] == ["dask"]:
        return "check", words, "starts a Dask cluster"
    if words[:1] == ["python"] and words[1].startswith("examples/"):
        return "check", words, "the example runs headless in tests/test_examples.py"
    assert words[0] == "warpshade", f"README command {command!r}: no test knows how to check it"
    argv = words[1:]
    if "HOST" in command:
        return "parse", argv, "needs a Dask cluster at tcp://HOST:8786"
    if argv[0] != "run":
        return "run", argv, ""
    why = long_precompute(argv[1])
    if why:
        return "shape", argv, why
    return "run", quick(argv), ""


def quick(argv: list[str]) -> list[str]:
    """``warpshade run`` flags made quick with documented flags: one frame (the first validated
    one, so --validate still measures) and few ground-truth rays."""
    spec = tomllib.loads((ROOT / argv[1]).read_text())
    frame = int(spec.get("validate", {}).get("frames", [0])[0])
    out = list(argv)
    if "--frames" in out:
        i = out.index("--frames")
        del out[i:i + 2]
    out += ["--frames", f"{frame}:{frame + 1}"]
    if "--validate" in out:
        out += ["--validate-samples", QUICK_SAMPLES]
    return out


#: How each kind of :func:`plan` is named in the README's sentence about this test.
KINDS = ("in full", "shortened", "started", "parsed", "checked")


def how_tested(command: str) -> str:
    """Which of :data:`KINDS` the README command is tested by (module docstring)."""
    how, argv, _ = plan(command)
    if how == "run":
        words = shlex.split(command)
        return "in full" if argv == words[words.index("warpshade") + 1:] else "shortened"
    return {"shape": "started", "parse": "parsed", "check": "checked"}[how]


def test_the_readme_says_how_its_commands_are_tested():
    """The README's sentence about this test gives the number of commands of each kind."""
    text = " ".join(README.read_text().split())
    counts = {kind: sum(how_tested(c) == kind for c in commands()) for kind in KINDS}
    sentence = re.search(r"`tests/test_readme\.py` runs (.*?)\.(?: |$)", text)
    assert sentence, "the README has no sentence on what tests/test_readme.py runs"
    said = sentence.group(1)
    for kind, n in counts.items():
        assert re.search(rf"\b{n} {kind}\b", said), (f"README: the sentence on tests/test_readme.py should say "
                                                     f"'{n} {kind}' (counts now: {counts}):\n{said}")


@pytest.fixture
def readme_dir(tmp_path, monkeypatch):
    """A temporary working folder holding the checkout's stages/, with a private artifact cache."""
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "stages").symlink_to(ROOT / "stages")
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("WARPSHADE_SCHEDULER", raising=False)
    monkeypatch.chdir(tmp_path / "work")
    return tmp_path / "work"


def test_the_readme_has_blocks_and_commands():
    assert len(fenced_blocks("python")) >= 2 and len(commands()) >= 10


@pytest.mark.parametrize("index", range(len(fenced_blocks("python"))))
def test_python_block_runs_as_is(index, readme_dir):
    block = fenced_blocks("python")[index]
    script = readme_dir / f"readme_block_{index}.py"
    script.write_text(block)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, script.name], cwd=readme_dir, env=env, capture_output=True, text=True,
                          timeout=HANG_S)
    assert done.returncode == 0, f"README python block {index}:\n{block}\n{done.stderr[-3000:]}"


@pytest.mark.parametrize("command", commands(), ids=[c.replace(" ", "_") for c in commands()])
def test_command(command, readme_dir, monkeypatch, capsys):
    how, argv, reason = plan(command)
    if how == "check":
        if argv[:2] == ["pip", "install"]:
            extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
            target = argv[-1]
            assert argv[2:4] == ["-e", target] and re.fullmatch(r"\.(\[[a-z,]+\])?", target), command
            for extra in re.findall(r"[a-z]+", target):
                assert extra in extras, f"{command}: pyproject.toml has no extra {extra!r}"
        elif argv[0] == "dask":
            assert argv[1] in ("scheduler", "worker"), command
        elif argv[0] == "python" and argv[1].startswith("examples/"):
            example = runpy.run_path(str(ROOT / argv[1]))  # its flags parse with its own parser
            example["build_parser"]().parse_args(argv[2:])
        pytest.skip(f"checked for shape only: {reason}")
    if how == "parse":
        args = cli.build_parser().parse_args(argv)
        assert (ROOT / args.graph).exists(), command
        pytest.skip(f"flags parsed only: {reason}")
    if how == "shape":
        def reached(*args, **kwargs):
            raise _WorkStarted

        monkeypatch.setattr(GraphSpec, "compile", reached)
        with pytest.raises(_WorkStarted):
            cli.main(argv)
        pytest.skip(f"run up to the start of its work only: {reason}")
    rc = cli.main(argv)
    assert rc == 0, f"warpshade {shlex.join(argv)}:\n{capsys.readouterr().err}"
