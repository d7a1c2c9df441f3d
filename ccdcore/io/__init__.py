"""Frames and maps on disk: reading (OpenImageIO, FITS through astropy, camera raw through
rawpy), atomic writes, and every verb's outputs written as one set.

Modules
-------
:mod:`ccdcore.io.frames`
    :func:`read_image`, :func:`read_frame`, :func:`read_header`, :func:`read_region`,
    :func:`write_image`, :func:`write_map` and the atomic-write building blocks.
:mod:`ccdcore.io.base`
    :class:`ImageHeader`, the file kinds by extension.
:mod:`ccdcore.io.limits`
    The pixel limit checked from a header before any pixel is decoded.
:mod:`ccdcore.io.oiio`, :mod:`ccdcore.io.oiio_write`
    OpenImageIO's reading and writing, every call's error looked at.
:mod:`ccdcore.io.fits`
    FITS through astropy (BZERO/BSCALE for every BITPIX).
:mod:`ccdcore.io.outputs`
    A verb's outputs swapped in as one set with a journal; only what ccdcore wrote is replaced.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "frames": ["ImageHeader", "read_header", "read_image", "read_frame", "read_region",
               "write_image", "write_map", "atomic_path", "atomic_write_text",
               "atomic_write_bytes", "is_image_path", "MAX_PIXELS", "pixel_limit"],
    "outputs": ["output_set", "write_outputs", "check_output", "check_not_inputs"],
})
