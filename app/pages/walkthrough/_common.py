"""What the Walkthrough's step modules share: the :class:`Step` interface and its helpers.

Step
    The base of every step object: ``build()`` (the widgets and panes of the step's body),
    ``async run()`` (compute what is missing, set the gate, draw) and ``draw()`` (show the
    stored result); ``release()`` and ``dropped(names)`` are hooks for the page.
table(css)
    An empty table pane in the app's style.
skip_missing(session, estimate)
    The *skip* gate of a step whose frames the session lacks.
IMAGE_WIDTH
    The width of the steps' image views.
Host
    What a step sees of its page (the page, :class:`.page.WalkthroughPage`, is one): this
    module imports neither the page nor the results, so the steps and the page import each
    other in one direction only.
"""
from __future__ import annotations

from typing import Any, Awaitable, Callable, ClassVar, Iterable, Protocol

import pandas as pd
import panel as pn

from ccdcore.guide import Gate, GateStatus
from ccdcore.product.make import missing_frames
from ccdcore.session import Session

from ...batch import batched, in_document
from .._styles import TABLE_CSS

IMAGE_WIDTH = 360


class Host(Protocol):
    """The page as its steps use it: the app state, the steps by slug, the typed results
    (:class:`.results.Results`), the document, the page's parameters and its gates."""

    state: Any
    steps: dict[str, Any]
    results: Any
    doc: Any
    param: Any

    def set_gate(self, slug: str, gate: Gate) -> None: ...


def table(css: str) -> pn.pane.DataFrame:
    """An empty table pane with the CSS class ``css`` (the browser tests find it by that)."""
    return pn.pane.DataFrame(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                             escape=True, css_classes=[css], stylesheets=[TABLE_CSS])


def skip_missing(session: Session, estimate: str) -> Gate | None:
    """A *skip* gate when the session lacks the frames of ``estimate`` (else ``None``)."""
    lacking = missing_frames(session, [estimate])
    if not lacking:
        return None
    req, roles = lacking[0]
    return Gate(GateStatus.SKIP, f"no {', '.join(roles)} frames: {req.purpose} is skipped",
                next=(f"capture {req.capture}",))


class Step:
    """One step of the walkthrough, bound to its page (one object per page and step).

    A subclass sets :attr:`slug` (one of :data:`ccdcore.guide.STEPS`) and defines
    :meth:`build`, :meth:`run` and :meth:`draw`. Its result is a frozen dataclass kept in the
    page's typed :class:`~.results.Results`, never on the step: a change drops it there.
    """

    slug: ClassVar[str]
    #: the attribute of :class:`~.results.Results` holding the step's result (default: slug)
    result_name: ClassVar[str] = ""

    def __init__(self, page: Host) -> None:
        self.page = page

    # ------------------------------------------------------------------ the interface -----
    def build(self) -> list[pn.viewable.Viewable]:
        """The widgets and panes of the step's body (built once, with the page)."""
        return []

    async def run(self) -> None:
        """Compute the step's result if it is missing (:meth:`ensure`, with the steps it needs),
        draw it and set its gate (:meth:`gate_of`)."""
        if self.needs_session() is None:
            return
        found = await self.ensure()
        if found is None:
            return
        self.redraw()
        gate = self.gate_of(found)
        if gate is not None:
            self.set_gate(gate)

    async def ensure(self) -> Any:
        """The step's result, computed once (``None`` when it is skipped or failed: the gate
        says why)."""
        return None

    def gate_of(self, found: Any) -> Gate | None:
        """The gate of the result ``found``: its own ``gate`` (the results of
        :mod:`ccdcore.guide` carry one); ``None`` when :meth:`ensure` has set it."""
        return getattr(found, "gate", None)

    def draw(self, found: Any) -> None:
        """Show the step's result ``found`` (:attr:`result`, never ``None``)."""

    def release(self) -> None:
        """The browser session ended: drop the arrays the step's views hold."""

    def dropped(self, names: Iterable[str]) -> None:
        """The results ``names`` were dropped (a change made them stale)."""

    # ------------------------------------------------------------------ helpers -----------
    @property
    def results(self) -> Any:
        """The page's typed results (:class:`.results.Results`)."""
        return self.page.results

    @property
    def result(self) -> Any:
        """The step's result in the page's results (``None``: not computed)."""
        return getattr(self.results, self.result_name or self.slug)

    async def once(self, make: Callable[[], Awaitable[Any]]) -> Any:
        """The step's :attr:`result`, made by ``make()`` when it is missing and stored unless
        it gives ``None``."""
        found = self.result
        if found is None:
            found = await make()
            if found is not None:
                setattr(self.results, self.result_name or self.slug, found)
        return found

    def set_gate(self, gate: Gate) -> None:
        self.page.set_gate(self.slug, gate)

    def redraw(self) -> None:
        """:meth:`draw` of the step's result, in the page's document as one browser update
        (nothing when the result was dropped meanwhile)."""

        def draw() -> None:
            found = self.result
            if found is not None:
                self.draw(found)

        in_document(self.page.doc, batched(draw))

    def needs_session(self) -> Session | None:
        """The loaded session; without one the step's gate says to open one."""
        session = self.page.state.session
        if session is None:
            self.set_gate(Gate(GateStatus.SKIP, "no session loaded",
                               next=("open a session on the Session page",)))
        return session

    async def compute(self, func: Callable, *args: Any, label: str,
                      pass_progress: bool = False) -> Any:
        """``func(*args)`` off the UI thread; a failure becomes the step's *fail* gate, a
        session changed meanwhile gives ``None``."""
        state = self.page.state
        session = state.session
        result = await state.compute(func, *args, label=label, pass_progress=pass_progress)
        if state.session is not session:
            return None
        if result is None:
            why = state.error or "the computation was cancelled"
            self.set_gate(Gate(GateStatus.FAIL, why, next=(
                "correct the frames or the choices of this step, then revisit it",)))
        return result
