"""ccdcore: radiometric camera calibration.

Implements, with uncertainties and against a simulator with known truth:

- G. E. Healey, R. Kondepudy, "Radiometric CCD Camera Calibration and Noise Estimation",
  IEEE TPAMI 16(3), 1994 (noise model, dark reference, fixed-pattern map, scene variation);
- Y. Tsin, V. Ramesh, T. Kanade, "Statistical Calibration of CCD Imaging Process", ICCV 2001
  (response curves, HDR radiance with uncertainty, illumination-invariant change detection);
- M. de Lasarte, J. Pujol, M. Arjona, M. Vilaseca, "Optimized algorithm for the spatial
  nonuniformity correction of an imaging system based on a charge-coupled device color camera",
  Applied Optics 46(2), 2007 (flat-field gain/offset correction, SNUP);

and the EMVA 1288 standard's figures and datasheet.

The main entry points are importable from here (each imported on first use, so ``import
ccdcore`` loads nothing heavy):

========================== ===============================================================
:func:`open_session`       a capture session: a folder with ``session.toml``, a plain folder
                           of camera files, or an EMVA 1288 descriptor
:func:`read_image`,        frames and maps as the camera wrote them (OpenImageIO, FITS, raw)
:func:`write_image`
:func:`photon_transfer`    the noise model A, σ_C² (Healey & Kondepudy eqs. 37–42)
:func:`dark_reference`     the dark reference D̂_D (eq. 43)
:func:`fixed_pattern_map`  the fixed-pattern map K̂ (eqs. 45–50)
:func:`calibrate`          every estimate a session allows, as a calibration product
:func:`load_product`       a saved product, loaded back exactly
:func:`apply_product`      frames corrected with a product (eq. 51 and the flat field)
:func:`flat_field_from_session`  de Lasarte's gain and offset maps (eqs. 1–4)
:func:`snup`               spatial nonuniformity, SNUP = 100 σ / mean (eq. 5)
:func:`session_response`   the camera response of a bracket (Tsin et al. sec. 3.2 and others)
:func:`merge`              HDR radiance with its per-pixel sigma (eqs. 9, 18, 19)
:func:`session_change`     change detection between a reference and a target (sec. 5)
:func:`detect`             the same on two radiance maps with their sigmas (eq. 20)
:func:`emva_figures`       the EMVA 1288 figures with their errors
:class:`CcdError`          the one error of bad input: the file or parameter and the problem
========================== ===============================================================

The subpackages list their own public names: :mod:`ccdcore.io`, :mod:`ccdcore.session`,
:mod:`ccdcore.dark`, :mod:`ccdcore.flatfield`, :mod:`ccdcore.response`, :mod:`ccdcore.change`,
:mod:`ccdcore.emva`, :mod:`ccdcore.product`, :mod:`ccdcore.distributed`, :mod:`ccdcore.cli`,
:mod:`ccdcore.simulate` (camera simulators with their truth). ``docs/architecture.md`` in the
repository describes the layout and the data flow. This package never imports a UI library.

Examples
--------
>>> import tempfile, ccdcore
>>> from ccdcore.simulate import simulate
>>> tmp = tempfile.TemporaryDirectory()
>>> truth = simulate("healey94", tmp.name, seed=1, size=(64, 48))
>>> product = ccdcore.calibrate(tmp.name)
>>> sorted(product.estimates.to_dict())[:3]
['correction_check', 'dark', 'fixed_pattern']
>>> tmp.cleanup()
"""
import lazy_loader as lazy

__version__ = "0.1.0"

# each public name is imported from its module on first use (SPEC 1's lazy loading): the
# command line's ``--help`` and ``--version`` load no estimator
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "session": ["open_session"],
    "io.frames": ["read_image", "write_image"],
    "noise": ["photon_transfer"],
    "dark.frame": ["dark_reference"],
    "fixedpattern": ["fixed_pattern_map"],
    "product.make": ["calibrate", "apply_product"],
    "product.file": ["load_product"],
    "flatfield.fit": ["flat_field_from_session"],
    "flatfield.uniformity": ["snup"],
    "response.bracket_fit": ["session_response"],
    "response.hdr_merge": ["merge"],
    "change.session": ["session_change"],
    "change.detector": ["detect"],
    "emva.datasheet": ["emva_figures"],
    "errors": ["CcdError"],
})
__all__ = [*__all__, "__version__"]
