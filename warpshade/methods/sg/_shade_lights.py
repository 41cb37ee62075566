"""The lights of ``sg.shade``: the environment (the ``sg.environment`` artifact, or prepared at
set-up for a lighting set at run time), its suns and the distant and sphere lights as the kernels'
:class:`~._kernels.Lights`, turned with the frame; and the check that sphere lights stay outside
the meshes whose visibility was precomputed for distant light.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..._wp import wp
from ..stage import Param, StageError
from . import _kernels as kernels
from ._lights import directional_light_lobe
from ._model import SUN_MODES, EnvironmentLighting, empty_table, environment_hash, environment_lighting, remember

#: Parameters of the environment's preparation (``sg.environment``).
ENVIRONMENT_PARAMS = {
    "lobes": Param(8, int, "most SG lobes of the environment's diffuse mixture (fewer than 10)", minimum=1, maximum=9),
    "error_budget": Param(None, float, "irradiance error the fit may leave (the fewest lobes that meet it)"),
    "fit": Param("lbfgsb", str, "environment fit", choices=("nnls", "lbfgsb")),
    "sun": Param("separate", str, "a small, very bright sun: taken out and shaded as a narrow light (its "
                 "visibility at its own direction) or left in the sky ('keep', the paper)", choices=SUN_MODES),
}
ENVIRONMENT_FITS = ("nnls", "lbfgsb")


def environment_settings(arrays) -> tuple:
    """(lobes, error_budget, fit, sun) the ``sg.environment`` stage used, read from its artifact
    ``arrays`` (its defaults without one)."""
    if arrays is not None and "settings" in arrays and np.asarray(arrays["settings"]).size == 4:
        lobes, budget, fit, sun = np.asarray(arrays["settings"], np.float64).reshape(4)
        return int(lobes), (None if budget < 0 else float(budget)), ENVIRONMENT_FITS[int(fit)], SUN_MODES[int(sun)]
    d = ENVIRONMENT_PARAMS
    return d["lobes"].default, d["error_budget"].default, d["fit"].default, d["sun"].default


def environment_for(env, arrays, device) -> EnvironmentLighting:
    """The prepared environment of ``env``: the ``sg.environment`` artifact ``arrays`` when it was
    built from this image, else built now (a lighting set at run time) with that stage's settings."""
    image_hash = environment_hash(env)
    stored = None if arrays is None or "none" in arrays else EnvironmentLighting.from_arrays(arrays)
    settings = environment_settings(arrays)
    if stored is not None and stored.image_hash == image_hash:
        remember(stored, *settings)
        return stored
    lobes, budget, fit, sun = settings
    return environment_lighting(env, lobes, budget, fit, device, None, sun)


class ShadeLights:
    """The frame's lights for the shading kernels.

    Attributes:
        lights: :class:`~._kernels.Lights`, the arrays the kernels read (axes turned every frame).
        environment: the prepared :class:`~._model.EnvironmentLighting`, or None without one.
    """

    def __init__(self, frame_lighting, environment: EnvironmentLighting | None, device):
        """Upload the lobes of ``environment`` (its mixture, prefiltered table and suns) and of the
        distant and sphere lights of ``frame_lighting`` (the frame's device lighting) to ``device``."""
        fl = frame_lighting
        self.device = device
        self.environment = environment
        lights = kernels.Lights()
        if environment is not None:
            mix = environment.mixture
            self._env_axes0 = wp.array(mix.axes.astype(np.float32), dtype=wp.vec3, device=device)
            lights.env_axes = wp.zeros(mix.lobe_count, dtype=wp.vec3, device=device)
            lights.env_sharpness = wp.array(mix.sharpness.astype(np.float32), dtype=float, device=device)
            lights.env_amplitude = wp.array(np.asarray(mix.amplitude, np.float32).reshape(-1, 3), dtype=wp.vec3,
                                            device=device)
            lights.env_count = mix.lobe_count
            lights.table = environment.table.to_device(device)
            lights.has_table = 1
        else:
            self._env_axes0 = wp.zeros(0, dtype=wp.vec3, device=device)
            lights.env_axes = wp.zeros(0, dtype=wp.vec3, device=device)
            lights.env_sharpness = wp.zeros(0, dtype=float, device=device)
            lights.env_amplitude = wp.zeros(0, dtype=wp.vec3, device=device)
            lights.env_count = 0
            lights.table = empty_table(device)
            lights.has_table = 0
        lights.env_to_world = (fl.environment_to_world if fl.environments
                               else wp.array(np.eye(3, dtype=np.float32)[None], dtype=wp.mat33, device=device))
        lights.sphere_position = fl.sphere_position
        lights.sphere_radius = fl.sphere_radius
        lights.sphere_radiance = fl.sphere_radiance
        lights.sphere_count = fl.sphere_light_count
        distant = list(fl.distant_lights)
        sun_axes, sun_sharp, sun_amp = (environment.sun_lobes if environment is not None
                                        else (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))))
        count = len(distant) + len(sun_sharp)
        self._distant_directions = fl.distant_direction if distant else wp.zeros(1, dtype=wp.vec3, device=device)
        self._sun_axes0 = wp.array(np.asarray(sun_axes, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
        self._distant_lights = len(distant)
        lights.distant_axes = wp.zeros(count, dtype=wp.vec3, device=device)
        sharp = np.zeros(count, np.float32)
        amp = np.zeros((count, 3), np.float32)
        for k, light in enumerate(distant):
            _, lam, mu = directional_light_lobe(light)
            sharp[k] = float(np.asarray(lam).reshape(-1)[0])
            amp[k] = np.asarray(mu, np.float64).reshape(3)
        sharp[len(distant):] = sun_sharp
        amp[len(distant):] = sun_amp
        lights.distant_sharpness = wp.array(sharp, dtype=float, device=device)
        lights.distant_amplitude = wp.array(amp, dtype=wp.vec3, device=device)
        lights.distant_count = count
        self.lights = lights

    def turn(self) -> None:
        """The frame's lobe axes: the environment's lobes and suns turned with it, distant lights."""
        dev, lights = self.device, self.lights
        if lights.env_count:
            wp.launch(kernels.turn_lobes_kernel, dim=lights.env_count, device=dev,
                      inputs=[self._env_axes0, lights.env_to_world, 0, lights.env_axes])
        if lights.distant_count:
            wp.launch(kernels.distant_axes_kernel, dim=lights.distant_count, device=dev,
                      inputs=[self._distant_directions, self._distant_lights, self._sun_axes0, lights.env_to_world,
                              lights.distant_axes])


def setup_lights(frame_lighting, environment_arrays, device, stage: str) -> ShadeLights:
    """The lights of ``frame_lighting`` with its one environment (if any) prepared from the
    ``sg.environment`` artifact ``environment_arrays`` (:func:`environment_for`)."""
    envs = frame_lighting.environments
    if len(envs) > 1:
        raise StageError(f"stage {stage!r}: SG shading takes one environment; this run has {len(envs)}")
    environment = environment_for(envs[0], environment_arrays, device) if envs else None
    return ShadeLights(frame_lighting, environment, device)


def lights_inside_hull(lighting, scene, stage: str) -> list:
    """Precomputed visibility is for distant light: every sphere light of ``lighting`` inside a
    mesh's convex hull (at the first frame's pose) at any frame of ``scene``, as ``{"mesh", "light",
    "frames" (the first 8), "count"}`` rows, with a warning; its shadows from that mesh are wrong on
    those frames."""
    from ._lights import inside_hull

    found = []
    spheres = lighting.sphere_lights() if lighting is not None else []
    if not spheres:
        return found
    table = lighting.sphere_position_table(scene.frames)  # (T, S, 3)
    points = scene.points_at(float(scene.frames[0]))
    for m in scene.meshes:
        pts = points[m.vertex_offset : m.vertex_offset + m.vertex_count]
        if m.vertex_count < 4:
            continue
        hits = inside_hull(pts, table.reshape(-1, 3)).reshape(table.shape[:2])  # (T, S)
        for s in range(table.shape[1]):
            inside = [int(t) for t in np.flatnonzero(hits[:, s])]
            if inside:
                found.append({"mesh": m.path, "light": s, "frames": inside[:8], "count": len(inside)})
    if found:
        first = found[0]
        warnings.warn(f"stage {stage!r}: sphere light {first['light']} is inside the convex hull of {first['mesh']} "
                      f"on {first['count']} frame(s) (from frame index {first['frames'][0]}): precomputed visibility is "
                      "for distant light, its shadows there are wrong", RuntimeWarning, stacklevel=2)
    return found
