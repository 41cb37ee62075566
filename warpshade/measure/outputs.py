"""What a run writes: the USD layer of its recorded frames, its JSON report, and the plan of its files.

Every file a run writes into its output directory is named here (:func:`preview_name`,
:func:`comparison_name`, :func:`pixel_image_names`, :func:`pixel_comparison_name`,
:func:`movie_name`, :func:`comparison_movie_name`, :func:`report_name`; the USD layer by :func:`warpshade.io.usd_write.usd_output_name`) and planned
before any work (:func:`plan_outputs`): an :class:`OutputPlan` lists every path, refuses a path
that holds a file warpshade did not write there itself, and records each file once written in the
directory's manifest (:data:`MANIFEST_NAME`), so a run never overwrites an input that happens to
share an output's name (a scene ``figure.usda`` beside the outputs of a graph named ``figure``).
"""

from __future__ import annotations

import errno
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._fileio import write_json_atomic

__all__: list[str] = []

#: The manifest of an output directory: what warpshade wrote there (name -> size, mtime), JSON.
MANIFEST_NAME = ".warpshade-outputs.json"


def write_usd(runtime, path, extra_primvars: dict | None = None) -> Path:
    """Write the run's recorded frames as a new USD layer (never over the input).

    The layer sublayers the input scene (when it came from a file) and adds per-vertex
    ``primvars:displayColor`` (vertex interpolation, time-sampled per recorded frame) to each
    shaded mesh; meshes not in the input file (e.g. a generated ground plane) are written in
    full (:func:`warpshade.io.usd_write.write_vertex_colors`).

    Raises:
        ValueError: when the run recorded no frames.
    """
    from ..io.usd_write import write_vertex_colors

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
    return f"{int(round(float(frame))):04d}"


def preview_frames(frames) -> list:
    """The frames a run's previews show: the first, middle and last of ``frames`` (time codes)."""
    rec = sorted(float(f) for f in frames)
    return sorted({rec[0], rec[len(rec) // 2], rec[-1]}) if rec else []


def preview_name(graph: str, frame) -> str:
    """``<graph>_<frame>.png``: the preview of one frame (:func:`~warpshade.measure.pictures.render_previews`)."""
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
    """``<graph>.mp4`` or ``.gif``: the movie of every recorded frame (:func:`~warpshade.measure.pictures.render_movie`)."""
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


@dataclass
class OutputPlan:
    """Every file a run will write into ``directory``, known before any work.

    Attributes:
        directory: the output directory.
        usd, report: the USD layer and the JSON report.
        previews, comparisons, pixel_comparisons: time code -> PNG path.
        pixel_images: time code -> (PNG path, EXR path).
        movie, comparison_movie: the movie of the recorded frames and that of the measured frames'
            comparison strips (None when not asked for).
        protected: files the run reads (its scene): never written, whatever the manifest says.
    """

    directory: Path
    usd: Path
    report: Path
    previews: dict = field(default_factory=dict)
    comparisons: dict = field(default_factory=dict)
    pixel_images: dict = field(default_factory=dict)
    pixel_comparisons: dict = field(default_factory=dict)
    movie: Path | None = None
    comparison_movie: Path | None = None
    protected: tuple = ()

    @property
    def manifest(self) -> Path:
        """The directory's manifest (:data:`MANIFEST_NAME`)."""
        return self.directory / MANIFEST_NAME

    def paths(self) -> list[Path]:
        """Every planned path."""
        out = [self.usd, *self.previews.values(), *self.comparisons.values()]
        for png, exr in self.pixel_images.values():
            out += [png, exr]
        movies = [p for p in (self.movie, self.comparison_movie) if p is not None]
        return [*out, *self.pixel_comparisons.values(), *movies, self.report]

    def written(self) -> dict:
        """The manifest's entries (name -> ``{"size", "mtime_ns"}``); empty when it is missing or unreadable."""
        try:
            entries = json.loads(self.manifest.read_text()).get("written", {})
        except (OSError, ValueError, AttributeError):
            return {}
        return entries if isinstance(entries, dict) else {}

    def check(self) -> None:
        """Refuse the plan when a path holds something this run must not replace: a file warpshade
        did not write there (not in the manifest, or changed since), a directory, or a file the run
        reads. Call it before any work.

        Raises:
            FileExistsError: naming the files and the directory.
        """
        written = self.written()
        protected = {Path(p).resolve() for p in self.protected}
        problems = []
        for path in self.paths():
            if path.resolve() in protected:
                problems.append(f"{path.name} (the run's own scene)")
            elif path.is_dir():
                problems.append(f"{path.name} (a directory)")
            elif os.path.lexists(path) and written.get(path.name) != _stat_entry(path):
                problems.append(path.name)
        if problems:
            shown = ", ".join(problems[:4]) + (f" and {len(problems) - 4} more" if len(problems) > 4 else "")
            it, is_ = ("it", "is") if len(problems) == 1 else ("them", "are")
            raise FileExistsError(
                errno.EEXIST,
                f"output directory {self.directory} already holds {shown}, which this run would write; nothing was "
                f"overwritten: {it} {is_} not among the files warpshade wrote there (its {MANIFEST_NAME}); move {it} "
                "away or choose another output directory (--out)")

    def record(self, paths) -> None:
        """Add files this run has just written to the manifest (atomically); entries of files that
        are gone are dropped.

        Raises:
            ValueError: a path that is not in the plan (every file a run writes is planned).
        """
        planned = {p.name for p in self.paths()}
        entries = {name: e for name, e in self.written().items() if os.path.lexists(self.directory / name)}
        for p in paths:
            p = Path(p)
            if p.name not in planned or p.parent.resolve() != self.directory.resolve():
                raise ValueError(f"output {p} was not planned for {self.directory}")
            entry = _stat_entry(p)
            if entry is not None:
                entries[p.name] = entry
        write_json_atomic(self.manifest, {"written": dict(sorted(entries.items()))})


def plan_outputs(directory, graph: str, usd_name: str, frames, measured=(), *, previews: bool = True,
                 validate: bool = False, pixels: bool = False, movie: str | None = None, protected=()) -> OutputPlan:
    """The files of a run (see :class:`OutputPlan`), from what is known before any work.

    Args:
        directory: the output directory; graph: the graph's name (it names every file).
        usd_name: the USD layer's file name (:func:`warpshade.io.usd_write.usd_output_name`).
        frames: the time codes the run records; measured: those measured against ground truth.
        previews: previews are written (of :func:`preview_frames`), and with ``validate`` the
            comparison pictures of the measured frames.
        validate: the run is measured; pixels: a stage of the run shades pixels (per-pixel images
            with ``previews``, per-pixel comparisons with ``validate``).
        movie: ``"mp4"`` or ``"gif"`` for a movie of every recorded frame, and with ``validate``
            one of the measured frames' comparison strips (None: no movies).
        protected: files the run reads (its scene).
    """
    d = Path(directory)
    shown = preview_frames(frames)
    measured = sorted(float(f) for f in measured) if validate else []
    return OutputPlan(
        directory=d,
        usd=d / usd_name,
        report=d / report_name(graph),
        previews={f: d / preview_name(graph, f) for f in shown} if previews else {},
        comparisons={f: d / comparison_name(graph, f) for f in measured} if previews else {},
        pixel_images={f: tuple(d / n for n in pixel_image_names(graph, f)) for f in shown} if previews and pixels else {},
        pixel_comparisons={f: d / pixel_comparison_name(graph, f) for f in measured} if pixels else {},
        movie=d / movie_name(graph, movie) if movie is not None else None,
        comparison_movie=d / comparison_movie_name(graph, movie) if movie is not None and measured else None,
        protected=tuple(protected),
    )
