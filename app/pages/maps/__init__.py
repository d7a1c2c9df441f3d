"""The Maps page: dark, fixed-pattern, EMVA spatial and scene maps pixel by pixel.

Modules: :mod:`ccdcore_app.pages.maps.page` (the page), its tabs as param mixins
(:mod:`ccdcore_app.pages.maps.tab`, :mod:`ccdcore_app.pages.maps.scene`,
:mod:`ccdcore_app.pages.maps.planning`) and its tables (:mod:`ccdcore_app.pages.maps.tables`).
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "page": ["MapsPage", "create_page"],
})
