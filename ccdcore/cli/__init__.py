"""The command line: ``ccdcore VERB ...`` (docs/cli.md is its contract).

Modules
-------
:mod:`ccdcore.cli.command`
    :func:`main` and the parser; it imports no estimator, so ``--help`` and ``--version`` start
    at once.
:mod:`ccdcore.cli.session`, :mod:`ccdcore.cli.calibration`, :mod:`ccdcore.cli.response`
    The verbs by family: ``simulate``, ``session``, ``report``, ``app``; ``ptc``,
    ``calibrate``, ``datasheet``, ``apply``, ``snup``; ``response``, ``hdr``, ``change``.
:mod:`ccdcore.cli.common`
    What the verbs share: the printing, the ``--scheduler`` / ``--workers`` reducer and its
    note, the parser pieces every verb uses.
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "command": ["main", "build_parser"],
})
