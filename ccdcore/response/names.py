"""The names and limits of the response estimators that the command line's parser needs
(``ccdcore response --help``) without loading the estimators: this module imports nothing.

:data:`ccdcore.response.methods.METHODS` is keyed by :data:`METHOD_NAMES`, in this order (it
checks so when it is imported); :mod:`ccdcore.response.brackets` holds the same blooming limits
(``tests/test_cli_startup.py`` checks that they agree).
"""
from __future__ import annotations

__all__ = ["METHOD_NAMES", "METHOD_CHOICES", "DEFAULT_METHOD", "EXPOSURE_MODES",
           "DEFAULT_BLOOM_RADIUS", "MAX_BLOOM_RADIUS"]

#: the response estimators, as :data:`ccdcore.response.methods.METHODS` orders its keys
METHOD_NAMES: tuple[str, ...] = ("tsin", "debevec", "robertson", "mitsunaga-nayar")
#: what ``--method`` takes: ``auto`` (the default: sec. 3.2 unless Debevec & Malik's curve
#: predicts the bracket clearly better) or one of the estimators
METHOD_CHOICES: tuple[str, ...] = ("auto",) + METHOD_NAMES
DEFAULT_METHOD = "auto"
#: what ``--exposures`` takes: the bracket's own exposures when the images disagree with the
#: listed ones (``auto``), the listed ones, or the bracket's own always
EXPOSURE_MODES: tuple[str, ...] = ("auto", "listed", "estimated")

#: radius (pixels) around a saturated pixel whose codes are dropped (sec. 2: "usually 3 pixels")
DEFAULT_BLOOM_RADIUS = 3
#: largest blooming radius accepted: the disk's cost grows with its area, and a halo wider than
#: this is lens flare, not blooming
MAX_BLOOM_RADIUS = 64
