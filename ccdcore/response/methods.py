"""One registry of response estimators, and the response of a session's bracket.

Every method returns, per channel, a :class:`ccdcore.response.tsin.ChannelResponse`: g on the
reported scale (:mod:`ccdcore.response.scale`) with its 1-sigma band, a_k and b_k, and the noise
terms of eq. 17:

``tsin``
    Tsin, Ramesh & Kanade (2001), sec. 3.2 (:func:`ccdcore.response.tsin.estimate`): the band
    is the sandwich estimate of the pools' spread, the noise terms come with the estimate.
``debevec``, ``robertson``, ``mitsunaga-nayar``
    The classic methods of :mod:`ccdcore.response.classic`. They return g only; here the band is
    a delete-one-block jackknife over 8 blocks of pixels (bands of rows of the frame, so that
    correlated neighbours stay together), and the noise terms are fitted to eq. 17 with their g
    on the same pools as ``tsin`` (:func:`ccdcore.response.tsin.noise_terms`).

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
from .agreement import Agreement, AgreementSummary, agreement, code_range
from .brackets import DEFAULT_BLOOM_RADIUS, DEFAULT_BORDER, BracketData, load_bracket
from .classic import debevec, mitsunaga_nayar, robertson
from .hdr_merge import ResponseModel
from .scale import reference_codes
from .tsin import ChannelResponse, TsinOptions, estimate, noise_terms

__all__ = ["METHODS", "Method", "ResponseResult", "ResponseSummary", "ResponseScaleSummary",
           "response_of", "session_response", "JACKKNIFE_BLOCKS"]

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


def _blocks(data: BracketData, n: int) -> NDArray[np.int64]:
    """Block of every pixel: bands of rows of the frame (or of the pixel order)."""
    P = data.n_pixels
    h, w = data.shape
    if data.pixels.size == P and h * w > 0:
        return np.minimum(data.pixels.astype(np.int64) * n // (h * w), n - 1)
    return np.arange(P, dtype=np.int64) * n // max(P, 1)


def _classic(name: str, fn: Callable[[BracketData], Any]
             ) -> Callable[[BracketData, Progress | None], ChannelResponse]:
    def run(data: BracketData, progress: Progress | None) -> ChannelResponse:
        fit = fn(data)
        g = np.asarray(fit.g, np.float64)
        L = g.size
        blocks = _blocks(data, JACKKNIFE_BLOCKS)
        reps = []
        for b in range(JACKKNIFE_BLOCKS):
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
            nz = noise_terms(data, g)
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
        verdict = ("no warning" if not self.warnings else
                   f"{len(self.warnings)} warning{'s' if len(self.warnings) > 1 else ''}: "
                   + "; ".join(self.warnings))
        out.append(Row("verdict", None, None, "", "whether the curves can be trusted: fits "
                                                  "converged, curves not collapsed, exposures "
                                                  "consistent with the images", verdict))
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

    def warnings(self) -> tuple[str, ...]:
        """Why the curves should not be trusted, in plain words (empty when nothing is wrong):
        a channel's fit that did not converge, a curve flat over a tenth of the readable codes
        (collapsed), and images that disagree with the exposures the result used."""
        out = []
        lo, hi = code_range(self.levels)
        for ch, r in zip(self.channels, self.responses):
            if not r.converged:
                out.append(f"channel {ch}: the fit stopped after {r.iterations} iterations "
                           "without converging; the curve may be wrong")
            g = np.asarray(r.g[lo:hi + 1])
            flat = np.diff(g) <= 1e-9 * max(float(g[-1] - g[0]), 1e-300)
            run = _longest_run(flat)
            if run >= 0.1 * (hi - lo):
                out.append(f"channel {ch}: g is flat over {run} codes of {lo}..{hi} (a "
                           "collapsed curve): it cannot tell those codes apart")
        ag = self.agreement
        if ag is not None and np.isfinite(ag.rms) and ag.rms > 1.5 * ag.rms_fitted + 1.0:
            out.append(f"the images disagree with the exposures used ({ag.rms:.1f} DN RMS with "
                       f"them, {ag.rms_fitted:.1f} DN with each pair's ratio fitted): the "
                       "exposure times are off"
                       + ("" if any(r.white_balance for r in self.responses) else
                          "; estimate the gains (--white-balance)"))
        return tuple(out)

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
            warnings=self.warnings())

    def to_dict(self) -> dict[str, Any]:
        """The CLI's JSON: per-channel lists in ``channels`` order (docs/cli.md): the
        :meth:`summary` with ``files`` after ``exposure_times``."""
        out: dict[str, Any] = {}
        for key, value in self.summary().to_dict().items():
            out[key] = value
            if key == "exposure_times":
                out["files"] = list(self.files)
        return out


def _longest_run(mask: NDArray[np.bool_]) -> int:
    """The longest run of True in a 1-D mask."""
    best = cur = 0
    for v in np.asarray(mask, bool).tolist():
        cur = cur + 1 if v else 0
        best = max(best, cur)
    return best


def response_of(brackets: Mapping[str, BracketData], method: str = "tsin", *,
                progress: Progress | None = None, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                white_balance: bool = False) -> ResponseResult:
    """Every channel of a bracket by ``method`` (a key of :data:`METHODS`); ``white_balance``
    estimates the gains a_k too (``tsin`` only). ``progress`` (a
    :class:`ccdcore.progress.Progress`) follows the channels, estimated side by side: its
    fraction is their mean."""
    if method not in METHODS:
        raise CcdError("response", f"unknown method {method!r}; choose one of "
                                   f"{', '.join(METHODS)}")
    if white_balance and not METHODS[method].white_balance:
        raise CcdError("response", f"{METHODS[method].label} takes the nominal exposure times "
                                   "as exact: white balance is estimated by the tsin method")
    names = tuple(brackets)
    if not names:
        raise CcdError("response", "the bracket has no channel")
    done = [0.0] * len(names)
    lock = threading.Lock()

    def one(i: int) -> ChannelResponse:
        name = names[i]

        def sub(frac: float, msg: str) -> None:
            if progress is not None:
                with lock:
                    done[i] = frac
                    progress(sum(done) / len(names), f"channel {name}: {msg}")
        kw = {"white_balance": True} if white_balance else {}
        return METHODS[method].run(brackets[name], sub, **kw)

    # the channels are independent: one thread each, up to the cores (the kernels release
    # the GIL); the first error of any channel is raised as it is. BLAS runs one thread
    # meanwhile: its own threads on the same cores made the channel threads no faster than
    # one after another (taipei, 2 cores: 1.49 s against 1.47 s; with one BLAS thread 1.00 s).
    # The limit is the process's while it holds (threadpoolctl cannot limit one thread).
    workers = max(1, min(len(names), os.cpu_count() or 1))
    if workers == 1:
        out = [one(i) for i in range(len(names))]
    else:
        with threadpool_limits(1, user_api="blas"), \
                ThreadPoolExecutor(workers, thread_name_prefix="response") as pool:
            out = list(pool.map(one, range(len(names))))
    first = brackets[names[0]]
    if progress is not None:
        progress(0.99, "agreement: each image predicted from its neighbours (sec. 4.2)")
    agree = agreement(brackets, dict(zip(names, out)))
    return ResponseResult(method, names, tuple(out), tuple(first.files), int(first.levels),
                          np.asarray(first.t, np.float64), int(bloom_radius), agreement=agree)


def session_response(session: Any, method: str = "tsin", *, stack: Any = None,
                     bloom_radius: int = DEFAULT_BLOOM_RADIUS, border: int = DEFAULT_BORDER,
                     progress: Progress | None = None, white_balance: bool = False
                     ) -> ResponseResult:
    """The response of a session's bracket ``stack`` (a path or an open session)."""
    from ..session import open_session

    if not hasattr(session, "bracket_stacks"):
        session = open_session(session)
    brackets = load_bracket(session, stack, bloom_radius=bloom_radius, border=border)
    return response_of(brackets, method, progress=progress, bloom_radius=bloom_radius,
                       white_balance=white_balance)
