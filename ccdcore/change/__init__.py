"""Illumination-invariant change detection (Tsin, Ramesh & Kanade 2001, sec. 5, eq. 20).
docs/change.md.

Modules
-------
:mod:`ccdcore.change.detector`
    :func:`detect` on two radiance maps with their sigmas: the background's colour transform,
    further clusters, shades of the background's light, the calibrated threshold.
:mod:`ccdcore.change.kernels`
    The compiled d² of the prediction error, the shade test and the LTS fit.
:mod:`ccdcore.change.session`
    :func:`session_change`: a session's reference and target (brackets or frame sets).
:mod:`ccdcore.change.frames`
    Single frames and frame sets: the response and the noise when there is no bracket.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "detector": ["detect", "ChangeOptions", "ChangeResult", "ChangeInputs", "LABEL_CHANGE",
                 "LABEL_SHADE", "LABEL_UNDETERMINED"],
    "session": ["session_change"],
    "frames": ["frames_change"],
})
