"""A calibration product on the Session page: opened, summarised, applied to a frame, saved.

Modules: :mod:`ccdcore_app.product.panel` (the panel), :mod:`ccdcore_app.product.summary`
(its tables), :mod:`ccdcore_app.product.apply` (the correction and its SNUP),
:mod:`ccdcore_app.product.save` (the Save card).
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "panel": ["ProductPanel"],
    "apply": ["apply_frame", "snup_pair"],
    "save": ["SaveCard"],
})
