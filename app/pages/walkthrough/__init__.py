"""The Walkthrough page: a guided calibration in eight steps, each with its own URL.

The package holds the page's shell (:mod:`.page`: layout, navigation, gates), one module per
step of :data:`ccdcore.guide.STEPS` (:mod:`.plan`, :mod:`.session`, :mod:`.dark`, :mod:`.ptc`,
:mod:`.pattern`, :mod:`.response`, :mod:`.verify`, :mod:`.export`), each defining one
:class:`~._common.Step` (``build()``, ``async run()``, ``draw()``) and its result as a frozen
dataclass, the typed results with the staleness rule (:mod:`.results`) and what the steps share
(:mod:`._common`).
"""
from .dark import DARK_TABLE_MAX, dark_level_columns
from .page import STATUS_ICONS, STEP_TYPES, WalkthroughPage, create_page, gate_markdown
from .ptc import emva_table
from .results import DOWNSTREAM, Results

__all__ = ["WalkthroughPage", "create_page", "STATUS_ICONS", "STEP_TYPES", "DOWNSTREAM",
           "Results", "DARK_TABLE_MAX", "dark_level_columns", "emva_table", "gate_markdown"]
