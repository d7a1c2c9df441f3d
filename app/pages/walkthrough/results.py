"""The Walkthrough's results, typed, and which of them a change makes stale.

DOWNSTREAM
    Per step, the results a change in that step makes stale (they recompute when shown).
stale(slug, include)
    The names :data:`DOWNSTREAM` drops for a change in ``slug`` (with ``slug`` itself when
    ``include``): the one place the staleness is decided.
Results
    One attribute per result, ``None`` while it is not computed (or after it was dropped). Each
    step's result is a frozen dataclass of its module (``VerifyResult(product, check)``, ...) or
    a frozen result of :mod:`ccdcore.guide`.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Iterable

if TYPE_CHECKING:
    from ccdcore.emva.results import EmvaSummary
    from ccdcore.guide import DarkStep, PatternStep

    from .export import ExportResult
    from .plan import PlanResult
    from .ptc import PtcResult
    from .response import ResponseAndHdr
    from .session import SessionResult
    from .verify import VerifyResult

#: the steps whose results a change in a step makes stale (they recompute when shown)
DOWNSTREAM: dict[str, tuple[str, ...]] = {
    "plan": (),
    "session": ("dark", "ptc", "emva", "pattern", "response", "verify", "report", "export"),
    "dark": ("pattern", "verify", "report", "export"),
    "ptc": ("emva", "pattern", "verify", "report", "export"),
    "pattern": ("verify", "report", "export"), "response": ("verify", "report", "export"),
    "verify": ("report", "export"), "export": ()}


def stale(slug: str, include: bool = False) -> tuple[str, ...]:
    """The results a change in step ``slug`` makes stale (with its own when ``include``)."""
    return DOWNSTREAM[slug] + ((slug,) if include else ())


@dataclass
class Results:
    """The walkthrough's results, one attribute each (``None``: not computed)."""

    plan: PlanResult | None = None
    session: SessionResult | None = None
    dark: DarkStep | None = None
    ptc: PtcResult | None = None
    #: the EMVA 1288 figures (:meth:`ccdcore.emva.datasheet.EmvaFigures.summary`) of the ptc step
    emva: EmvaSummary | None = None
    pattern: PatternStep | None = None
    response: ResponseAndHdr | None = None
    verify: VerifyResult | None = None
    #: the HTML report of the verify step's product (the export step's download and save)
    report: str | None = None
    export: ExportResult | None = None

    def drop(self, names: Iterable[str]) -> None:
        """Forget the results ``names`` (they recompute when their step is shown)."""
        known = {f.name for f in fields(self)}
        for name in names:
            if name not in known:
                raise KeyError(f"no walkthrough result {name!r}")
            setattr(self, name, None)

    def clear(self) -> None:
        self.drop(f.name for f in fields(self))
