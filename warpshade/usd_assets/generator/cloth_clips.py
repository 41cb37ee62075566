"""``cloth_train.usdc`` and ``cloth_heldout.usdc`` -- a banner simulated by Newton in changing wind.

A square cloth (``BANNER_CELLS`` x ``BANNER_CELLS`` cells, 1,089 vertices, 2,048 triangles,
``BANNER_SIZE`` = 1.6 m a side) hangs from a horizontal rod along its top edge (x in -0.8..0.8 m,
z = ``BANNER_TOP`` = 2.0 m; the rod's 33 vertices are pinned) and flaps in a wind whose speed and
heading change over time. The wind is a spatial gust field (:class:`Wind`): a mean velocity
interpolated between keyframes plus travelling gusts, applied per triangle as a normal-pressure
drag on the velocity relative to the cloth (:func:`add_wind_forces`). The cloth is solved by
Newton's ``SolverXPBD`` (stretch springs, bending constraints, contact with a ground plane at
z = 0) at 600 steps per second on Warp's CPU device; every clip starts from the same rest state
(the flat sheet, hanging) after ``PREROLL_SECONDS`` of calm.

* ``cloth_train.usdc`` -- 120 frames (5 s at 24 fps), ``TRAIN_WIND``: calm, gusts from the front,
  from either side and from behind, strong and weak.
* ``cloth_heldout.usdc`` -- 60 frames (2.5 s), ``HELDOUT_WIND``: other headings, speeds, gust
  wavelengths and timings (the held-out forcing).

Both have the same topology (a triangle mesh ``/World/Cloth``, ``faceVarying`` ``st`` UVs,
double sided), the ground grid, the shared sky and one camera; points are rounded to 1e-4 m
like every bundled scene. The simulation is deterministic on the CPU (Warp runs a CPU launch on
one thread, so the order of atomic additions is fixed), so rerunning the generator rewrites the
same points; it needs Newton (``pip install -e ".[sim]"``) and takes a few minutes the first
time (Newton's kernels compile, about 90 s on a CPU). These two scenes are written only on
request: ``python -m warpshade.usd_assets.generator --scenes cloth_train cloth_heldout``.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
from pxr import Sdf, UsdGeom, Vt

from .sky import define_sky
from .writing import FPS, define_camera, define_ground, define_mesh, new_stage, rounded, save_stage, vec3f

#: Cells along each side of the banner (vertices: (BANNER_CELLS + 1) ** 2 = 1,089).
BANNER_CELLS = 32
#: Side of the square banner (m) and the height of its pinned top edge (m).
BANNER_SIZE = 1.6
BANNER_TOP = 2.0
#: Mass of one particle (kg) and the cloth's springs, as in ``examples/newton_cloth.py`` (lighter
#: particles, 0.02 kg, crumple these springs under XPBD even in still air).
PARTICLE_MASS = 0.05
SPRING_KE, SPRING_KD, BEND_KE = 1.0e3, 1.0, 1.0e1
#: Solver steps per frame at ``FPS`` (24): dt = 1/600 s, stable for these springs.
SUBSTEPS = 25
XPBD_ITERATIONS = 10
#: Seconds simulated before the first written frame (the hanging sheet settles in the calm).
PREROLL_SECONDS = 1.0
#: Drag coefficient of the normal-pressure wind force (N per m^2 per m/s of normal relative speed).
WIND_DRAG = 25.0
#: Frames of the two clips.
TRAIN_FRAMES, HELDOUT_FRAMES = 120, 60


@dataclasses.dataclass(frozen=True)
class Wind:
    """A wind field: a mean velocity between keyframes plus gusts travelling with it.

    Attributes:
        keys: (time s, speed m/s, heading degrees, updraft m/s) keyframes; the heading is the
            direction the wind blows towards, measured from +y (0: towards +y, through the banner
            from the front; 90: towards +x, along it), interpolated with a smoothstep between keys.
        gust: relative amplitude of the travelling gusts (0: a uniform wind).
        gust_wavelength: wavelength of the gusts (m) along the wind.
        gust_swirl: amplitude (m/s) of the cross-wind gusts that vary along the banner (x) and up (z).
    """

    keys: tuple
    gust: float
    gust_wavelength: float
    gust_swirl: float

    def mean(self, time: float) -> np.ndarray:
        """The mean wind velocity at ``time`` (s), shape (3,), m/s, world frame (Z up)."""
        keys = np.asarray(self.keys, dtype=np.float64)
        t = float(np.clip(time, keys[0, 0], keys[-1, 0]))
        k = int(np.clip(np.searchsorted(keys[:, 0], t, side="right") - 1, 0, len(keys) - 2))
        u = (t - keys[k, 0]) / (keys[k + 1, 0] - keys[k, 0])
        u = u * u * (3.0 - 2.0 * u)
        speed, heading, updraft = (1.0 - u) * keys[k, 1:] + u * keys[k + 1, 1:]
        a = np.radians(heading)
        return np.array([speed * np.sin(a), speed * np.cos(a), updraft])

    def parameters(self, time: float) -> np.ndarray:
        """What the force kernel reads at ``time``: (mean velocity (3), gust phase, gust, swirl,
        wave number), shape (7,), float32."""
        mean = self.mean(time)
        speed = float(np.linalg.norm(mean[:2]))
        k = 2.0 * np.pi / self.gust_wavelength
        return np.array([*mean, k * speed * time, self.gust, self.gust_swirl, k], dtype=np.float32)


#: The training wind: calm, then gusts from the front, both sides and behind, strong and weak.
TRAIN_WIND = Wind(
    keys=((0.0, 0.3, 0.0, 0.0), (0.8, 6.0, 0.0, 0.5), (1.6, 3.0, 50.0, 0.0), (2.4, 8.0, -40.0, 1.0),
          (3.2, 1.0, 90.0, 0.0), (4.0, 7.0, 180.0, 0.5), (5.0, 4.0, 150.0, -0.5)),
    gust=0.35, gust_wavelength=1.2, gust_swirl=1.0,
)
#: The held-out wind: other headings, speeds and timings, longer gusts.
HELDOUT_WIND = Wind(
    keys=((0.0, 2.0, 20.0, 0.0), (0.8, 7.0, -20.0, 0.8), (1.6, 4.5, 165.0, 0.0), (2.5, 5.5, 120.0, 0.3)),
    gust=0.25, gust_wavelength=1.8, gust_swirl=0.7,
)


def _wind_kernel():
    import warp as wp

    @wp.kernel(enable_backward=False)
    def add_wind_forces(q: wp.array(dtype=wp.vec3), qd: wp.array(dtype=wp.vec3), tris: wp.array(dtype=wp.int32, ndim=2),
                        wind: wp.array(dtype=wp.float32), drag: float, f: wp.array(dtype=wp.vec3)):
        t = wp.tid()
        i, j, k = tris[t, 0], tris[t, 1], tris[t, 2]
        c = (q[i] + q[j] + q[k]) / 3.0
        n2 = wp.cross(q[j] - q[i], q[k] - q[i])  # twice the area times the unit normal
        mean = wp.vec3(wind[0], wind[1], wind[2])
        speed = wp.length(mean)
        along = wp.vec3(0.0, 0.0, 0.0)
        if speed > 1.0e-6:
            along = mean / speed
        phase = wind[6] * wp.dot(c, along) - wind[3]
        w = mean * (1.0 + wind[4] * wp.sin(phase)) + wind[5] * wp.vec3(
            wp.sin(2.3 * c[0] - 0.7 * phase), 0.0, wp.cos(1.7 * c[2] + 0.9 * c[0] - 0.5 * phase))
        v = (qd[i] + qd[j] + qd[k]) / 3.0
        # normal pressure: drag times (normal relative speed) times area, along the normal
        force = (0.5 * drag / 3.0) * wp.dot(w - v, n2) * n2 / wp.max(wp.length(n2), 1.0e-12)
        wp.atomic_add(f, i, force)
        wp.atomic_add(f, j, force)
        wp.atomic_add(f, k, force)

    return add_wind_forces


def simulate_banner(wind: Wind, frames: int, cells: int = BANNER_CELLS, device: str = "cpu", progress=None):
    """Simulate the banner in ``wind`` with Newton and return its points per frame.

    Args:
        wind: the wind field.
        frames: frames to return (at ``FPS``), after ``PREROLL_SECONDS`` of calm.
        cells: cells along each side.
        device: Warp device (the CPU keeps it deterministic).
        progress: optional callable(frame) called after each frame.

    Returns:
        (points (frames, V, 3) float64 m world frame, faces (F, 3) int32, rest points (V, 3)).

    Raises:
        ImportError: Newton is not installed (``pip install -e ".[sim]"``).
        FloatingPointError: the simulation produced a non-finite point.
    """
    try:
        import newton
        import warp as wp
    except ImportError as exc:  # pragma: no cover - the [sim] extra
        raise ImportError('the cloth clips are simulated with Newton: pip install -e ".[sim]"') from exc

    kernel = _wind_kernel()
    with wp.ScopedDevice(device):
        builder = newton.ModelBuilder()  # Z up, gravity -9.81 m/s^2
        builder.add_ground_plane()
        cell = BANNER_SIZE / cells
        # the grid's local y is world z (a quarter turn about x): its top row is the rod
        builder.add_cloth_grid(
            pos=wp.vec3(-0.5 * BANNER_SIZE, 0.0, BANNER_TOP - BANNER_SIZE),
            rot=wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), 0.5 * np.pi), vel=wp.vec3(0.0, 0.0, 0.0),
            dim_x=cells, dim_y=cells, cell_x=cell, cell_y=cell, mass=PARTICLE_MASS, fix_top=True,
            add_springs=True, spring_ke=SPRING_KE, spring_kd=SPRING_KD, edge_ke=BEND_KE, particle_radius=0.4 * cell,
        )
        model = builder.finalize(device=device)
        model.soft_contact_ke = 1.0e2
        model.soft_contact_kd = 1.0
        model.soft_contact_mu = 0.8
        faces = model.tri_indices.numpy().astype(np.int32)
        solver = newton.solvers.SolverXPBD(model, iterations=XPBD_ITERATIONS)
        state_0, state_1 = model.state(), model.state()
        control = model.control()
        pipeline = newton.CollisionPipeline(model)
        contacts = pipeline.contacts()
        wind_params = wp.zeros(7, dtype=wp.float32, device=device)
        dt = 1.0 / (FPS * SUBSTEPS)
        rest = state_0.particle_q.numpy().astype(np.float64)
        preroll = int(round(PREROLL_SECONDS * FPS))
        out = np.empty((frames, len(rest), 3), dtype=np.float64)
        step = 0
        calm = Wind(keys=((0.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)), gust=0.0, gust_wavelength=1.0, gust_swirl=0.0)
        for frame in range(-preroll, frames):
            for _ in range(SUBSTEPS):
                time = step * dt - PREROLL_SECONDS
                field = calm if time < 0.0 else wind
                wind_params.assign(field.parameters(max(time, 0.0)))
                state_0.clear_forces()
                wp.launch(kernel, dim=len(faces), inputs=[state_0.particle_q, state_0.particle_qd, model.tri_indices,
                                                          wind_params, WIND_DRAG, state_0.particle_f])
                pipeline.collide(state_0, contacts)
                solver.step(state_0, state_1, control, contacts, dt)
                state_0, state_1 = state_1, state_0
                step += 1
            if frame >= 0:
                out[frame] = state_0.particle_q.numpy()
                if not np.all(np.isfinite(out[frame])):
                    raise FloatingPointError(f"cloth_clips: non-finite cloth point at frame {frame}")
                if progress is not None:
                    progress(frame)
    return out, faces, rest


def _write_clip(out_dir: str, name: str, wind: Wind, frames: int) -> str:
    from tqdm import tqdm

    with tqdm(total=frames, desc=f"simulating {name}", unit="frame") as bar:
        points, faces, rest = simulate_banner(wind, frames, progress=lambda frame: bar.update(1))
    stage = new_stage(animated=True, frame_count=frames)
    define_sky(stage)
    define_ground(stage)
    mesh = define_mesh(stage, "/World/Cloth", points[0], np.full(len(faces), 3), faces.ravel(), (0.75, 0.3, 0.2))
    mesh.CreateDoubleSidedAttr(True)
    lo, hi = rounded(points.reshape(-1, 3).min(0)), rounded(points.reshape(-1, 3).max(0))
    mesh.GetExtentAttr().Set(Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32)))
    attr = mesh.GetPointsAttr()
    for f in range(frames):
        attr.Set(vec3f(points[f]), f)
    # UVs from the rest sheet: u along the rod (x), v up (z)
    st_vertex = np.stack([(rest[:, 0] + 0.5 * BANNER_SIZE) / BANNER_SIZE, (rest[:, 2] - (BANNER_TOP - BANNER_SIZE)) / BANNER_SIZE], 1)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy(rounded(st_vertex[faces.ravel()]).astype(np.float32)))
    define_camera(stage, eye=(3.4, -3.6, 2.3), target=(0.0, 0.0, 1.1))
    path = os.path.join(out_dir, f"{name}.usdc")
    save_stage(stage, path)
    return path


def make_cloth_train(out_dir: str) -> str:
    return _write_clip(out_dir, "cloth_train", TRAIN_WIND, TRAIN_FRAMES)


def make_cloth_heldout(out_dir: str) -> str:
    return _write_clip(out_dir, "cloth_heldout", HELDOUT_WIND, HELDOUT_FRAMES)
