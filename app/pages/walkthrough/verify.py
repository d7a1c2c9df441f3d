"""Step 7, verify: the calibration product, made with the photon transfer the user chose, applied
to frames the calibration did not use (:func:`ccdcore.guide.verify`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import pandas as pd
import panel as pn

from ccdcore import guide
from ccdcore.guide import Gate
from ccdcore.progress import Progress
from ccdcore.session import Session

from ._common import Step, skip_missing, table

if TYPE_CHECKING:
    from ccdcore.product.make import CalibrationProduct


@dataclass(frozen=True, eq=False)
class VerifyResult:
    """The calibration product and its verification on held-out frames."""

    product: CalibrationProduct
    check: guide.Verification


def compute_product(session: Session, noise: Any, progress: Progress | None = None) -> Any:
    """The calibration product with the walkthrough's photon-transfer choices."""
    from ccdcore.product.make import calibrate

    return calibrate(session, noise=noise, progress=progress)


def compute_verify(session: Session, noise: Any, progress: Progress | None = None
                   ) -> VerifyResult:
    product = compute_product(session, noise, progress)
    return VerifyResult(product, guide.verify(session, product, noise=noise))


def verify_table(rows: tuple[guide.VerifyRow, ...]) -> pd.DataFrame:
    """The verification's rows: SNUP, pixel-scale nonuniformity, floor, pixels changed."""
    if not rows:
        return pd.DataFrame([{"": "no held-out frames"}])
    return pd.DataFrame([
        {"frame": r.frame, "channel": r.channel, "SNUP before → after (%)":
         f"{r.before:.3g} → {r.after:.3g}", "pixel scale before → after (%)":
         f"{r.local_before:.3g} → {r.local_after:.3g}",
         "noise floor (%)": "–" if r.floor is None else f"{r.floor:.3g}",
         "pixels changed > 1 code": f"{r.changed:,} of {r.n_pixels:,}"} for r in rows])


class VerifyStep(Step):
    slug = "verify"

    def build(self) -> list[pn.viewable.Viewable]:
        self.verify_table = table("ccd-wt-verify")
        return [self.verify_table]

    async def ensure(self) -> VerifyResult | None:
        """The product and its verification, computed once (``None`` when it failed)."""
        return await self.once(self._compute)

    async def _compute(self) -> VerifyResult | None:
        session = self.page.state.session
        noise = (await self.page.steps["ptc"].ensure()
                 if not skip_missing(session, "noise") else None)
        return await self.compute(compute_verify, session, noise,
                                  label="the calibration product", pass_progress=True)

    def gate_of(self, found: VerifyResult) -> Gate:
        return found.check.gate

    def draw(self, found: VerifyResult) -> None:
        self.verify_table.object = verify_table(found.check.rows)
