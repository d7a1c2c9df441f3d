"""The Calibration product tab's last card: save the session's frames corrected by the product.

Public objects
--------------
SaveCard
    The part of :class:`ccdcore_app.product.panel.ProductPanel` (a ``param`` mixin: the output
    folder and the scope) that writes the chosen frame, or every frame of its role, corrected
    (or linearised) as float32 files (:func:`ccdcore_app.product.apply.save_corrected`, i.e.
    :func:`ccdcore.product.make.apply_product`) into a folder inside the allowed roots that holds no
    frame of the session, and lists what it wrote.
hidden_alert(kind, css_class)
    An empty alert, hidden until it has something to say.
ONE, ROLE, MAX_LISTED
    The scopes (the chosen frame, every frame of its role); at most this many written paths
    are listed.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import param

from ccdcore.errors import CcdError

from .apply import LINEARISE, save_corrected
from .summary import code_span
from ..pages._styles import MUTED

__all__ = ["SaveCard", "hidden_alert", "ONE", "ROLE", "MAX_LISTED"]

#: save the chosen frame or every frame of its role
ONE, ROLE = "frame", "role"
#: at most this many written paths are listed (the rest are counted)
MAX_LISTED = 20


def hidden_alert(kind: str, css_class: str) -> Any:
    """An empty alert of ``kind`` with the CSS class ``css_class`` (browser tests find it by
    it), hidden until it has something to say."""
    import panel as pn

    return pn.pane.Alert("", alert_type=kind, visible=False, sizing_mode="stretch_width",
                         css_classes=[css_class])


class SaveCard(param.Parameterized):
    """Mixin of the Calibration product panel: the Save card (see the module docstring)."""

    state: Any
    product: Any
    product_path: str
    frame: Any
    mode: str
    written: list[Path]
    _records: dict[str, Any]

    out_dir = param.String(default="", doc="The folder corrected frames are written into.")
    scope = param.Selector(default=ONE, objects={"This frame": ONE,
                                                 "Every frame of the role": ROLE},
                           doc="Save the chosen frame or every frame of its role.")

    def _build_save_widgets(self) -> None:
        """The output folder, the scope and the save button with its alerts."""
        import panel as pn

        self.out_input = pn.widgets.TextInput(
            label="Output folder (inside the allowed folders; never a folder of the session's "
                 "frames)", placeholder="/path/to/output", sizing_mode="stretch_width",
            min_width=300)
        self.scope_select = pn.widgets.RadioButtonGroup.from_param(self.param.scope,
                                                                   label="Save", align="end")
        self.save_button = pn.widgets.Button(label="Save corrected frames",
                                             color="success", align="end", width=200)
        self.save_button.on_click(self._on_save)
        self.save_alert = hidden_alert("danger", "ccd-product-save-error")
        self.saved_alert = hidden_alert("success", "ccd-product-saved")
        self.save_body = pn.Column(
            pn.Row(self.out_input, self.scope_select, self.save_button,
                   sizing_mode="stretch_width"),
            pn.pane.Markdown("Each frame is written as float32 with its base name (TIFF, EXR "
                             "and FITS keep their format, others become TIFF) by "
                             "`ccdcore.product.make.apply_product`, atomically; the inputs are "
                             "never changed.", styles={"color": MUTED},
                             sizing_mode="stretch_width"),
            self.save_alert, self.saved_alert, sizing_mode="stretch_width", visible=False)

    # ============================================================ saving ===================
    async def _on_save(self, event: Any = None) -> None:
        await self.save(self.out_input.value_input or self.out_input.value)

    def _save_failed(self, message: str) -> None:
        self.saved_alert.visible = False
        self.save_alert.param.update(object=f"**Nothing written:** {message}", visible=True)

    async def save(self, out_dir: str | Path) -> list[Path]:
        """Write the chosen frame, or every frame of its role, corrected (or linearised) as
        float32 into ``out_dir`` (inside the allowed roots, holding no frame of the session);
        the written files, listed in a success alert (an alert says why nothing was written)."""
        product, session = self.product, self.state.session
        rec = self._records.get(self.frame) if self.frame is not None else None
        self.written = []
        if product is None or session is None or rec is None:
            self._save_failed("open a calibration product and a session, and choose a frame")
            return []
        text = str(out_dir).strip()
        if not text:
            self._save_failed("type the output folder first")
            return []
        try:
            folder = self.state.check_allowed(text)
        except CcdError as err:
            self._save_failed(str(err))
            return []
        inputs = {r.path.resolve().parent for r in session.frames}
        if folder in inputs:
            self._save_failed(f"{code_span(folder)} holds frames of the session; choose another "
                              "folder so that no input can be overwritten")
            return []
        if self.product_path and folder in (Path(self.product_path),
                                            Path(self.product_path) / "maps"):
            self._save_failed(f"{code_span(folder)} is the product's own folder; choose another")
            return []
        recs = session.by_role(rec.role) if self.scope == ROLE else (rec,)
        what = f"{len(recs)} corrected frame{'s' if len(recs) != 1 else ''}"
        written, error = await self._compute(
            save_corrected, product, [r.path for r in recs], folder,
            linearise=self.mode == LINEARISE, label=what)
        if written is None:
            self._save_failed(error)
            return []
        self.written = list(written)
        listed = "\n".join(f"- {code_span(p)}" for p in self.written[:MAX_LISTED])
        more = len(self.written) - MAX_LISTED
        self.save_alert.visible = False
        self.saved_alert.param.update(
            object=f"**Wrote {len(self.written)} file{'s' if len(self.written) != 1 else ''}** "
                   f"({'linearised' if self.mode == LINEARISE else 'corrected'}, float32) into "
                   f"{code_span(folder)}:\n\n{listed}" + (f"\n- ... and {more} more" if more > 0
                                                       else ""),
            visible=True)
        return self.written
