"""Static PRT and unshadowed irradiance (the baselines every dynamic method is measured against)."""

from .stages import ShadeTransferStage, TransferStage, UnshadowedStage

__all__ = ["ShadeTransferStage", "TransferStage", "UnshadowedStage"]
