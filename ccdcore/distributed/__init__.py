"""The frame reductions on a Dask cluster, in row bands the workers read (docs/distributed.md).

Modules
-------
:mod:`ccdcore.distributed.client`
    The client side: :class:`DaskReducer`, :func:`open_reducer`, :func:`get_client`.
:mod:`ccdcore.distributed.band_tasks`
    The tasks a worker runs on one band of frames (moments, pair sums, frame sums).
:mod:`ccdcore.distributed.hdr`
    The HDR merge band by band, with the halo the merge's blooming mask needs.
:mod:`ccdcore.distributed.kmap`
    The fixed-pattern map K̂ band by band.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "client": ["DaskReducer", "open_reducer", "get_client", "max_workers", "MAX_WORKERS",
               "SCHEDULER_ENV"],
})
