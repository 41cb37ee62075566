"""What a run writes: the USD layer of its recorded frames, its JSON report, and the plan of its files.

Every file a run writes into its output directory is named here (:func:`preview_name`,
:func:`comparison_name`, :func:`pixel_image_names`, :func:`pixel_comparison_name`,
:func:`movie_name`, :func:`comparison_movie_name`, :func:`report_name`; the USD layer by
:func:`warpshade.io._usd_write.usd_output_name`) and planned before any work (:func:`plan_outputs`):
an :class:`OutputPlan` lists every path and, before any work (:meth:`OutputPlan.check`), reads the
directory's manifest (:data:`MANIFEST_NAME`; one that cannot be read is named then, not after the
USD layer is written) and refuses a path that holds a file warpshade did not write there itself,
a file the run reads (:func:`run_inputs`: the scene and what it pulls in, a training clip, a table,
a texture, whatever the manifest says), a symbolic link (its write would land outside the
directory), or a file named like the temporary file of an interrupted write that is not
warpshade's (the clean-up after interrupted writes would delete it). Each file is recorded in the
manifest once written, under a lock of the directory (:data:`LOCK_NAME` where ``flock`` is
missing), so that runs writing into one directory at once keep each other's entries, and a run
never overwrites an input that happens to share an output's name (a scene ``figure.usda`` beside
the outputs of a graph named ``figure``).
"""

from __future__ import annotations

import errno
import json
import os
import re
import time
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._fileio import _pid_alive, temporary_pattern, write_json_atomic
from ..io._scene_specs import (SCENE_SPEC_PREFIXES, USD_SUFFIXES, bundled_asset_directory, resolve_scene_path,
                              usd_file_dependencies)

__all__ = ["LOCK_NAME", "MANIFEST_NAME", "OutputPlan", "check_output_directory", "plan_outputs", "run_inputs"]

#: The manifest of an output directory, JSON: what warpshade wrote there (``"written"``: name ->
#: size, mtime) and the processes that wrote there (``"writers"``: the temporary files of their
#: interrupted writes are warpshade's to remove).
MANIFEST_NAME = ".warpshade-outputs.json"
#: The lock of the manifest where the output directory itself cannot be locked (no ``fcntl``, or
#: a file system without ``flock`` on directories): a directory, created and removed around each
#: update of the manifest.
LOCK_NAME = ".warpshade-outputs.lock"
#: How long an update of the manifest waits for that lock (seconds) before naming it.
LOCK_TIMEOUT_S = 60.0


def write_usd(runtime, path, extra_primvars: dict | None = None) -> Path:
    """Write the run's recorded frames as a new USD layer (never over the input).

    The layer sublayers the input scene (when it came from a file) and adds per-vertex
    ``primvars:displayColor`` (vertex interpolation, time-sampled per recorded frame) to each
    shaded mesh; meshes not in the input file (e.g. a generated ground plane) are written in
    full (:func:`warpshade.io._usd_write.write_vertex_colors`).

    Raises:
        ValueError: when the run recorded no frames.
    """
    from ..io._usd_write import write_vertex_colors

    if not runtime.results:
        raise ValueError("write_usd: the run recorded no frames (step with record=True, or run())")
    frames = sorted(runtime.results)
    colors = np.stack([runtime.results[f] for f in frames])
    return write_vertex_colors(path, runtime.scene, np.array(frames), colors, extra_primvars=extra_primvars)


def report(runtime, error: dict | None = None) -> dict:
    """The run's description (:meth:`~warpshade.graph.Runtime.describe`) with its error."""
    out = runtime.describe()
    out["error"] = error
    return out


def write_report(runtime, path, error: dict | None = None) -> Path:
    """Write :func:`report` as JSON, atomically."""
    return write_json_atomic(path, report(runtime, error))


# ---- names of a run's files --------------------------------------------------------------------
def _frame_tag(frame) -> str:
    """A time code in a file name: ``0012`` for 12, ``0012p5`` for 12.5 (fractional time codes of
    a stage sampled at its own time samples keep their own names, to a thousandth)."""
    f = float(frame)
    if f == round(f):
        return f"{int(round(f)):04d}"
    whole, frac = f"{abs(f):.3f}".split(".")
    return f"{'-' if f < 0 else ''}{int(whole):04d}p{frac.rstrip('0')}"


def preview_frames(frames) -> list:
    """The frames a run's previews show: the first, middle and last of ``frames`` (time codes)."""
    rec = sorted(float(f) for f in frames)
    return sorted({rec[0], rec[len(rec) // 2], rec[-1]}) if rec else []


def preview_name(graph: str, frame) -> str:
    """``<graph>_<frame>.png``: the preview of one frame (:func:`~warpshade.measure._pictures.render_previews`)."""
    return f"{graph}_{_frame_tag(frame)}.png"


def comparison_name(graph: str, frame) -> str:
    """``<graph>_<frame>_vs_reference.png``: method | reference | error of one frame."""
    return f"{graph}_{_frame_tag(frame)}_vs_reference.png"


def pixel_image_names(graph: str, frame) -> tuple[str, str]:
    """``<graph>_px_<frame>.png`` and ``.exr``: the per-pixel image of one frame, tone-mapped and linear."""
    stem = f"{graph}_px_{_frame_tag(frame)}"
    return f"{stem}.png", f"{stem}.exr"


def pixel_comparison_name(graph: str, frame) -> str:
    """``<graph>_px_<frame>_vs_reference.png``: per-pixel method | reference | error strip of one frame."""
    return f"{graph}_px_{_frame_tag(frame)}_vs_reference.png"


def movie_name(graph: str, movie_format: str) -> str:
    """``<graph>.mp4`` or ``.gif``: the movie of every recorded frame (:func:`~warpshade.measure._pictures.render_movie`)."""
    return f"{graph}.{_movie_suffix(movie_format)}"


def comparison_movie_name(graph: str, movie_format: str) -> str:
    """``<graph>_vs_reference.mp4`` or ``.gif``: the method | reference | error strips of the measured frames."""
    return f"{graph}_vs_reference.{_movie_suffix(movie_format)}"


def _movie_suffix(movie_format: str) -> str:
    if movie_format not in ("mp4", "gif"):
        raise ValueError(f"movie format must be 'mp4' or 'gif', got {movie_format!r}")
    return movie_format


def report_name(graph: str) -> str:
    """``<graph>.json``: the run's report."""
    return f"{graph}.json"


# ---- the plan and the manifest -------------------------------------------------------------------
def _stat_entry(path: Path) -> dict | None:
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return {"size": int(st.st_size), "mtime_ns": int(st.st_mtime_ns)}


def _read_manifest(directory: Path, planning: bool = False) -> dict:
    """The manifest of ``directory``: ``{"written": {name: {"size", "mtime_ns"}}, "writers": [pid, ...]}``,
    both empty when there is none (``planning``: read before any work, and said so in an error).

    Raises:
        ValueError: naming the manifest when it is a link or a directory, cannot be read, is not
            JSON or is not a manifest.
    """
    path = directory / MANIFEST_NAME
    if not os.path.lexists(path):
        return {"written": {}, "writers": []}
    where = f"output directory {directory}: its manifest {MANIFEST_NAME}"
    advice = (("nothing was written; " if planning else "") + "move it away (warpshade then takes none of the "
              "files there for its own) or choose another output directory (--out)")
    if os.path.islink(path):
        raise ValueError(f"{where} is a symbolic link (to {os.readlink(path)}); {advice}")
    try:
        doc = json.loads(path.read_bytes())
    except OSError as exc:
        raise ValueError(f"{where} cannot be read ({exc.strerror or exc}); {advice}") from None
    except ValueError as exc:
        raise ValueError(f"{where} is not valid JSON ({exc}); {advice}") from None
    written = doc.get("written") if isinstance(doc, dict) else None
    writers = doc.get("writers", []) if isinstance(doc, dict) else None
    if not (isinstance(written, dict) and all(isinstance(e, dict) for e in written.values())
            and isinstance(writers, list) and all(type(pid) is int for pid in writers)):
        raise ValueError(f"{where} is not a manifest of warpshade (a JSON object of \"written\" files and "
                         f"\"writers\" process ids); {advice}")
    return {"written": written, "writers": writers}


def _flock_directory(directory: Path) -> int | None:
    """A descriptor of ``directory`` that holds an exclusive ``flock`` on it (closing it lets go),
    or None where there is no such lock (no ``fcntl``, or a file system that refuses it)."""
    try:
        import fcntl
    except ImportError:
        return None
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
    except OSError:
        os.close(fd)
        return None
    return fd


@contextmanager
def _manifest_lock(directory: Path):
    """Hold the lock of ``directory``'s manifest while it is read, changed and written, so that
    two runs writing into one directory at once keep each other's entries: a ``flock`` on the
    directory, or else the directory :data:`LOCK_NAME` inside it, created and removed around the
    update (waited for up to :data:`LOCK_TIMEOUT_S`)."""
    fd = _flock_directory(directory)
    if fd is not None:
        try:
            yield
        finally:
            os.close(fd)
        return
    lock = directory / LOCK_NAME
    deadline = time.monotonic() + LOCK_TIMEOUT_S
    while True:
        try:
            os.mkdir(lock)
            break
        except FileExistsError:
            if time.monotonic() > deadline:
                raise TimeoutError(errno.ETIMEDOUT, f"output directory {directory}: {LOCK_NAME} has been held for "
                                   f"{LOCK_TIMEOUT_S:g} s; remove it if no warpshade run is writing there") from None
            time.sleep(0.05)
    try:
        yield
    finally:
        try:
            os.rmdir(lock)
        except OSError:
            pass


def _temporary_pattern(path: Path) -> re.Pattern:
    """The names of the temporary files of a write of ``path``: those that the clean-up after
    interrupted writes (:func:`warpshade._fileio.remove_stale_temporaries`) removes when the
    process id in the name is no longer running): :func:`warpshade._fileio.temporary_pattern`."""
    return temporary_pattern(path)


def _writers_to_keep(writers, names) -> list[int]:
    """The writer processes a manifest keeps listing: this one, those still running and those
    whose temporary files are still in the directory (``names``)."""
    keep = {os.getpid()}
    for pid in writers:
        if _pid_alive(pid) or any(re.match(rf"^\..+-{pid}-.", name) for name in names):
            keep.add(pid)
    return sorted(keep)


@dataclass
class OutputPlan:
    """Every file a run will write into ``directory``, known before any work.

    Attributes:
        directory: the output directory.
        usd, report: the USD layer and the JSON report (None when the run writes none).
        extra: other files the command writes (:func:`warpshade.measure._auto.shade_scene`'s).
        previews, comparisons, pixel_comparisons: time code -> PNG path.
        pixel_images: time code -> (PNG path, EXR path).
        movie, comparison_movie: the movie of the recorded frames and that of the measured frames'
            comparison strips (None when not asked for).
        protected: the files the run reads (its scene, the layers and assets the scene pulls in,
            a stage's training clip, table or texture: :func:`run_inputs`), path -> what reads it:
            never written, whatever the manifest says.
    """

    directory: Path
    usd: Path | None
    report: Path | None
    previews: dict = field(default_factory=dict)
    comparisons: dict = field(default_factory=dict)
    pixel_images: dict = field(default_factory=dict)
    pixel_comparisons: dict = field(default_factory=dict)
    movie: Path | None = None
    comparison_movie: Path | None = None
    protected: dict = field(default_factory=dict)
    #: Other files of the command (``warpshade shade``'s graph, choice report and chart).
    extra: tuple = ()

    @property
    def manifest(self) -> Path:
        """The directory's manifest (:data:`MANIFEST_NAME`)."""
        return self.directory / MANIFEST_NAME

    def paths(self) -> list[Path]:
        """Every planned path."""
        out = [*((self.usd,) if self.usd is not None else ()), *self.extra, *self.previews.values(), *self.comparisons.values()]
        for png, exr in self.pixel_images.values():
            out += [png, exr]
        last = [p for p in (self.movie, self.comparison_movie, self.report) if p is not None]
        return [*out, *self.pixel_comparisons.values(), *last]

    def written(self) -> dict:
        """The manifest's entries (name -> ``{"size", "mtime_ns"}``); empty when there is no manifest.

        Raises:
            ValueError: naming the manifest when it cannot be read or is not one.
        """
        return _read_manifest(self.directory)["written"] if os.path.isdir(self.directory) else {}

    def check(self) -> None:
        """Refuse the plan when a path holds something this run must not replace: a file warpshade
        did not write there (not in the manifest, or changed since), a file the run reads
        (:attr:`protected`), a symbolic link (its write would land outside the directory), a
        directory, or a file named like the temporary file of an interrupted write that the
        manifest does not list as warpshade's (the clean-up after interrupted writes would delete
        it). The manifest is read and checked first. Call it before any work.

        Where the directory has a manifest, this process is entered in it as one of the
        directory's writers, so that the temporary files of a write it is killed in are known
        later to be warpshade's.

        Raises:
            FileExistsError: naming the files and the directory.
            ValueError: naming the manifest when it cannot be read or is not one.
            NotADirectoryError: the output directory is a file.
        """
        d = self.directory
        if not os.path.isdir(d):
            if os.path.lexists(d):
                raise NotADirectoryError(errno.ENOTDIR, f"output directory {d} is an existing file, not a directory "
                                         "(--out)")
            return  # nothing there yet: the caller creates it
        with _manifest_lock(d):
            manifest = _read_manifest(d, planning=True)
            names = os.listdir(d)
            problems = self._problems(manifest, names)
            if problems:
                shown = ", ".join(problems[:4]) + (f" and {len(problems) - 4} more" if len(problems) > 4 else "")
                it = "it" if len(problems) == 1 else "them"
                raise FileExistsError(
                    errno.EEXIST,
                    f"output directory {d} already holds {shown}, which this run would write or remove; nothing was "
                    f"written: warpshade replaces only the files it wrote there itself (its {MANIFEST_NAME}), and never "
                    f"a file the run reads; move {it} away or choose another output directory (--out)")
            if os.path.lexists(self.manifest):
                write_json_atomic(self.manifest, {"written": manifest["written"],
                                                  "writers": _writers_to_keep(manifest["writers"], names)})

    def _problems(self, manifest: dict, names: list) -> list[str]:
        """What :meth:`check` refuses, each as ``name`` or ``name (why)``."""
        written, writers = manifest["written"], set(manifest["writers"])
        protected = []
        for p, what in self.protected.items():
            try:
                st = os.stat(p)
                protected.append((Path(p).resolve(), (st.st_dev, st.st_ino), what))
            except (OSError, ValueError):
                protected.append((Path(p).resolve(), None, what))
        problems = []
        for path in self.paths():
            if not os.path.lexists(path):
                continue
            try:
                st = os.stat(path)
                key = (st.st_dev, st.st_ino)
            except OSError:
                key = None
            real = path.resolve()
            read_by = next((what for p, k, what in protected if p == real or (key is not None and k == key)), None)
            if read_by is not None:
                problems.append(f"{path.name} ({read_by})")
            elif os.path.islink(path):
                problems.append(f"{path.name} (a symbolic link to {os.readlink(path)}; the run writes only into its "
                                "output directory)")
            elif path.is_dir():
                problems.append(f"{path.name} (a directory)")
            elif written.get(path.name) != _stat_entry(path):
                problems.append(path.name)
        patterns = [_temporary_pattern(p) for p in (*self.paths(), self.manifest)]
        for name in sorted(names):
            for pattern in patterns:
                m = pattern.match(name)
                if m is None:
                    continue
                pid = int(m.group(1))
                if pid != os.getpid() and pid not in writers and not _pid_alive(pid):
                    problems.append(f"{name} (named like the temporary file of an interrupted write, which warpshade "
                                    "would delete; the manifest does not list it as warpshade's)")
                break
        return problems

    def record(self, paths) -> None:
        """Add files this run has just written to the manifest; entries of files that are gone are
        dropped. The manifest is read, changed and written (atomically) under the directory's lock,
        so that runs writing into one directory at once keep each other's entries.

        Raises:
            ValueError: a path that is not in the plan (every file a run writes is planned), or a
                manifest that cannot be read or is not one.
        """
        planned = {p.name for p in self.paths()}
        paths = [Path(p) for p in paths]
        for p in paths:
            if p.name not in planned or p.parent.resolve() != self.directory.resolve():
                raise ValueError(f"output {p} was not planned for {self.directory}")
        with _manifest_lock(self.directory):
            manifest = _read_manifest(self.directory)
            names = os.listdir(self.directory)
            present = set(names)
            entries = {name: e for name, e in manifest["written"].items() if name in present}
            for p in paths:
                entry = _stat_entry(p)
                if entry is not None:
                    entries[p.name] = entry
            write_json_atomic(self.manifest, {"written": dict(sorted(entries.items())),
                                              "writers": _writers_to_keep(manifest["writers"], names)})


def check_output_directory(directory) -> Path:
    """Create a script's output directory if needed and check that files can be written there
    (before any work). Raises ``OSError`` whose message starts with the path: an existing file,
    or a directory that cannot be created or written."""
    from .._fileio import check_writable_dir

    return check_writable_dir(directory, what="")


def plan_outputs(directory, graph: str, usd_name: str, frames, measured=(), *, previews: bool = True,
                 validate: bool = False, pixels: bool = False, movie: str | None = None, report: bool = True,
                 protected=()) -> OutputPlan:
    """The files of a run (see :class:`OutputPlan`), from what is known before any work.

    Args:
        directory: the output directory; graph: the graph's name (it names every file).
        usd_name: the USD layer's file name (:func:`warpshade.io._usd_write.usd_output_name`).
        frames: the time codes the run records; measured: those measured against ground truth.
        previews: previews are written (of :func:`preview_frames`), and with ``validate`` the
            comparison pictures of the measured frames.
        validate: the run is measured; pixels: a stage of the run shades pixels (per-pixel images
            with ``previews``, per-pixel comparisons with ``validate``).
        movie: ``"mp4"`` or ``"gif"`` for a movie of every recorded frame, and with ``validate``
            one of the measured frames' comparison strips (None: no movies).
        report: the run writes its JSON report (:func:`report_name`).
        protected: the files the run reads, a mapping path -> what reads it (:func:`run_inputs`)
            or paths.
    """
    d = Path(directory)
    shown = preview_frames(frames)
    measured = sorted(float(f) for f in measured) if validate else []
    if not isinstance(protected, Mapping):
        protected = {p: "a file the run reads" for p in protected}
    return OutputPlan(
        directory=d,
        usd=d / usd_name,
        report=d / report_name(graph) if report else None,
        previews={f: d / preview_name(graph, f) for f in shown} if previews else {},
        comparisons={f: d / comparison_name(graph, f) for f in measured} if previews else {},
        pixel_images={f: tuple(d / n for n in pixel_image_names(graph, f)) for f in shown} if previews and pixels else {},
        pixel_comparisons={f: d / pixel_comparison_name(graph, f) for f in measured} if pixels else {},
        movie=d / movie_name(graph, movie) if movie is not None else None,
        comparison_movie=d / comparison_movie_name(graph, movie) if movie is not None and measured else None,
        protected=dict(protected),
    )


# ---- what a run reads -------------------------------------------------------------------------------
def run_inputs(spec, scene=None) -> dict:
    """The files a run of the graph ``spec`` reads, each with what reads it: the scene and the
    layers and assets it pulls in (sublayers, references, textures, sky images), the graph file,
    the ``[lighting]`` image, the ``[[material]]`` tables and every stage parameter that names a
    file (a training clip and what it pulls in, a BRDF table, a texture), resolved as the stage
    resolves it (against the graph file's directory; ``bundled:`` and ``warp-example:`` names).
    :meth:`OutputPlan.check` never lets a run write over one of them, whatever the manifest says.

    Args:
        spec: the graph (:class:`~warpshade.graph.GraphSpec`); scene: its loaded scene (for its
            ``source``), or None.

    Returns:
        Absolute path -> what reads it, e.g. ``"read by stage 'data' (parameter 'training')"``.
    """
    base = Path(spec.source_path).parent if getattr(spec, "source_path", None) else Path.cwd()
    found: dict = {}

    def add(path, what: str, pulled_in: str) -> None:
        try:
            p = Path(path).expanduser()
            if not p.is_file():
                return
            p = p.resolve()
        except (OSError, ValueError):  # a name too long, a NUL byte: no file of that name
            return
        found.setdefault(p, what)
        if p.suffix in USD_SUFFIXES:
            for dep in usd_file_dependencies(p):
                found.setdefault(Path(dep).resolve(), pulled_in)

    source = getattr(scene, "source", None)
    if source:
        add(source, "the run's own scene", "read by the run's scene")
    if getattr(spec, "source_path", None):
        add(spec.source_path, "the run's graph file", "read by the run's graph file")
    light = (spec.lighting or {}).get("source")
    if isinstance(light, str) and light:
        for path in _named_files(light, base):
            add(path, "read by [lighting] source", "read by [lighting] source")
    for i, entry in enumerate(spec.materials or ()):
        table = getattr(entry.get("brdf"), "source", None)
        if isinstance(table, str) and table:
            add(table, f"read by [[material]] #{i + 1}", f"read by [[material]] #{i + 1}")
    for st in spec.stages:
        for key, value in (st.params or {}).items():
            if isinstance(value, str) and value:
                what = f"read by stage {st.name!r} (parameter {key!r})"
                for path in _named_files(value, base):
                    add(path, what, what)
    return found


def _named_files(value: str, base: Path) -> list:
    """The files a string parameter may name: a scene spec resolved as the loader does and, for
    ``bundled:NAME``, NAME in the bundled assets as a stage resolves it; a path relative to
    ``base``."""
    if value.startswith(SCENE_SPEC_PREFIXES):
        out = []
        try:
            out.append(resolve_scene_path(value))
        except (OSError, ValueError):
            pass
        if value.startswith("bundled:"):
            out.append(os.path.join(bundled_asset_directory(), value[len("bundled:"):]))
        return out
    try:
        p = Path(value).expanduser()
    except RuntimeError:  # "~user" of no such user
        return []
    return [p if p.is_absolute() else base / p]
