"""Pins of the survivors of the sixth and seventh sets of planted bugs (docs/testing.md, "Rounds
so far"): each expectation comes from the documented contract, never from current output."""
from __future__ import annotations

from pathlib import Path

import pytest

from ccdcore.errors import CcdError
from ccdcore.io.outputs import check_not_inputs


@pytest.mark.parametrize("contain", [True, False])
def test_an_output_inside_an_input_folder_is_refused_whatever_contain(tmp_path: Path,
                                                                       contain: bool) -> None:
    """The docstring: an output equal to or *inside* an input is refused; only an output that
    *holds* an input depends on ``contain``. A folder written inside the session folder being
    read would overwrite what the run reads, whatever the caller asks of the other direction."""
    session = tmp_path / "session"
    (session / "darks").mkdir(parents=True)
    with pytest.raises(CcdError) as err:
        check_not_inputs([session / "darks" / "out"], [session], contain=contain)
    assert "is inside" in str(err.value) and "out" in str(err.value)
    # the other direction: an output folder holding an input is refused only with contain
    if contain:
        with pytest.raises(CcdError, match="holds"):
            check_not_inputs([tmp_path], [session / "darks"], contain=True)
    else:
        check_not_inputs([tmp_path], [session / "darks"], contain=False)


def test_the_datasheets_snr_plot_keeps_measured_points_below_one() -> None:
    """Release 3.1 sec. 6.6 plots the measured SNR from the darkest level up: below the absolute
    sensitivity threshold the SNR is under 1, and those points are the plot's left end. Only
    values a log axis cannot show (0, negative, NaN) are left out."""
    from types import SimpleNamespace

    from matplotlib.figure import Figure

    from ccdcore.emva import datasheet_files as dsf

    u_p = [2.0, 5.0, 20.0, 100.0, 1000.0]
    snr = [0.0, 0.4, 1.7, 6.0, None]
    curve = SimpleNamespace(u_p=u_p, snr=snr, snr_model=[], snr_total=[])
    emva = SimpleNamespace(snr_curve=curve, u_p_min=0.0, u_p_sat=0.0)
    fig = Figure()
    dsf._draw_snr(fig, emva)
    (measured,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "measured"]
    assert list(measured.get_xdata()) == [5.0, 20.0, 100.0]
    assert list(measured.get_ydata()) == [0.4, 1.7, 6.0]
