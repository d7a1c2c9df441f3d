"""The dark reference (Healey & Kondepudy 1994, sec. 3.1) and the per-pixel dark model
(offset plus dark current times exposure). docs/darks_flats.md.

Modules
-------
:mod:`ccdcore.dark.frame`
    :func:`dark_reference`: the mean dark frame with its variance, hot and dead pixels.
:mod:`ccdcore.dark.map`
    :class:`DarkReference`, the result, and its summary.
:mod:`ccdcore.dark.model`
    :func:`fit_dark_model`, :func:`session_dark_model`: offset and dark current per pixel
    from biases and darks at several exposures, at the flats' temperature.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "frame": ["dark_reference", "dark_reference_from_model"],
    "map": ["DarkReference"],
    "model": ["DarkModel", "fit_dark_model", "session_dark_model"],
})
