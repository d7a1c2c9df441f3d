"""Results cached on disk by the session's content hash, shared by every browser tab.

Modules: :mod:`ccdcore_app.cache.store` (the cache, its keys and its entries' encoding),
:mod:`ccdcore_app.cache.limits` (an entry's size checked before it is loaded).
"""
import lazy_loader as lazy

# each public name is imported from its module on first use (SPEC 1's lazy loading)
__getattr__, __dir__, __all__ = lazy.attach(__name__, submod_attrs={
    "store": ["ResultCache", "default_cache", "shared_results", "content_hash", "code_version"],
})
