"""What changes outside the frame: the :class:`Change` flags stages are notified with, and the
:class:`MaterialAssignment` of BRDFs chosen at run time (host data the frame state carries)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any


class Change(enum.IntFlag):
    """What changed outside the frame (``notify_changed`` flags).

    LIGHTING: the lights or a lighting override; MATERIAL: albedo, BRDFs; PARAMETERS: a stage
    parameter; VIEW: the eye / camera.
    """

    NONE = 0
    LIGHTING = 1
    MATERIAL = 2
    PARAMETERS = 4
    VIEW = 8
    ALL = 15


@dataclass
class MaterialAssignment:
    """BRDFs chosen at run time (``Runtime.set_material``): one for every mesh and per-prim ones.

    Attributes:
        default: a :class:`~warpshade.scene._materials.BRDF` for every mesh without a prim entry,
            or None (each stage's own BRDF parameters).
        prims: mesh prim path -> BRDF.
        version: incremented by every change (stages compare it to what they built).
    """

    default: Any = None
    prims: dict = field(default_factory=dict)
    version: int = 0

    def brdf_of(self, path: str, fallback=None):
        """The BRDF of the mesh ``path`` (its own, else the default, else ``fallback``)."""
        if path in self.prims:
            return self.prims[path]
        return self.default if self.default is not None else fallback

    def saved(self) -> tuple:
        """``(default, prims)`` as they are now (a copy), to put back with
        :meth:`FrameEvaluator.assign_materials` when a change is rejected."""
        return self.default, dict(self.prims)

    def describe(self) -> dict:
        return {"default": None if self.default is None else self.default.describe(),
                "prims": {k: v.describe() for k, v in sorted(self.prims.items())}}
