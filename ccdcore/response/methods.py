"""One registry of response estimators, and the response of a session's bracket.

Every method returns, per channel, a :class:`ccdcore.response.tsin.estimator.ChannelResponse`: g on
the reported scale (:mod:`ccdcore.response.scale`) with its 1-sigma band, a_k and b_k, and the noise
terms of eq. 17:

``tsin``
    Tsin, Ramesh & Kanade (2001), sec. 3.2 (:func:`ccdcore.response.tsin.estimator.estimate`): the
    band is the sandwich estimate of the pools' spread, the noise terms come with the estimate.
``debevec``, ``robertson``, ``mitsunaga-nayar``
    The classic methods of :mod:`ccdcore.response.classic`. They return g only; here the band is
    a delete-one-block jackknife over 8 blocks of pixels (bands of rows of the frame, so that
    correlated neighbours stay together), and the noise terms are fitted to eq. 17 with their g
    on the same pools as ``tsin`` (:func:`ccdcore.response.tsin.estimator.noise_terms`).

Public objects
--------------
METHODS
    name -> :class:`Method` (label, paper, function); the CLI's and the app's choices.
ResponseResult
    The per-channel responses of one bracket, with ``to_dict()`` (the CLI's JSON) and
    ``summary()``.
ResponseSummary, ResponseScaleSummary
    The record ``calibration.json`` stores (``estimates["response"]``: the CLI's JSON without
    ``files``), with ``rows()`` and ``models(where)`` (the curves as the HDR merge takes them).
response_of(brackets, method, ...)
    Estimate every channel of a bracket (:func:`ccdcore.response.brackets.load_bracket`).
session_response(session, method, ...)
    (defined in :mod:`ccdcore.response.bracket_fit`, which registers the frames and leaves the
    moving pixels out first)
    Load a session's bracket and estimate it.
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from ..errors import CcdError
from ..progress import Progress
from ..records import Record, Row
from .agreement import Agreement, AgreementSummary, agreement
from .brackets import DEFAULT_BLOOM_RADIUS, BracketData
from .classic import debevec, mitsunaga_nayar, robertson
from .hdr_merge import ResponseModel
from .names import DEFAULT_METHOD, EXPOSURE_MODES, METHOD_CHOICES, METHOD_NAMES
from .scale import reference_codes
from .tsin.estimator import ChannelResponse, TsinOptions, estimate, noise_terms
from .exposures import ExposureEstimate, ExposureSummary, estimate_exposures
from .verdict import ResponseVerdict, response_verdict

__all__ = ["METHODS", "Method", "ResponseResult", "ResponseSummary", "ResponseScaleSummary",
           "MethodComparison", "response_of", "JACKKNIFE_BLOCKS", "AUTO",
           "CHALLENGER", "EXPOSURE_MODES"]

#: the default method: sec. 3.2, unless Debevec & Malik's curve predicts the bracket clearly
#: better (:func:`response_of`)
AUTO = "auto"
#: the method every result is checked against (fast, and well behaved far from the truth)
CHALLENGER = "debevec"
#: which exposures a response takes (:data:`ccdcore.response.names.EXPOSURE_MODES`): ``auto``
#: (the bracket's own when the images disagree with the listed ones), ``listed``,
#: ``estimated`` (:mod:`ccdcore.response.exposures`)

#: blocks of pixels of the classic methods' jackknife band
JACKKNIFE_BLOCKS = 8


@dataclass(frozen=True)
class Method:
    """A response estimator: ``run(data, progress)`` -> ChannelResponse."""

    name: str
    label: str
    paper: str
    run: Callable[..., ChannelResponse]
    white_balance: bool = False      # the method can estimate the gains a_k


def _tsin(data: BracketData, progress: Progress | None, white_balance: bool = False
          ) -> ChannelResponse:
    return estimate(data, TsinOptions(white_balance=white_balance), progress=progress)


def _classic(name: str, fn: Callable[[BracketData], Any]
             ) -> Callable[..., ChannelResponse]:
    def run(data: BracketData, progress: Progress | None, band: bool = True) -> ChannelResponse:
        fit = fn(data)
        g = np.asarray(fit.g, np.float64)
        L = g.size
        blocks = data.row_bands(JACKKNIFE_BLOCKS)
        reps = []
        for b in range(JACKKNIFE_BLOCKS if band else 0):
            if progress is not None:
                progress((b + 1) / (JACKKNIFE_BLOCKS + 2), f"band: jackknife block {b + 1} "
                                                          f"of {JACKKNIFE_BLOCKS}")
            keep = np.flatnonzero(blocks != b)
            try:
                gb = np.asarray(fn(data.take(keep)).g, np.float64)
            except CcdError:
                continue
            # on the reported scale g(z_hi) is fixed: compare the shapes there
            reps.append(gb)
        if len(reps) >= 3:
            R = np.stack(reps)
            m = len(reps)
            g_err = np.sqrt((m - 1) / m * np.sum((R - R.mean(axis=0)) ** 2, axis=0))
        else:
            g_err = np.full(L, np.nan)
        if progress is not None:
            progress(0.95, "noise terms (eq. 17)")
        try:
            nz = noise_terms(data, g) if band else {}
        except CcdError:
            nz = {}
        t = np.asarray(data.t, np.float64)
        zeros = np.zeros(t.size)
        return ChannelResponse(
            channel=data.channel, method=name, g=g, g_err=g_err, a=t.copy(), a_err=zeros,
            b=zeros.copy(), b_err=zeros.copy(), t=t, sigma_s=nz.get("sigma_s"),
            sigma_c1=nz.get("sigma_c1"), sigma_c2=nz.get("sigma_c2"),
            sigma_s_err=nz.get("sigma_s_err"), sigma_c1_err=nz.get("sigma_c1_err"),
            sigma_c2_err=nz.get("sigma_c2_err"), iterations=int(fit.iterations),
            converged=bool(fit.converged), notes=tuple(fit.notes))
    return run


METHODS: dict[str, Method] = {
    "tsin": Method("tsin", "Tsin, Ramesh & Kanade (sec. 3.2)",
                   "Tsin, Ramesh & Kanade 2001, ICCV", _tsin, white_balance=True),
    "debevec": Method("debevec", "Debevec & Malik", "Debevec & Malik 1997, SIGGRAPH",
                      _classic("debevec", debevec)),
    "robertson": Method("robertson", "Robertson et al.",
                        "Robertson, Borman & Stevenson 2003, J. Electronic Imaging",
                        _classic("robertson", robertson)),
    "mitsunaga-nayar": Method("mitsunaga-nayar", "Mitsunaga & Nayar",
                              "Mitsunaga & Nayar 1999, CVPR",
                              _classic("mitsunaga-nayar", mitsunaga_nayar)),
}
assert tuple(METHODS) == METHOD_NAMES and DEFAULT_METHOD == AUTO and METHOD_CHOICES == (AUTO,) + \
    METHOD_NAMES, "names.py is out of step"


_Curves = tuple[tuple[float | None, ...], ...]


@dataclass(frozen=True)
class ResponseScaleSummary(Record):
    """The reported scale of g (:mod:`ccdcore.response.scale`): g(z_hi) = z_hi / (levels − 1)."""

    #: the code z_hi where g is fixed, and g there
    fixed_code: int
    g_at_fixed_code: float
    #: whether g has a free offset (never, in this release)
    offset: bool


@dataclass(frozen=True)
class MethodComparison(Record):
    """Another method's curve on the same bracket and exposures: its prediction agreement
    (sec. 4.2, DN RMS from a neighbour with the exposures, and with each pair's ratio
    fitted)."""

    method: str
    rms: float | None
    rms_fitted: float | None


@dataclass(frozen=True)
class ResponseSummary(Record):
    """A :class:`ResponseResult` as ``calibration.json`` stores it (``estimates["response"]``):
    the inverse response g of Tsin, Ramesh & Kanade (2001) per channel, in ``channels`` order,
    with its band and the noise terms of eq. 17; ``None`` for a number that is not finite.
    The bracket's files are in the product's provenance."""

    #: the estimator (a key of :data:`METHODS`), the channels and the codes per channel
    method: str
    channels: tuple[str, ...]
    levels: int
    #: the scale g is reported on
    scale: ResponseScaleSummary
    #: the bracket's nominal exposure times t_k, s, in increasing order
    exposure_times: tuple[float | None, ...]
    #: g per channel and code (relative exposure) and its 1-σ band
    g: _Curves
    g_err: _Curves
    #: the gains a_k and offsets b_k per channel and image (eq. 5; the nominal t_k and 0 unless
    #: white balance was estimated), then their standard errors
    a: _Curves
    b: _Curves
    a_err: _Curves
    b_err: _Curves
    #: the noise terms of eq. 17 per channel: shot σ_s and dark/input σ_c1 in units of g,
    #: output/read σ_c2 in DN (``None``: not estimated), then their standard errors
    sigma_s: tuple[float | None, ...]
    sigma_c1: tuple[float | None, ...]
    sigma_c2: tuple[float | None, ...]
    sigma_s_err: tuple[float | None, ...]
    sigma_c1_err: tuple[float | None, ...]
    sigma_c2_err: tuple[float | None, ...]
    #: iterations of each channel's fit and whether it converged
    iterations: tuple[int, ...]
    converged: tuple[bool, ...]
    #: radius (pixels) around saturated pixels left out of the fit
    bloom_radius: int
    #: per channel: the gains a_k were estimated (white balance); products made before
    #: white balance lack the key
    white_balance: tuple[bool, ...] = ()
    #: decisions and doubts per channel, keyed by channel
    notes: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: how well the curves predict the bracket's own images (sec. 4.2; ``None``: not computed)
    agreement: AgreementSummary | None = None
    #: why the curves should not be trusted (:meth:`ResponseResult.warnings`)
    warnings: tuple[str, ...] = ()
    #: whether the curves can be trusted (:mod:`ccdcore.response.verdict`; ``None`` in
    #: products made before the verdict)
    verdict: ResponseVerdict | None = None
    #: the method asked for ("auto" or a method) and why this one was kept
    requested: str = ""
    selection: str = ""
    #: the other curves fitted to the same bracket and exposures, with their agreement
    compared: tuple["MethodComparison", ...] = ()
    #: the bracket's own exposures against the listed ones (``None``: not estimated)
    exposures: ExposureSummary | None = None

    def rows(self) -> tuple[Row, ...]:
        """The method, the noise terms of every channel, the prediction agreement and a
        verdict."""
        out = [Row("method", None, None, "", f"the estimator of the inverse response g, "
                                             f"{self.levels} codes per channel", self.method)]
        terms = (("sigma_s", "σ_s", "", "shot noise (eq. 17), in units of g"),
                 ("sigma_c1", "σ_c1", "", "dark/input noise (eq. 17), in units of g"),
                 ("sigma_c2", "σ_c2", "DN", "output/read noise (eq. 17)"))
        for i, ch in enumerate(self.channels):
            for key, symbol, unit, meaning in terms:
                value, err = getattr(self, key), getattr(self, f"{key}_err")
                out.append(Row(f"{symbol}, {ch}", value[i] if i < len(value) else None,
                               err[i] if i < len(err) else None, unit, meaning))
        if self.agreement is not None:
            out += [replace(r, label=f"agreement {r.label}") for r in self.agreement.rows()[:2]]
        if self.exposures is not None:
            out += list(self.exposures.rows())
        if self.selection:
            out.append(Row("method chosen", None, None, "", self.selection, self.method))
        if self.verdict is not None:
            out += list(self.verdict.rows())
        else:
            verdict = ("no warning" if not self.warnings else
                       f"{len(self.warnings)} warning{'s' if len(self.warnings) > 1 else ''}: "
                       + "; ".join(self.warnings))
            out.append(Row("verdict", None, None, "", "whether the curves can be trusted",
                           verdict))
        return tuple(out)

    def models(self, where: Any = None) -> dict[str, ResponseModel]:
        """Channel -> :class:`ccdcore.response.hdr.ResponseModel` (g per code, a_k, b_k, the
        noise terms, ``None`` as 0), checked.

        Raises
        ------
        CcdError
            Naming ``where``: a channel without its curve or noise terms, g not a finite
            non-decreasing curve of two codes or more, a and b of different lengths or a not
            positive ("damaged response estimate: ...").
        """
        try:
            m = len(self.channels)
            for key in ("g", "a", "b", "sigma_s", "sigma_c1", "sigma_c2"):
                if len(getattr(self, key)) < m:
                    raise ValueError(f"{key} has {len(getattr(self, key))} entries for {m} "
                                     "channels")
            out = {}
            for i, c in enumerate(self.channels):
                g = np.asarray(self.g[i], np.float64)
                a = np.asarray(self.a[i], np.float64)
                b = np.asarray(self.b[i], np.float64)
                if g.ndim != 1 or g.size < 2 or not np.all(np.isfinite(g)) \
                        or np.any(np.diff(g) < 0):
                    raise ValueError(f"g of channel {c} is not a finite non-decreasing curve")
                if a.shape != b.shape or not np.all(a > 0):
                    raise ValueError(f"a, b of channel {c} do not match or a is not positive")
                out[c] = ResponseModel(g, a, b, float(self.sigma_s[i] or 0.0),
                                       float(self.sigma_c1[i] or 0.0),
                                       float(self.sigma_c2[i] or 0.0))
        except (TypeError, ValueError) as exc:
            raise CcdError(where, f"damaged response estimate: {exc}") from None
        return out


def _num(v: Any) -> float | None:
    """A plain float, ``None`` for None or a number that is not finite."""
    if v is None:
        return None
    v = float(v)
    return v if np.isfinite(v) else None


def _curve(x: Any) -> tuple[float | None, ...]:
    return tuple(_num(v) for v in np.asarray(x, np.float64).tolist())


@dataclass(frozen=True, eq=False)
class ResponseResult:
    """The responses of one bracket, one per channel in ``channels`` order."""

    method: str
    channels: tuple[str, ...]
    responses: tuple[ChannelResponse, ...]
    files: tuple[str, ...]
    levels: int
    t: NDArray[np.float64]
    bloom_radius: int = DEFAULT_BLOOM_RADIUS
    notes: tuple[str, ...] = field(default_factory=tuple)
    #: how well the curves predict the bracket's own images (sec. 4.2; ``None``: not computed)
    agreement: Agreement | None = None
    #: the bracket's own exposures (``None``: the listed ones taken as they are)
    exposures: ExposureEstimate | None = None
    #: the method asked for, why this one was kept, the other curves fitted
    requested: str = ""
    selection: str = ""
    compared: dict[str, Agreement] = field(default_factory=dict)
    #: whether the curves can be trusted (:func:`ccdcore.response.verdict.response_verdict`)
    verdict: ResponseVerdict | None = None

    def warnings(self) -> tuple[str, ...]:
        """The verdict's line when the result is not trusted (empty when it is)."""
        v = self.verdict if self.verdict is not None else response_verdict(self, self.compared)
        return () if v.trusted else (v.line(),)

    def __getitem__(self, channel: str) -> ChannelResponse:
        return self.responses[self.channels.index(channel)]

    def models(self) -> dict[str, ChannelResponse]:
        """channel -> response, as :func:`ccdcore.response.hdr.merge` takes them."""
        return dict(zip(self.channels, self.responses))

    def summary(self) -> ResponseSummary:
        """The record ``calibration.json`` stores: :meth:`to_dict` without ``files``."""
        _, z_hi = reference_codes(self.levels)
        levels = int(self.levels)
        r = self.responses

        def each(key: str) -> tuple[float | None, ...]:
            return tuple(_num(getattr(c, key)) for c in r)

        def curves(key: str) -> _Curves:
            return tuple(_curve(getattr(c, key)) for c in r)

        return ResponseSummary(
            method=str(self.method), channels=tuple(str(c) for c in self.channels),
            levels=levels,
            scale=ResponseScaleSummary(int(z_hi), float(z_hi / (levels - 1)), False),
            exposure_times=_curve(self.t), g=curves("g"), g_err=curves("g_err"),
            a=curves("a"), b=curves("b"), a_err=curves("a_err"), b_err=curves("b_err"),
            sigma_s=each("sigma_s"), sigma_c1=each("sigma_c1"), sigma_c2=each("sigma_c2"),
            sigma_s_err=each("sigma_s_err"), sigma_c1_err=each("sigma_c1_err"),
            sigma_c2_err=each("sigma_c2_err"),
            iterations=tuple(int(c.iterations) for c in r),
            converged=tuple(bool(c.converged) for c in r),
            bloom_radius=int(self.bloom_radius),
            white_balance=tuple(bool(c.white_balance) for c in r),
            notes={str(ch): tuple(str(n) for n in c.notes) for ch, c in zip(self.channels, r)},
            agreement=None if self.agreement is None else self.agreement.summary_record(),
            warnings=self.warnings(), verdict=self.verdict, requested=str(self.requested),
            selection=str(self.selection),
            compared=tuple(MethodComparison(str(n), _num(c.rms), _num(c.rms_fitted))
                           for n, c in self.compared.items()),
            exposures=None if self.exposures is None else self.exposures.summary())

    def to_dict(self) -> dict[str, Any]:
        """The CLI's JSON: per-channel lists in ``channels`` order (docs/cli.md): the
        :meth:`summary` with ``files`` after ``exposure_times``."""
        out: dict[str, Any] = {}
        for key, value in self.summary().to_dict().items():
            out[key] = value
            if key == "exposure_times":
                out["files"] = list(self.files)
        return out


def _estimate_all(brackets: Mapping[str, BracketData], method: str, progress: Any,
                  white_balance: bool, band: bool = True) -> tuple[ChannelResponse, ...]:
    """Every channel of a bracket by one method, side by side in threads; ``band=False``: a
    classic method's curve only (no jackknife band, no noise terms: the challenger's)."""
    names = tuple(brackets)
    done = [0.0] * len(names)
    lock = threading.Lock()

    def one(i: int) -> ChannelResponse:
        name = names[i]

        def sub(frac: float, msg: str) -> None:
            if progress is not None:
                with lock:
                    done[i] = frac
                    progress(sum(done) / len(names), f"channel {name}: {msg}")
        kw: dict[str, Any] = {"white_balance": True} if white_balance else {}
        if not band:
            kw["band"] = False
        return METHODS[method].run(brackets[name], sub, **kw)

    # the channels are independent: one thread each, up to the cores (the kernels release
    # the GIL); the first error of any channel is raised as it is. BLAS runs one thread
    # meanwhile: its own threads on the same cores made the channel threads no faster than
    # one after another (taipei, 2 cores: 1.49 s against 1.47 s; with one BLAS thread 1.00 s).
    # The limit is the process's while it holds (threadpoolctl cannot limit one thread).
    workers = max(1, min(len(names), os.cpu_count() or 1))
    if workers == 1:
        return tuple(one(i) for i in range(len(names)))
    with threadpool_limits(1, user_api="blas"), \
            ThreadPoolExecutor(workers, thread_name_prefix="response") as pool:
        return tuple(pool.map(one, range(len(names))))


def _choose(runs: dict[str, Agreement], requested: str, white_balance: bool = False
            ) -> tuple[str, str]:
    """The method kept and why: the one asked for, or with ``auto`` sec. 3.2 unless
    :data:`CHALLENGER`'s curve predicts the bracket clearly better
    (:data:`ccdcore.response.verdict.BETTER_FACTOR`, :data:`~ccdcore.response.verdict.BETTER_DN`).
    """
    from .verdict import BETTER_DN, BETTER_FACTOR

    def fig(name: str) -> str:
        return f"{METHODS[name].label} {runs[name].rms:.2f} DN"

    if requested != AUTO:
        return requested, f"asked for ({METHODS[requested].label})"
    if white_balance:
        return "tsin", ("white balance asked for: sec. 3.2 is the method that estimates the "
                        f"gains (against {fig(CHALLENGER)} at the exposures: "
                        f"{fig('tsin')})")
    t, c = runs["tsin"].rms, runs[CHALLENGER].rms
    text = (f"prediction RMS from a neighbour over the whole bracket (curves fitted to a "
            f"sample of its pixels): {fig('tsin')}, {fig(CHALLENGER)}")
    if np.isfinite(c) and (not np.isfinite(t) or (c * BETTER_FACTOR < t and t - c > BETTER_DN)):
        return CHALLENGER, f"{text}: the {CHALLENGER} curve predicts the bracket clearly better"
    return "tsin", f"{text}: sec. 3.2 kept"


def response_of(brackets: Mapping[str, BracketData], method: str = AUTO, *,
                progress: Progress | None = None, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                white_balance: bool = False, exposures: str = "auto") -> ResponseResult:
    """Every channel of a bracket by ``method`` (a key of :data:`METHODS`, or ``"auto"``: sec.
    3.2 unless Debevec & Malik's curve predicts the bracket clearly better); ``white_balance``
    estimates the gains a_k too (``tsin`` only). ``exposures`` (:data:`EXPOSURE_MODES`): the
    bracket's own exposures (:func:`ccdcore.response.exposures.estimate_exposures`) are
    estimated unless ``"listed"``, and taken when the images disagree with the listed ones
    (``"auto"``) or always (``"estimated"``). Every result is checked against
    :data:`CHALLENGER`'s curve on the same exposures and carries its verdict
    (:mod:`ccdcore.response.verdict`). ``progress`` (a :class:`ccdcore.progress.Progress`)
    follows the steps."""
    if method != AUTO and method not in METHODS:
        raise CcdError("response", f"unknown method {method!r}; choose one of "
                                   f"{', '.join((AUTO,) + tuple(METHODS))}")
    if exposures not in EXPOSURE_MODES:
        raise CcdError("response", f"unknown exposures {exposures!r}; choose one of "
                                   f"{', '.join(EXPOSURE_MODES)}")
    main = "tsin" if method == AUTO else method
    if white_balance and not METHODS[main].white_balance:
        raise CcdError("response", f"{METHODS[main].label} takes the exposures as exact: "
                                   "white balance is estimated by the tsin method")
    names = tuple(brackets)
    if not names:
        raise CcdError("response", "the bracket has no channel")
    first = brackets[names[0]]
    ex = None
    if exposures != "listed":
        if progress is not None:
            progress(0.0, "the bracket's own exposures (a quick curve, each pair's ratio)")
        ex = estimate_exposures(brackets)
        if exposures == "estimated" and ex.used != "estimated":
            ex = replace(ex, used="estimated", reason=f"asked for (--exposures estimated); "
                                                      f"{ex.reason}")
    use = dict(brackets)
    seeded = None if ex is None else \
        {ch: replace(d, t=np.asarray(ex.estimated, np.float64)) for ch, d in use.items()}
    if ex is not None and ex.used == "estimated":
        use = seeded
    order = [main] + ([CHALLENGER] if main != CHALLENGER else [])
    fits: dict[str, tuple[ChannelResponse, ...]] = {}
    runs: dict[str, Agreement] = {}
    for i, name in enumerate(order):
        span = (0.05, 0.9) if i == 0 else (0.9, 0.97)

        def sub(frac: float, msg: str, span=span, name=name) -> None:
            if progress is not None:
                progress(span[0] + (span[1] - span[0]) * frac,
                         msg if name == main else f"{name} (to compare): {msg}")
        # the challenger is a curve to compare: no band, no noise terms -- unless kept (auto).
        # The white-balance fit starts its gains at the bracket's own exposures whether or not
        # the listed ones are taken as wrong: from the listed times, on a real night bracket
        # whose short exposures run 25 % off, the joint fit ended its 30 passes at chi²/dof 10;
        # seeded, at 3.3
        wb_here = white_balance and name == main
        data = seeded if wb_here and seeded is not None else use
        fits[name] = _estimate_all(data, name, sub, wb_here, band=name == main)
        if progress is not None:
            progress(span[1], f"{name}: agreement, each image predicted from its neighbours "
                              "(sec. 4.2)")
        runs[name] = agreement(data, dict(zip(names, fits[name])))
    kept, why = _choose(runs, method, white_balance)
    if kept != main:
        # the challenger kept: its band and noise terms now
        fits[kept] = _estimate_all(use, kept, None, False)
    res = ResponseResult(kept, names, fits[kept], tuple(first.files), int(first.levels),
                         np.asarray(first.t, np.float64), int(bloom_radius),
                         agreement=runs[kept], exposures=ex, requested=method, selection=why,
                         compared={n: a for n, a in runs.items() if n != kept})
    return replace(res, verdict=response_verdict(res, res.compared))
