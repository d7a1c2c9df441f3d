"""Pure plot builders (no page state): frames, histograms and their reductions
(:mod:`ccdcore_app.plots.base`), change masks (:mod:`ccdcore_app.plots.change`), flat fields
(:mod:`ccdcore_app.plots.flat`), maps (:mod:`ccdcore_app.plots.maps`), response curves and HDR
(:mod:`ccdcore_app.plots.response`).
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "base": ["channel_planes", "auto_clim", "histogram_counts", "overview", "block_reduce"],
    "change": ["RgbView", "D2Histogram", "label_rgb"],
    "maps": ["MapLayer", "map_layers"],
    "response": ["ResponseFigure", "hdr_views", "verdict_markdown"],
})
