"""What every method's stages share: the common parameters and the frame's SH lighting.

* :func:`order_param`, :data:`WINDOW`, :data:`WINDOW_SIZE`, :func:`window_args` -- the SH order
  and lighting-window parameters, defined once (each method picks its order range);
* :class:`ShLighting` -- the frame's world-frame SH lighting at a stage's order, optionally
  scaled per band (a window, the clamped-cosine convolution, a band truncation), in a fixed
  device buffer that a per-frame kernel refreshes from the
  :class:`~warpshade.scene._lighting_warp.FrameLighting` of the state;
* :func:`launch_parallel` -- a per-receiver launch split over the CPU cores (one launch on a
  GPU); inside a recorded CPU frame it runs between the recorded segments.
"""

from __future__ import annotations

import numpy as np

from .._wp import launch_parallel, wp
from ..basis import sh
from .stage import Param

__all__ = ["order_param", "rays_param", "WINDOW", "WINDOW_SIZE", "WINDOW_PARAMS", "window_args", "band_weights", "ShLighting",
           "launch_parallel"]

wp.set_module_options({"enable_backward": False})


def order_param(default: int = 4, minimum: int = 1, maximum: int = 10) -> Param:
    """The SH order parameter ``order`` (n bands, n*n coefficients) with a method's range."""
    return Param(default, int, "SH order n (n*n coefficients)", minimum=minimum, maximum=maximum)


def rays_param(default: int, doc: str = "rays per vertex", minimum: int = 16) -> Param:
    """A ray-count parameter, bounded by :data:`warpshade._limits.MAX_RAYS_PER_VERTEX`."""
    from .._limits import MAX_RAYS_PER_VERTEX

    return Param(default, int, doc, minimum=minimum, maximum=MAX_RAYS_PER_VERTEX)


#: SH window of the lighting (and, for SHEXP, the visibility).
WINDOW = Param(None, str, "SH window applied to the lighting (None, 'cosine', 'hanning', 'lanczos')",
               choices=(None, "cosine", "hanning", "lanczos"))
#: Its size h in bands.
WINDOW_SIZE = Param(None, float, "window size h in bands (default: 2n for 'cosine', n otherwise)", minimum=1e-6)
#: Both, for a stage's ``parameters``.
WINDOW_PARAMS = {"window": WINDOW, "window_size": WINDOW_SIZE}


def window_args(params: dict) -> dict:
    """Keyword arguments of :func:`warpshade.basis.sh.window` from a stage's parameters."""
    if params.get("window") is None:
        return {}
    args = {"kind": params["window"]}
    if params.get("window_size") is not None:
        args["size"] = params["window_size"]
    return args


def band_weights(order: int, params: dict | None = None, convolution=None, keep_bands: int | None = None) -> np.ndarray | None:
    """Per-band factors ``alpha_l`` (n,) of a stage's lighting, or None when all are 1.

    Args:
        order: SH order n.
        params: the stage's parameters (its ``window``/``window_size``).
        convolution: extra per-band factors (n,), e.g. the clamped cosine ``A_l``.
        keep_bands: zero the bands from this one on (shade at a lower order than accumulated).
    """
    alpha = np.ones(order)
    args = window_args(params or {})
    changed = False
    if args:
        alpha = alpha * sh.window_weights(args["kind"], order, size=args.get("size"))
        changed = True
    if convolution is not None:
        alpha = alpha * np.asarray(convolution, np.float64).reshape(order)
        changed = True
    if keep_bands is not None and keep_bands < order:
        alpha[keep_bands:] = 0.0
        changed = True
    return alpha if changed else None


@wp.kernel
def _scale_lighting_kernel(src: wp.array2d(dtype=wp.float32), weights: wp.array(dtype=wp.float32),
                           dst: wp.array2d(dtype=wp.float32)):
    c, i = wp.tid()
    dst[c, i] = src[c, i] * weights[i]


class ShLighting:
    """A stage's view of the frame's SH lighting: (3, n*n) float32, world frame, fixed address.

    Args:
        lighting: the state's :class:`~warpshade.scene._lighting_warp.FrameLighting`.
        order: the stage's SH order n.
        weights: per-band factors (n,) (:func:`band_weights`), or None for the lighting as is
            (then :attr:`light` *is* the state's array and :meth:`launch` does nothing).

    Attributes:
        light: wp.array2d (3, n*n) float32 read by the stage's kernels.
        changed: the state's (1,) int32 flag, 1 when the lighting changed since the last frame.
    """

    def __init__(self, lighting, order: int, weights=None):
        if lighting is None:
            raise ValueError("this stage needs the frame's lighting (the run has none)")
        src = lighting.sh(order)
        self.order = int(order)
        self.changed = lighting.changed
        self._src = src
        self._weights = None
        if weights is None:
            self.light = src
        else:
            per_coeff = np.asarray(weights, np.float64)[sh.band_of(order)]
            self._weights = wp.array(per_coeff.astype(np.float32), dtype=wp.float32, device=src.device)
            self.light = wp.zeros_like(src)

    @classmethod
    def for_stage(cls, lighting, order: int, params: dict, convolution=None, keep_bands: int | None = None) -> "ShLighting":
        """The lighting of a stage with ``window``/``window_size`` parameters."""
        return cls(lighting, order, band_weights(order, params, convolution, keep_bands))

    def launch(self) -> None:
        """Refresh :attr:`light` from the frame's lighting (kernels only)."""
        if self._weights is not None:
            wp.launch(_scale_lighting_kernel, dim=self.light.shape, inputs=[self._src, self._weights, self.light],
                      device=self.light.device)
