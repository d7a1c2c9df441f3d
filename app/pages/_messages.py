"""The info and error alerts that the analysis pages share.

A page using :class:`PageMessages` has ``state`` (the :class:`~ccdcore_app.state.AppState`),
``info_alert`` and ``error_alert`` (``pn.pane.Alert``), ``content`` (what the info message
hides), ``_session`` (the session it shows) and an ``error`` string that tests and the header
read.
"""
from __future__ import annotations

from typing import Any


class PageMessages:
    """Mixin: one info line (hides the page content) and one error alert per page."""

    state: Any
    info_alert: Any
    error_alert: Any
    content: Any
    error: str
    _session: Any

    def _build_alerts(self, prefix: str) -> None:
        """The page's two alerts, hidden, with CSS classes ``ccd-{prefix}-info`` and
        ``ccd-{prefix}-error`` (the browser tests find them by those)."""
        import panel as pn

        self.info_alert = pn.pane.Alert("", alert_type="info", visible=False,
                                        sizing_mode="stretch_width",
                                        css_classes=[f"ccd-{prefix}-info"])
        self.error_alert = pn.pane.Alert("", alert_type="danger", visible=False,
                                         sizing_mode="stretch_width",
                                         css_classes=[f"ccd-{prefix}-error"])

    def _new_session(self, busy: bool = False) -> Any:
        """The loaded session when the page has not shown it yet (and not ``busy``): the page
        takes it (``_session``) and clears its error. ``None`` when there is nothing to do; with
        no session loaded the page says so."""
        session = self.state.session
        if session is None:
            self._show_empty()
            return None
        if session is self._session or busy:
            return None
        self._session = session
        self._set_error("")
        return session

    def _show_empty(self) -> None:
        if self.state.session is None:
            self._info("No session loaded: open one on the **Session** page.")

    def _info(self, text: str) -> None:
        self.info_alert.object = text
        self.info_alert.visible = bool(text)
        if text:
            self.content.visible = False

    def _set_error(self, text: str) -> None:
        self.error = text
        self.error_alert.object = f"**Error:** {text}" if text else ""
        self.error_alert.visible = bool(text)
