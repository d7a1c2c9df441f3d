"""The names of a calibration product's maps: :class:`MapName`.

Its home is below :mod:`ccdcore.product.make` (which re-exports it) so that the estimators writing
maps for a product (:meth:`ccdcore.flatfield.fit.FlatField.maps`) name them without importing the
product module, which imports them.
"""
from __future__ import annotations

from enum import StrEnum

__all__ = ["MapName"]


class MapName(StrEnum):
    """The name of one map of :attr:`ccdcore.product.make.CalibrationProduct.maps`.

    A ``str``: each member equals, hashes, formats and serialises (JSON) as its value
    (``MapName.K == "K"``, ``f"maps/{MapName.K}.exr" == "maps/K.exr"``), so
    ``calibration.json``, the map files and a lookup by the plain string are unchanged.
    :func:`ccdcore.product.make.load_product` refuses a map whose name is not a member.
    """

    DARK = "dark"              # D̂_D (sec. V-A of Healey & Kondepudy 1994)
    DARK_VAR = "dark_var"      # its per-pixel temporal variance
    HOT = "hot"                # 0/1 flags
    DEAD = "dead"              # 0/1 flags
    K = "K"                    # K̂, eq. 49
    K_VAR = "K_var"            # K̂'s per-pixel error variance
    N1_USED = "n1_used"        # n'_1
    FLAT_G = "flat_G"          # flat-field gain G (de Lasarte et al. 2007)
    FLAT_O = "flat_O"          # flat-field offset O
    FLAT_FLAGS = "flat_flags"  # 0/1 flags of G
    FLAT_DARK = "flat_dark"    # DL_0
    FLAT_BASE = "flat_base"    # DL_B
