"""Step 2, session: every validation problem of the loaded session with its fix
(:func:`ccdcore.guide.session_gate`)."""
from __future__ import annotations

from dataclasses import dataclass

import pandas as pd
import panel as pn

from ccdcore import guide

from ._common import Step, table


@dataclass(frozen=True, eq=False)
class SessionResult:
    """The session's problems as a table: severity, where, problem, fix."""

    problems: pd.DataFrame


class SessionStep(Step):
    slug = "session"

    def build(self) -> list[pn.viewable.Viewable]:
        self.problems_table = table("ccd-wt-problems")
        return [self.problems_table]

    async def run(self) -> None:
        session = self.needs_session()
        if session is None:
            return
        gate = guide.session_gate(session)
        rows = [{"severity": p.severity, "where": p.where, "problem": p.message,
                 "fix": p.code.fix}
                for p in session.problems]
        self.results.session = SessionResult(pd.DataFrame(rows or [
            {"severity": "", "where": "", "problem": "no problems", "fix": ""}]))
        self.redraw()
        self.set_gate(gate)

    def draw(self, found: SessionResult) -> None:
        self.problems_table.object = found.problems
