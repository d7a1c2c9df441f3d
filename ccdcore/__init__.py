"""ccdcore: radiometric camera calibration.

Implements, with uncertainties and against a simulator with known truth:

- G. E. Healey, R. Kondepudy, "Radiometric CCD Camera Calibration and Noise Estimation",
  IEEE TPAMI 16(3), 1994 (noise model, dark reference, fixed-pattern map, scene variation);
- Y. Tsin, V. Ramesh, T. Kanade, "Statistical Calibration of CCD Imaging Process", ICCV 2001
  (response curves, HDR radiance with uncertainty, illumination-invariant change detection);
- M. de Lasarte, J. Pujol, M. Arjona, M. Vilaseca, "Optimized algorithm for the spatial
  nonuniformity correction of an imaging system based on a charge-coupled device color camera",
  Applied Optics 46(2), 2007 (flat-field gain/offset correction, SNUP).

Modules: :mod:`ccdcore.io` (frames and maps), :mod:`ccdcore.session` (capture sessions),
:mod:`ccdcore.channels` (layouts, channels, Bayer planes), :mod:`ccdcore.common` (shared helpers),
:mod:`ccdcore.stats` (streamed per-pixel statistics), the estimators (:mod:`ccdcore.noise`,
:mod:`ccdcore.darkframe`, :mod:`ccdcore.fixedpattern`, :mod:`ccdcore.planning`,
:mod:`ccdcore.scene`, :mod:`ccdcore.uniformity`, :mod:`ccdcore.flatfield`),
:mod:`ccdcore.product` (calibration products), :mod:`ccdcore.simulate` (camera simulators with
their truth), :mod:`ccdcore.cli` (command line).  ``docs/architecture.md`` in the repository
describes the layout and the data flow.  This package never imports a UI library.
"""
__version__ = "0.1.0"
