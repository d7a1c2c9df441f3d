"""The EMVA 1288 figures and the whole datasheet (release 3.1 definitions; release 4.0's
row, column and pixel parts of DSNU and PRNU). docs/emva.md.

Modules
-------
:mod:`ccdcore.emva.datasheet`
    :func:`emva_figures`: K, σ_d, QE, saturation, SNR, DR, linearity error, DSNU, PRNU.
:mod:`ccdcore.emva.results`
    The figures' result records and their summaries.
:mod:`ccdcore.emva.fits`
    One function per step of the figures: sensitivity, dark noise, the dynamic range, the
    linearity, DSNU1288 and PRNU1288.
:mod:`ccdcore.emva.dark`
    Dark current from the mean and from the variance.
:mod:`ccdcore.emva.spatial`
    Spectrograms, histograms, profiles and the split of DSNU and PRNU.
:mod:`ccdcore.emva.sheet`
    The datasheet's rows, in the standard's order.
:mod:`ccdcore.emva.datasheet_files`
    The datasheet as files: CSV, JSON and the plots (``ccdcore datasheet``).
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "datasheet": ["emva_figures", "EmvaFigures"],
    "sheet": ["datasheet_rows", "DATASHEET"],
    "dark": ["dark_current", "DarkCurrent"],
    "spatial": ["spatial_plots", "variance_split", "nonuniformity_split"],
    "datasheet_files": ["write_datasheet"],
})
