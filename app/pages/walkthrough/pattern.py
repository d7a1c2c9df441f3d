"""Step 5, pattern: the fixed pattern K̂ against the sec. V-B plan, and the flat field with its
SNUP before and after on flats outside the base group."""
from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import panel as pn

from ccdcore import guide
from ccdcore.session import Session

from ...image_view import ImageView, view_pane
from ._common import IMAGE_WIDTH, Step, table


def compute_pattern(session: Session, dark: Any, noise: Any) -> Any:
    return guide.pattern_step(session, dark=dark, noise=noise)


def snup_table(rows: tuple[dict[str, Any], ...]) -> pd.DataFrame:
    """The held-out flats' SNUP before and after the correction, as table rows."""
    if not rows:
        return pd.DataFrame([{"": "no held-out flat frames"}])
    return pd.DataFrame([
        {"frame": r["frame"], "channel": r["channel"], "before (%)": f"{r['before']:.3g}",
         "after (%)": f"{r['after']:.3g}"} for r in rows])


class PatternStep(Step):
    """The pattern step; its result is :class:`ccdcore.guide.PatternStep` (``results.pattern``)."""

    slug = "pattern"

    def build(self) -> list[pn.viewable.Viewable]:
        self.k_view = ImageView(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH,
                                cmap="RdBu_r", label="K̂", symbol="K̂",
                                css_classes=["ccd-wt-k-map"])
        self.k_pane = view_pane(self.k_view)
        self.snup_table = table("ccd-wt-snup")
        return [pn.Row(self.k_pane, pn.Column(
            pn.pane.Markdown("**SNUP on held-out flats** (%, before → after the flat-field "
                             "correction)"), self.snup_table, sizing_mode="stretch_width"),
            sizing_mode="stretch_width")]

    async def _compute_step(self) -> guide.PatternStep | None:
        session = self.page.state.session
        if not (session.fixed_pattern_configs() or session.flat_groups()):
            return guide.pattern_step(session)        # the skip gate, nothing to read
        steps = self.page.steps
        dark = await steps["dark"].ensure()
        noise = await steps["ptc"].ensure()
        return await self.compute(compute_pattern, session,
                                  dark.dark if dark is not None else None, noise,
                                  label="the fixed pattern and flat field")

    async def ensure(self) -> guide.PatternStep | None:
        return await self.once(self._compute_step)

    def draw(self, step: guide.PatternStep) -> None:
        if step.fixed_pattern is not None:
            K = step.fixed_pattern.K
            half = float(max(np.percentile(np.abs(K - 1.0), 99.5), 1e-4))
            self.k_view.show(K, clim=(1.0 - half, 1.0 + half))
            self.k_pane.visible = True
        self.snup_table.object = snup_table(step.snup_rows)

    def release(self) -> None:
        self.k_view.release()
