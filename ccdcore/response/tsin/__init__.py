"""The iterative response estimator of Tsin, Ramesh & Kanade (2001), sec. 3.2.

Modules
-------
:mod:`ccdcore.response.tsin.estimator`
    :func:`estimate` (instrumented pools, the band of g) and :func:`noise_terms`.
:mod:`ccdcore.response.tsin.kernels`
    Its compiled passes over the pools.
:mod:`ccdcore.response.tsin.gauge`
    The gauge of the white-balance fit and the band.
:mod:`ccdcore.response.tsin.noise`
    Eq. 17's fit of the noise terms.
:mod:`ccdcore.response.tsin.notes`
    Its notes, in words.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "estimator": ["estimate", "noise_terms", "TsinOptions", "ChannelResponse"],
})
