"""Step 6, response: the response curve g(z) of the first bracket (Tsin et al. sec. 3.2) and
the bracket's HDR radiance beside its relative sigma (eqs. 18-19), zoom linked."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import panel as pn

from ccdcore import guide
from ccdcore.guide import Gate, GateStatus
from ccdcore.product.make import requirement
from ccdcore.progress import Progress, within
from ccdcore.session import Session

from ...image_view import view_pane
from ...plots.response import hdr_views
from ._common import IMAGE_WIDTH, Step

if TYPE_CHECKING:
    from ccdcore.response.hdr_merge import HdrResult
    from ccdcore.response.methods import ResponseResult


@dataclass(frozen=True, eq=False)
class ResponseAndHdr:
    """The response of the session's first bracket and the bracket's HDR radiance; both
    ``None`` when the session has no bracket (the step is skipped)."""

    response: ResponseResult | None
    hdr: HdrResult | None

    @property
    def skipped(self) -> bool:
        return self.response is None


def compute_response(session: Session, progress: Progress | None = None) -> ResponseAndHdr:
    """The response of the session's first bracket (Tsin et al. sec. 3.2; its frames registered,
    its moving pixels left out) and the bracket's HDR radiance with its sigma (eqs. 9, 18, 19;
    the moving pixels from one exposure)."""
    from ccdcore.response.bracket_fit import fit_bracket, merge_fit

    fit = fit_bracket(session, progress=within(progress, 0.0, 0.9))
    if progress is not None:
        progress(0.9, "HDR radiance")
    return ResponseAndHdr(fit.result, merge_fit(fit, session.camera.layout))


class ResponseStep(Step):
    slug = "response"

    def build(self) -> list[pn.viewable.Viewable]:
        from ccdcore.response.methods import METHODS

        from ...plots.response import ResponseFigure

        self.response_fig = ResponseFigure(["tsin"], {"tsin": METHODS["tsin"].label},
                                           height=340)
        # the verdict in the library's words, as the Response & HDR page shows it
        self.verdict_alert = pn.pane.Alert("", alert_type="success",
                                           sizing_mode="stretch_width",
                                           css_classes=["ccd-wt-response-verdict"])
        self.response_holder = pn.Column(pn.pane.Bokeh(self.response_fig.fig,
                                                       sizing_mode="stretch_width"),
                                         self.verdict_alert,
                                         visible=False, sizing_mode="stretch_width")
        self.hdr_view, self.hdr_sigma = hdr_views(IMAGE_WIDTH,
                                                  ("ccd-wt-hdr", "ccd-wt-hdr-sigma"))
        self.hdr_pane, self.hdr_sigma_pane = view_pane(self.hdr_view), view_pane(self.hdr_sigma)
        return [self.response_holder,
                pn.pane.Markdown("**HDR radiance** (gamma 2.2 for display) **and its relative "
                                 "sigma** (eq. 19), zoom linked; the Response & HDR page has "
                                 "every control.", sizing_mode="stretch_width"),
                pn.Row(self.hdr_pane, self.hdr_sigma_pane)]

    async def ensure(self) -> ResponseAndHdr | None:
        """The response and the HDR radiance (``None`` when skipped or failed)."""
        found = await self.once(self._compute)
        return None if found is None or found.skipped else found

    async def _compute(self) -> ResponseAndHdr | None:
        session = self.page.state.session
        if not session.bracket_stacks("bracket"):
            self.set_gate(Gate(
                GateStatus.SKIP, "no exposure bracket: the response curve and HDR are skipped",
                next=(f"capture {requirement('response').capture}",)))
            return ResponseAndHdr(None, None)
        return await self.compute(compute_response, session, label="the response curve",
                                  pass_progress=True)

    def gate_of(self, found: ResponseAndHdr) -> Gate:
        return guide.response_gate(found.response, found.hdr)

    def draw(self, found: ResponseAndHdr) -> None:
        if found.skipped:
            return
        from ...plots.response import VERDICT_ALERTS, hdr_planes, verdict_markdown

        res = found.response
        ch = res.channels[0]
        self.response_fig.show({"tsin": (res[ch].g, res[ch].g_err)}, "tsin", False)
        verdict = res.verdict
        self.verdict_alert.param.update(
            object="" if verdict is None else verdict_markdown(verdict),
            alert_type="info" if verdict is None else VERDICT_ALERTS.get(verdict.status, "info"),
            visible=verdict is not None)
        self.response_holder.visible = True
        p = hdr_planes(found.hdr, 0)
        self.hdr_view.show(p["display"], clim=(0.0, 1.0))
        self.hdr_sigma.show(p["rel"], clim=(0.0, p["top"]))
        self.hdr_pane.visible = self.hdr_sigma_pane.visible = True

    def release(self) -> None:
        self.hdr_view.release()
        self.hdr_sigma.release()
