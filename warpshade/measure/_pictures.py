"""Pictures of a run: previews, and the method side by side with ray-traced ground truth.

``comparison_figure`` renders one frame three times from the same camera: the method's
per-vertex radiance, the reference radiance (both at one exposure so they compare), and the
signed relative error per vertex on a diverging colour map, then writes the three panels with
titles and a colour bar as one PNG (atomically, :func:`write_panels`, which the per-pixel
strips of :mod:`._pixels` use too). :func:`render_previews` and :func:`render_comparisons` do it
for the recorded frames of a run. Every picture of a run has one exposure (:func:`run_exposure`),
so frames, previews and comparisons compare with each other.

The error shown is ``(Y_est - Y_ref) / mean(Y_ref)`` per vertex, with ``Y`` the Rec. 709
luminance: blue where the method is too dark (e.g. over-occlusion), red where it is too bright.
Normalising by the mean rather than by each vertex keeps dark, fully shadowed vertices from
dominating the picture; it is the same normalisation as the relative RMS in the reports.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._fileio import atomic_path
from ._outputs import comparison_name, preview_frames, preview_name

__all__ = [
    "ERROR_COLORMAP",
    "ERROR_LIMIT",
    "luminance",
]

#: Rec. 709 luminance weights of linear RGB.
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: Diverging colour map of the error panel (white at zero error).
ERROR_COLORMAP = "RdBu_r"
#: Default end of the error colour scale, as a fraction of the mean reference luminance.
ERROR_LIMIT = 0.5
#: Label of the error colour bar: the signed luminance error over the mean reference luminance.
ERROR_LABEL = "error: (Y_method - Y_ref) / mean Y_ref"


def luminance(rgb) -> np.ndarray:
    """Rec. 709 luminance of linear RGB, shape (..., 3) -> (...)."""
    return np.asarray(rgb, np.float64) @ LUMA


def reference_exposure(radiance) -> float:
    """Exposure (stops) mapping the 99th percentile of the luminance of radiance (..., 3) to 0.9."""
    p99 = float(np.percentile(luminance(radiance).ravel(), 99))
    return float(np.log2(0.9 / p99)) if p99 > 0 else 0.0


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def error_colors(estimate, reference, limit: float = ERROR_LIMIT, cmap: str = ERROR_COLORMAP):
    """Per-vertex colours of the signed relative error, as linear RGB for the renderer.

    Args:
        estimate, reference: per-vertex linear RGB radiance, shape (V, 3).
        limit: error mapped to the ends of the colour map (> 0).
        cmap: a matplotlib colour map name.

    Returns:
        (colors (V, 3) float32 linear RGB -- sRGB-encoded by the renderer at exposure 0 they are
        exactly the colour map's colours -- and the signed error (V,) float64).
    """
    import matplotlib

    est, ref = np.asarray(estimate, np.float64), np.asarray(reference, np.float64)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] != 3:
        raise ValueError(f"error_colors: estimate {est.shape} and reference {ref.shape} must both be (V, 3)")
    if not limit > 0:
        raise ValueError(f"error_colors: limit must be > 0, got {limit!r}")
    y_ref = luminance(ref)
    scale = float(np.mean(y_ref))
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError("error_colors: the reference has no positive mean luminance")
    err = (luminance(est) - y_ref) / scale
    t = np.clip(0.5 + 0.5 * np.nan_to_num(err, nan=0.0) / limit, 0.0, 1.0)
    rgba = matplotlib.colormaps[cmap](t)
    return _srgb_to_linear(rgba[:, :3]).astype(np.float32), err


def comparison_figure(
    scene,
    frame,
    estimate,
    reference,
    path,
    *,
    label: str = "estimate",
    reference_label: str = "ray traced",
    environment=None,
    exposure: float | None = None,
    limit: float = ERROR_LIMIT,
    width: int = 400,
    height: int = 300,
    supersample: int = 2,
    device=None,
) -> Path:
    """Write a three-panel PNG: method | reference | signed relative error, for one frame.

    Args:
        scene: the :class:`~warpshade.scene.Scene`; frame: its time code.
        estimate, reference: per-vertex linear RGB radiance of the frame, shape (V, 3).
        path: destination PNG (written atomically; its directory is created).
        label, reference_label: panel titles (the error statistics are appended).
        environment: shown where camera rays miss (default: neutral grey).
        exposure: stops; default maps the reference's 99th-percentile luminance to 0.9.
        limit: end of the error colour scale (fraction of the mean reference luminance).
        width, height, supersample: per-panel resolution and rays per pixel per axis.
        device: Warp device.

    Returns:
        The path written.
    """
    images, titles, caption = comparison_panels(
        scene, frame, estimate, reference, label=label, reference_label=reference_label, environment=environment,
        exposure=exposure, limit=limit, width=width, height=height, supersample=supersample, device=device)
    return write_panels(path, images, titles, limit, caption)


def comparison_panels(scene, frame, estimate, reference, *, label: str = "estimate", reference_label: str = "ray traced",
                      environment=None, exposure: float | None = None, limit: float = ERROR_LIMIT, width: int = 400,
                      height: int = 300, supersample: int = 2, device=None, bvh=None):
    """The three panels of :func:`comparison_figure` (same arguments), not yet composed.

    Args:
        bvh: a :class:`~warpshade.geometry._bvh.Visibility` of the scene to refit and reuse (frame
            loops); default one built for the call.

    Returns:
        (three uint8 sRGB images (height, width, 3): method, reference, error; their three titles;
        the caption naming the frame).
    """
    from ..geometry._bvh import Visibility
    from ..render import render
    from ._metrics import error_metrics

    est = np.asarray(estimate, np.float64)
    ref = np.asarray(reference, np.float64)
    if est.shape != (scene.vertex_count, 3) or ref.shape != est.shape:
        raise ValueError(f"comparison_figure: estimate {est.shape} and reference {ref.shape} must be "
                         f"({scene.vertex_count}, 3) for this scene")
    if exposure is None:
        exposure = reference_exposure(ref)
    colors, err = error_colors(est, ref, limit)
    state = scene.evaluate(frame, device=device)
    if bvh is None:
        bvh = Visibility.from_scene(scene, device=device)
    common = dict(width=width, height=height, supersample=supersample, device=device, bvh=bvh, state=state)
    images = [
        render(scene, frame, colors=est.astype(np.float32), environment=environment, exposure=exposure, **common).image,
        render(scene, frame, colors=ref.astype(np.float32), environment=environment, exposure=exposure, **common).image,
        render(scene, frame, colors=colors, exposure=0.0, **common).image,
    ]
    metrics = error_metrics(est, ref)
    titles = [
        f"method: {label}\nrel RMS {metrics['rel_rms']:.3f}, p99 {metrics['rel_p99']:.3f}",
        f"reference: {reference_label}",
        f"error\nmin {np.nanmin(err):+.2f}, max {np.nanmax(err):+.2f}",
    ]
    return images, titles, f"frame {float(frame):g}"


#: Narrowest panel of :func:`write_panels`, inches at 100 dpi (room for a two-line title).
PANEL_MIN_INCHES = 3.0


def write_panels(path, images, titles, limit: float = ERROR_LIMIT, caption: str = "") -> Path:
    """Write three images side by side -- method | reference | error -- with a title over each
    and a colour bar for the error panel (``ERROR_COLORMAP`` from ``-limit`` to ``+limit``,
    labelled :data:`ERROR_LABEL`), as one PNG (atomically; its directory is created).

    Args:
        path: destination PNG.
        images: three tone-mapped sRGB images, uint8, each (H, W, 3), of one size.
        titles: three panel titles.
        limit: error at the ends of the colour bar (fraction of the mean reference luminance).
        caption: a line under the panels (e.g. the frame).

    Returns:
        The path written.
    """
    import matplotlib.pyplot as plt

    fig = _panels_figure(images, titles, limit, caption)
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return path


def panels_image(images, titles, limit: float = ERROR_LIMIT, caption: str = "") -> np.ndarray:
    """The picture :func:`write_panels` writes, as an sRGB uint8 array (height, width, 3) (a movie's frame)."""
    import matplotlib.pyplot as plt

    fig = _panels_figure(images, titles, limit, caption)
    try:
        fig.canvas.draw()
        return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    finally:
        plt.close(fig)


def _panels_figure(images, titles, limit: float, caption: str):
    """The matplotlib figure of :func:`write_panels` (the caller closes it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if len(images) != 3 or len(titles) != 3:
        raise ValueError(f"write_panels: needs three images and three titles, got {len(images)} and {len(titles)}")
    images = [np.asarray(img) for img in images]
    if any(img.dtype != np.uint8 or img.ndim != 3 or img.shape != images[0].shape for img in images):
        raise ValueError(f"write_panels: needs three uint8 (H, W, 3) images of one size, got "
                         f"{[(str(img.dtype), img.shape) for img in images]}")
    height, width = images[0].shape[:2]
    # panels placed by hand in inches: three images side by side, a colour bar, room for titles;
    # a small image is shown enlarged (nearest pixels) so that its panel is wide enough for its title
    top, bottom, bar = 0.55, 0.25, 1.1
    pw, ph = (max(1.0, PANEL_MIN_INCHES * 100 / width) * n / 100 for n in (width, height))
    fig_w, fig_h = 3 * pw + bar, ph + top + bottom
    fig = plt.figure(figsize=(fig_w, fig_h), dpi=100)
    axes = [fig.add_axes([i * pw / fig_w, bottom / fig_h, pw / fig_w, ph / fig_h]) for i in range(3)]
    for ax in axes:
        ax.title.set_wrap(True)
    for ax, img, title in zip(axes, images, titles):
        ax.imshow(img, interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    cax = fig.add_axes([(3 * pw + 0.12) / fig_w, (bottom + 0.1 * ph) / fig_h, 0.12 / fig_w, 0.8 * ph / fig_h])
    mappable = plt.cm.ScalarMappable(norm=matplotlib.colors.Normalize(-limit, limit), cmap=ERROR_COLORMAP)
    cbar = fig.colorbar(mappable, cax=cax)
    cbar.ax.tick_params(labelsize=7)
    cbar.set_label(ERROR_LABEL, fontsize=7)
    if caption:
        fig.text(0.5 * 3 * pw / fig_w, 0.04, caption, fontsize=9, ha="center")
    return fig


def run_exposure(runtime) -> float:
    """The one exposure (stops) of every picture of a run -- previews, comparisons, per-pixel
    images and strips: it maps the 99th percentile of the luminance of the recorded radiance
    (the first, middle and last recorded frames) to 0.9 before sRGB encoding.

    Raises:
        ValueError: when the run recorded no frames.
    """
    rec = sorted(runtime.results)
    if not rec:
        raise ValueError("run_exposure: the run recorded no frames (step with record=True, or run())")
    frames = sorted({rec[0], rec[len(rec) // 2], rec[-1]})
    lum = np.concatenate([luminance(runtime.results[float(f)]) for f in frames])
    p99 = float(np.percentile(lum, 99)) if lum.size else 1.0
    return float(np.log2(0.9 / p99)) if p99 > 0 else 0.0


def _environment_at(runtime, frame):
    from ..scene._lighting import Environment

    return next((light for light in runtime.lighting.lights_at(frame) if isinstance(light, Environment)), None)


def render_previews(runtime, out_dir, frames=None, width: int = 480, height: int = 360, exposure: float | None = None) -> list:
    """Write ``<graph>_<frame>.png`` previews of recorded frames (default: first, middle, last).

    One exposure is used for all pictures of a run so they compare (default :func:`run_exposure`).

    Raises:
        ValueError: when the run recorded no frames.
    """
    from ..render import render

    rec = sorted(runtime.results)
    if not rec:
        raise ValueError("render_previews: the run recorded no frames (step with record=True, or run())")
    if frames is None:
        frames = preview_frames(rec)
    if exposure is None:
        exposure = run_exposure(runtime)
    paths = []
    for f in frames:
        p = Path(out_dir) / preview_name(runtime.spec.name, f)
        render(runtime.scene, f, colors=runtime.results[float(f)], width=width, height=height,
               environment=_environment_at(runtime, f), exposure=exposure, path=p, device=runtime.device, supersample=2)
        paths.append(p)
    return paths


def render_comparisons(runtime, measurement, out_dir, frames=None, width: int = 400, height: int = 300,
                       exposure: float | None = None) -> list:
    """Write ``<graph>_<frame>_vs_reference.png`` (method | ray-traced | signed error) per frame.

    Args:
        runtime: the run; measurement: its :class:`~warpshade.measure._truth.Measurement`.
        frames: default every frame the measurement has.
        exposure: stops, the same for every frame (default :func:`run_exposure`, or the first
            measured reference's when the run recorded no frames).

    Raises:
        ValueError: a frame the measurement does not have.
    """
    frames = sorted(measurement.references) if frames is None else [float(f) for f in frames]
    missing = [f for f in frames if f not in measurement.references]
    if missing:
        raise ValueError(f"render_comparisons: frame(s) {missing} were not measured (measured: "
                         f"{sorted(measurement.references)})")
    if exposure is None and frames:
        exposure = run_exposure(runtime) if runtime.results else reference_exposure(measurement.references[frames[0]])
    paths = []
    for f in frames:
        p = Path(out_dir) / comparison_name(runtime.spec.name, f)
        paths.append(comparison_figure(runtime.scene, f, measurement.estimates[f], measurement.references[f], p,
                                       label=runtime.spec.name, environment=_environment_at(runtime, f),
                                       exposure=exposure, width=width, height=height, device=runtime.device))
    return paths


# ---- movies -----------------------------------------------------------------------------------------
def movie_format() -> str:
    """The format of a run's movies: ``"mp4"`` (H.264) when imageio's ffmpeg plugin finds an ffmpeg
    binary (``imageio-ffmpeg`` carries one), else ``"gif"``.

    Raises:
        ImportError: when imageio is not installed, saying what to install.
    """
    try:
        import imageio  # noqa: F401
    except ImportError:
        raise ImportError("movies need imageio: pip install imageio imageio-ffmpeg") from None
    try:
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return "gif"
    return "mp4"


def write_movie(path, frames, fps: float) -> Path:
    """Write sRGB frames as a movie, atomically (its directory is created).

    Args:
        path: destination; its suffix picks the format (``.mp4``: H.264 through imageio-ffmpeg;
            ``.gif``: looping GIF through Pillow).
        frames: an iterable of uint8 sRGB images (H, W, 3), all of one size; each is written as
            it comes (a long run is never held in memory). Odd sizes are padded by one edge pixel
            (H.264 in yuv420p needs even sizes).
        fps: frames per second (> 0).

    Returns:
        The path written.

    Raises:
        ValueError: no frames, frames of different sizes or not uint8 (H, W, 3), or ``fps`` <= 0.
    """
    import imageio.v2 as imageio

    path = Path(path)
    if not fps > 0:
        raise ValueError(f"write_movie: fps must be > 0, got {fps!r} ({path.name})")
    suffix = path.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise ValueError(f"write_movie: {path.name}: the suffix must be .mp4 or .gif")
    count, shape = 0, None
    with atomic_path(path) as tmp:
        if suffix == ".mp4":
            writer = imageio.get_writer(tmp, format="FFMPEG", mode="I", fps=float(fps), codec="libx264",
                                        pixelformat="yuv420p", macro_block_size=1, quality=8)
        else:
            writer = imageio.get_writer(tmp, format="GIF", mode="I", duration=1000.0 / float(fps), loop=0)
        with writer:
            for image in frames:
                image = np.asarray(image)
                if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
                    raise ValueError(f"write_movie: {path.name}: frame {count} is {image.dtype} {image.shape}, "
                                     "expected uint8 (H, W, 3)")
                if shape is None:
                    shape = image.shape
                elif image.shape != shape:
                    raise ValueError(f"write_movie: {path.name}: frame {count} is {image.shape}, frame 0 {shape}")
                pad = ((0, image.shape[0] % 2), (0, image.shape[1] % 2), (0, 0))
                writer.append_data(np.pad(image, pad, mode="edge") if any(p[1] for p in pad[:2]) else image)
                count += 1
            if count == 0:
                raise ValueError(f"write_movie: {path.name}: no frames")
    return path


def _fps(runtime) -> float:
    fps = float(getattr(runtime.scene, "fps", 0.0) or 0.0)
    return fps if np.isfinite(fps) and fps > 0 else 24.0


def render_movie(runtime, path, frames=None, width: int = 480, height: int = 360, exposure: float | None = None,
                 supersample: int = 1) -> Path:
    """Write a movie (:func:`write_movie`) of recorded frames at the scene's frame rate (24 when it has none).

    Each frame is rendered as the previews are (:func:`render_previews`: the same camera, sky and
    the run's one exposure, :func:`run_exposure`), so the movie and the pictures compare.

    Args:
        runtime: the run; path: ``.mp4`` or ``.gif`` (see :func:`movie_format`).
        frames: time codes (default every recorded frame, in order).
        width, height, supersample: resolution and rays per pixel per axis.
        exposure: stops (default :func:`run_exposure`).

    Raises:
        ValueError: when the run recorded no frames or a frame was not recorded.
    """
    from ..geometry._bvh import Visibility
    from ..render import render

    frames = sorted(runtime.results) if frames is None else [float(f) for f in frames]
    missing = [f for f in frames if f not in runtime.results]
    if not frames or missing:
        raise ValueError(f"render_movie: frame(s) {missing or frames} were not recorded "
                         f"(recorded: {len(runtime.results)} frames)")
    if exposure is None:
        exposure = run_exposure(runtime)
    bvh = Visibility.from_scene(runtime.scene, device=runtime.device)

    def images():
        for f in frames:
            yield render(runtime.scene, f, colors=runtime.results[f], width=width, height=height,
                         environment=_environment_at(runtime, f), exposure=exposure, device=runtime.device,
                         supersample=supersample, bvh=bvh).image

    return write_movie(path, images(), _fps(runtime))


def render_comparison_movie(runtime, measurement, path, frames=None, width: int = 400, height: int = 300,
                            exposure: float | None = None) -> Path:
    """Write a movie of the method | reference | error strips (:func:`comparison_figure`) of measured frames.

    It plays the measured frames at the scene's pace: the scene's frame rate over the median step
    between them (validated frames 0 and 24 of a 24 fps scene: one a second), at least 1 fps.

    Args:
        runtime: the run; measurement: its :class:`~warpshade.measure._truth.Measurement`.
        path: ``.mp4`` or ``.gif``; frames: default every frame the measurement has.
        exposure: stops, the same for every frame (default :func:`run_exposure`).

    Raises:
        ValueError: no frame, or a frame the measurement does not have.
    """
    from ..geometry._bvh import Visibility

    frames = sorted(measurement.references) if frames is None else [float(f) for f in frames]
    missing = [f for f in frames if f not in measurement.references]
    if not frames or missing:
        raise ValueError(f"render_comparison_movie: frame(s) {missing or frames} were not measured (measured: "
                         f"{sorted(measurement.references)})")
    if exposure is None:
        exposure = run_exposure(runtime) if runtime.results else reference_exposure(measurement.references[frames[0]])
    bvh = Visibility.from_scene(runtime.scene, device=runtime.device)

    def strips():
        for f in frames:
            images, titles, caption = comparison_panels(
                runtime.scene, f, measurement.estimates[f], measurement.references[f], label=runtime.spec.name,
                environment=_environment_at(runtime, f), exposure=exposure, width=width, height=height,
                device=runtime.device, bvh=bvh)
            yield panels_image(images, titles, ERROR_LIMIT, caption)

    gaps = np.diff(frames)
    fps = _fps(runtime) / max(float(np.median(gaps)), 1.0) if len(frames) > 1 else 1.0
    return write_movie(path, strips(), max(fps, 1.0))
