"""Calibration products: every estimate a session allows, saved as a folder that loads back
exactly, and applied to frames.

Modules
-------
:mod:`ccdcore.product.make`
    :func:`calibrate` (every estimate the session's frames allow), :func:`apply_product`
    (eq. 51 and the flat field), :func:`estimate_all`.
:mod:`ccdcore.product.file`
    :class:`CalibrationProduct` as a folder: ``calibration.json`` and ``maps/*.exr``;
    :func:`load_product`.
:mod:`ccdcore.product.records`
    The product's typed records: each estimate's summary and the provenance.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "make": ["calibrate", "apply_product", "estimate_all", "Estimates", "MapName"],
    "file": ["CalibrationProduct", "load_product", "PRODUCT_FILE"],
    "records": ["ProductEstimates", "Provenance"],
})
