"""Flat-field correction and spatial nonuniformity (de Lasarte, Pujol, Arjona & Vilaseca
2007). docs/darks_flats.md.

Modules
-------
:mod:`ccdcore.flatfield.fit`
    :func:`flat_field` (eqs. 1–4: gain and offset maps per channel), :func:`correct`, the base
    image study, the zero-dark form.
:mod:`ccdcore.flatfield.results`
    The flat field's result records.
:mod:`ccdcore.flatfield.check`
    The check on held-out flats against their noise floor.
:mod:`ccdcore.flatfield.uniformity`
    :func:`snup` (SNUP = 100 σ / mean, eq. 5), SNUP against averaging, linearity.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "fit": ["flat_field", "flat_field_from_session", "correct", "FlatField", "zero_dark"],
    "check": ["held_out_figures", "HeldOutCheck"],
    "uniformity": ["snup", "SnupResult", "linearity"],
})
