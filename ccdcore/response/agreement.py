"""How well a response explains its own bracket: the prediction agreement of Tsin, Ramesh &
Kanade (2001), sec. 4.2.

The paper judges response curves on real data by predicting each image of the bracket from the
others: an image ``j`` gives every pixel's radiance through the curve and the exposure,
``E = (g(z_j) - b_j) / a_j`` (eq. 8), and image ``k`` is then expected to read
``ẑ_k = f(a_k E + b_k)`` with ``f = g^-1`` (eq. 5). The agreement is the RMS of ``ẑ_k - z_k`` in
digital numbers over the pixels whose codes both images can read. A curve of the wrong shape
mispredicts at once, whatever its scale; a curve that collapses (flat over a range of codes)
mispredicts grossly, since f then maps a range of signals onto one code.

Three figures per channel, in DN:

``rms`` (the result's own exposures)
    Each image predicted from its neighbours (``k = j ± 1``, both directions) with the ratio
    the result itself uses: ``a_k / a_j`` with ``a`` the nominal times for methods that take
    them as exact, or the gains and offsets a result estimated (white balance).
``rms_fitted``
    The same with the ratio of each pair fitted to the pair (one ratio per pair, both
    directions, least squares in DN). The difference from ``rms`` is what exposure errors cost;
    what remains is the curve's shape.
``rms_blend``
    Each image predicted from the blend of all the others (eq. 9's radiance with eq. 18's
    weights, σ taken as g', over the others' readable codes; an even sample of at most
    :data:`MAX_PIXELS` pixels), with the result's exposures.

Every pair's figures are kept (``PairAgreement``), so one bad frame (a moved camera, a wrong
exposure in the manifest) shows as the pairs it takes part in.

Public objects
--------------
CODE_RANGE
    The codes counted by default: 10 .. 245 of 8 bits (scaled for other depths), away from the
    toe and the knee where cameras clip and compress.
PairAgreement, ChannelAgreement, Agreement
    The figures per pair of neighbours, per channel and pooled over the channels.
PairAgreementSummary, ChannelAgreementSummary, AgreementSummary
    Their records as ``calibration.json`` stores them (``response.agreement``), with ``rows()``:
    ``PairAgreement.summary()``, ``ChannelAgreement.summary()``,
    ``Agreement.summary_record()`` (``Agreement.summary()`` is the one-line text).
channel_agreement(data, g, a, b)
    One channel of a bracket against one curve.
agreement(brackets, responses)
    Every channel; ``responses`` maps a channel to anything with ``g``, ``a`` and ``b``.
inverse(g)
    ``f = g^-1`` as a function of continuous signals (the codes as real numbers).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar

from ..common import float_or_nan
from ..records import Record, Row
from .brackets import BracketData

__all__ = ["PairMoments", "pair_moments", "moments_of_codes", "moments_by_block", "moments_of_counts", "fit_ratio",
           "CODE_RANGE", "PairAgreement", "ChannelAgreement", "Agreement",
           "PairAgreementSummary", "ChannelAgreementSummary", "AgreementSummary", "agreement",
           "channel_agreement", "code_range", "inverse", "MAX_PIXELS"]

#: codes counted by default, for 8 bits (scaled to other bit depths by :func:`code_range`)
CODE_RANGE = (10, 245)
#: most pixels per channel the blend figure is computed from (an even sample beyond; the pair
#: figures count every pixel)
MAX_PIXELS = 100_000
#: a fitted ratio is searched within this factor of the result's own ratio
RATIO_SPAN = 4.0


def code_range(levels: int) -> tuple[int, int]:
    """The readable codes of a ``levels``-code camera: 10 .. 245 scaled from 8 bits."""
    top = int(levels) - 1
    return int(round(CODE_RANGE[0] * top / 255.0)), int(round(CODE_RANGE[1] * top / 255.0))


def inverse(g: ArrayLike) -> "callable":
    """``f = g^-1`` on continuous signals: the code (a real number) whose g is the signal.

    g is non-decreasing; flat runs are collapsed to their middle code, so that a flat curve
    maps its value to the middle of the run (a collapsed curve then mispredicts visibly).
    Signals beyond g's range map to the end codes."""
    g = np.asarray(g, np.float64)
    codes = np.arange(g.size, dtype=np.float64)
    # unique values of g, each at the mean code of its run
    vals, inv = np.unique(g, return_inverse=True)
    mean_code = np.bincount(inv, weights=codes) / np.bincount(inv)

    def f(signal: ArrayLike) -> NDArray[np.float64]:
        return np.interp(signal, vals, mean_code)
    return f


#: the pooled figures as their rows label them, with what each means
_LABELS = {"rms": ("RMS, own ratios",
                   "each image predicted from a neighbour with the result's exposure ratio"),
           "rms_fitted": ("RMS, fitted ratios",
                          "the same with each pair's ratio fitted: what remains is the "
                          "curve's shape"),
           "rms_blend": ("RMS from the blend of the others",
                         "each image predicted from the blend of all the others (eq. 9)")}


def _rms_rows(s: Any) -> list[Row]:
    return [Row(label, getattr(s, key), None, "DN", meaning)
            for key, (label, meaning) in _LABELS.items() if hasattr(s, key)]


@dataclass(frozen=True)
class PairAgreementSummary(Record):
    """A :class:`PairAgreement` as ``calibration.json`` stores it
    (``response.agreement.channels[i].pairs[p]``); ``None`` for a figure that is not finite."""

    #: the images ``j`` and ``k = j + 1`` (increasing exposure, from 0) and the predictions
    #: counted (both directions)
    j: int
    k: int
    n: int
    #: RMS of ẑ − z in DN with the result's ratio and with the pair's fitted ratio
    rms: float | None
    rms_fitted: float | None
    #: the result's exposure ratio a_k / a_j and the pair's fitted ratio
    ratio: float | None
    ratio_fitted: float | None

    def rows(self) -> tuple[Row, ...]:
        """The two RMS figures (DN) and the two ratios."""
        return (*_rms_rows(self),
                Row("ratio", self.ratio, None, "", "the result's exposure ratio a_k / a_j"),
                Row("fitted ratio", self.ratio_fitted, None, "",
                    "the exposure ratio that predicts the pair best"))


@dataclass(frozen=True)
class PairAgreement:
    """Neighbouring images ``j`` and ``k = j + 1`` (increasing exposure) predicted from each
    other: RMS in DN with the result's ratio and with the pair's fitted ratio."""

    j: int
    k: int
    n: int                  # predictions counted (both directions)
    rms: float
    rms_fitted: float
    ratio: float            # the result's a_k / a_j
    ratio_fitted: float

    def summary(self) -> PairAgreementSummary:
        """The record ``calibration.json`` stores (non-finite figures as ``None``)."""
        return PairAgreementSummary(int(self.j), int(self.k), int(self.n), _num(self.rms),
                                    _num(self.rms_fitted), _num(self.ratio),
                                    _num(self.ratio_fitted))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


@dataclass(frozen=True)
class ChannelAgreementSummary(Record):
    """A :class:`ChannelAgreement` as ``calibration.json`` stores it
    (``response.agreement.channels[i]``): the pooled sums are left out."""

    #: the channel's name
    channel: str
    #: RMS in DN over every prediction: own ratios, fitted ratios, from the blend of the others
    #: (``None``: nothing to predict)
    rms: float | None
    rms_fitted: float | None
    rms_blend: float | None
    #: predictions counted by the pairs and by the blend
    n: int
    n_blend: int
    #: every pair of neighbouring images
    pairs: tuple[PairAgreementSummary, ...]

    def rows(self) -> tuple[Row, ...]:
        """The three RMS figures (DN) and the predictions counted."""
        return (*_rms_rows(self),
                Row("predictions", self.n, None, "",
                    "pixels predicted from a neighbour, both directions"))


@dataclass(frozen=True)
class ChannelAgreement:
    """One channel: the pairs, and the figures pooled over them (RMS over every prediction)."""

    channel: str
    pairs: tuple[PairAgreement, ...]
    rms: float
    rms_fitted: float
    rms_blend: float
    n: int
    n_blend: int
    sse: float = 0.0         # the pooled sums behind the RMS, for pooling over channels
    sse_fitted: float = 0.0
    sse_blend: float = 0.0

    def worst_pair(self) -> PairAgreement | None:
        live = [p for p in self.pairs if p.n > 0 and math.isfinite(p.rms)]
        return max(live, key=lambda p: p.rms) if live else None

    def summary(self) -> ChannelAgreementSummary:
        """The record ``calibration.json`` stores (non-finite figures as ``None``)."""
        return ChannelAgreementSummary(str(self.channel), _num(self.rms),
                                       _num(self.rms_fitted), _num(self.rms_blend),
                                       int(self.n), int(self.n_blend),
                                       tuple(p.summary() for p in self.pairs))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


def _line(rms: float | None, rms_fitted: float | None, rms_blend: float | None,
          codes: tuple[int, int]) -> str:
    """The pooled figures in one line (``nan`` for a figure that is not there)."""
    f = float_or_nan
    return (f"predicts its images within {f(rms):.2f} DN RMS from a neighbour "
            f"({f(rms_fitted):.2f} DN with each pair's ratio fitted, "
            f"{f(rms_blend):.2f} DN from the blend of the others; codes "
            f"{codes[0]}..{codes[1]})")


@dataclass(frozen=True)
class AgreementSummary(Record):
    """An :class:`Agreement` as ``calibration.json`` stores it (``response.agreement``): the
    prediction agreement of Tsin, Ramesh & Kanade (2001), sec. 4.2."""

    #: the codes counted (both images of a pair must read them)
    code_range: tuple[int, int]
    #: RMS in DN pooled over the channels: own ratios, fitted ratios, from the blend of the
    #: others (``None``: nothing to predict)
    rms: float | None
    rms_fitted: float | None
    rms_blend: float | None
    #: every channel's figures and pairs
    channels: tuple[ChannelAgreementSummary, ...]

    def __getitem__(self, channel: str) -> ChannelAgreementSummary:
        for c in self.channels:
            if c.channel == channel:
                return c
        raise KeyError(channel)

    def line(self) -> str:
        """One line: the pooled figures (as :meth:`Agreement.summary`)."""
        return _line(self.rms, self.rms_fitted, self.rms_blend, self.code_range)

    def rows(self) -> tuple[Row, ...]:
        """The three pooled RMS figures (DN) and the predictions counted."""
        return (*_rms_rows(self),
                Row("predictions", sum(c.n for c in self.channels), None, "",
                    f"pixels predicted from a neighbour, both directions, codes "
                    f"{self.code_range[0]}..{self.code_range[1]}"))


@dataclass(frozen=True)
class Agreement:
    """Every channel's agreement and the figures pooled over the channels (DN)."""

    channels: tuple[ChannelAgreement, ...]
    code_range: tuple[int, int]
    rms: float
    rms_fitted: float
    rms_blend: float

    def __getitem__(self, channel: str) -> ChannelAgreement:
        for c in self.channels:
            if c.channel == channel:
                return c
        raise KeyError(channel)

    def summary_record(self) -> AgreementSummary:
        """The record ``calibration.json`` stores (non-finite figures as ``None``).
        (:meth:`summary` is the one-line text the CLI prints.)"""
        return AgreementSummary((int(self.code_range[0]), int(self.code_range[1])),
                                _num(self.rms), _num(self.rms_fitted), _num(self.rms_blend),
                                tuple(c.summary() for c in self.channels))

    def to_dict(self) -> dict[str, Any]:
        return self.summary_record().to_dict()

    def summary(self) -> str:
        """One line: the pooled figures."""
        return _line(_num(self.rms), _num(self.rms_fitted), _num(self.rms_blend),
                     self.code_range)


def _num(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def _sample_columns(P: int, max_pixels: int) -> NDArray[np.int64] | slice:
    if P <= max_pixels:
        return slice(None)
    keep = np.linspace(0, P - 1, max_pixels).astype(np.int64)      # sorted: drop repeats
    return keep[np.r_[True, keep[1:] != keep[:-1]]]


def _rms(sse: float, n: int) -> float:
    return math.sqrt(sse / n) if n > 0 else float("nan")


@dataclass(frozen=True, eq=False)
class PairMoments:
    """The codes of neighbouring images ``j`` and ``k = j + 1`` where both are readable, as
    sums per code: every sum of :func:`fit_ratio` over pixels is a sum over codes (a prediction
    depends on the pixel's pair of codes only). ``src_j``: per code u of image j, the count,
    sum and sum of squares of image k's codes (``src_k`` the other way); ``n`` the pixels."""

    n: int
    src_j: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
    src_k: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]

    def __add__(self, other: "PairMoments") -> "PairMoments":
        return PairMoments(self.n + other.n,
                           tuple(x + y for x, y in zip(self.src_j, other.src_j)),
                           tuple(x + y for x, y in zip(self.src_k, other.src_k)))

    def __sub__(self, other: "PairMoments") -> "PairMoments":
        return PairMoments(self.n - other.n,
                           tuple(x - y for x, y in zip(self.src_j, other.src_j)),
                           tuple(x - y for x, y in zip(self.src_k, other.src_k)))


def moments_of_codes(zj: ArrayLike, zk: ArrayLike, levels: int, codes: tuple[int, int]
                     ) -> PairMoments:
    """:class:`PairMoments` of two images' codes at the same pixels (both readable: within
    ``codes``)."""
    zj, zk = np.asarray(zj), np.asarray(zk)
    lo, hi = codes
    m = (zj >= lo) & (zj <= hi) & (zk >= lo) & (zk <= hi)
    xj, xk = zj[m].astype(np.int64), zk[m].astype(np.int64)
    out = []
    for src, dst in ((xj, xk), (xk, xj)):
        w = dst.astype(np.float64)
        out.append((np.bincount(src, minlength=levels).astype(np.float64),
                    np.bincount(src, weights=w, minlength=levels),
                    np.bincount(src, weights=w * w, minlength=levels)))
    return PairMoments(int(xj.size), out[0], out[1])


def moments_by_block(zj: ArrayLike, zk: ArrayLike, levels: int, codes: tuple[int, int],
                     block: ArrayLike, blocks: int) -> list[PairMoments]:
    """:func:`moments_of_codes` of every block of pixels (``block``: each pixel's block, in
    ``0 .. blocks - 1``), in one pass: their sum is the moments of all the pixels."""
    zj, zk, block = np.asarray(zj), np.asarray(zk), np.asarray(block)
    lo, hi = codes
    L = int(levels)
    m = (zj >= lo) & (zj <= hi) & (zk >= lo) & (zk <= hi)
    xj, xk, bk = zj[m].astype(np.int64), zk[m].astype(np.int64), block[m].astype(np.int64)
    n_blk = np.bincount(bk, minlength=blocks)
    sums = []
    for src, dst in ((xj, xk), (xk, xj)):
        w = dst.astype(np.float64)
        idx = bk * L + src
        sums.append([np.bincount(idx, weights=x, minlength=blocks * L).reshape(blocks, L)
                     for x in (None, w, w * w)])
    return [PairMoments(int(n_blk[b]), tuple(np.asarray(a[b], np.float64) for a in sums[0]),
                        tuple(np.asarray(a[b], np.float64) for a in sums[1]))
            for b in range(blocks)]


def moments_of_counts(counts: NDArray, codes: tuple[int, int]) -> PairMoments:
    """:class:`PairMoments` of a comparagram: ``counts[u, v]`` pixels read u in image j and v
    in image k (``BracketData.pair_counts``)."""
    C = np.asarray(counts, np.float64)
    L = C.shape[0]
    lo, hi = codes
    inside = np.zeros(L, bool)
    inside[lo:hi + 1] = True
    C = C * inside[:, None] * inside[None, :]
    v = np.arange(L, dtype=np.float64)
    return PairMoments(int(round(C.sum())), (C.sum(axis=1), C @ v, C @ (v * v)),
                       (C.sum(axis=0), C.T @ v, C.T @ (v * v)))


def pair_moments(data: BracketData, codes: tuple[int, int] | None = None,
                 columns: ArrayLike | None = None) -> tuple[PairMoments, ...]:
    """Every neighbour pair's :class:`PairMoments` of a channel: from its comparagrams over the
    whole frame when the bracket carries them (``pair_counts``), else from its pixels
    (``columns``: only those)."""
    rng = code_range(data.levels) if codes is None else tuple(codes)
    counts = getattr(data, "pair_counts", None)
    if counts is not None and columns is None:
        return tuple(moments_of_counts(c, rng) for c in counts)
    z = np.asarray(data.z)
    if columns is not None:
        z = z[:, np.asarray(columns)]
    return tuple(moments_of_codes(z[j], z[j + 1], int(data.levels), rng)
                 for j in range(data.n_images - 1))


def fit_ratio(mom: PairMoments, f: Any, sig_j: NDArray, sig_k: NDArray, b_j: float,
              b_k: float, r0: float) -> tuple[float, float, float]:
    """The pair's squared prediction errors (both directions, DN²) at the ratio ``r0`` and at
    the ratio that predicts it best, and that ratio: ``(sse at r0, sse fitted, fitted ratio)``.
    ``f`` is the inverse of the curve (:func:`inverse`), ``sig_j``, ``sig_k`` the signal of
    every code in each image (g − b). The ratio is searched within :data:`RATIO_SPAN` of
    ``r0``."""
    (n_j, s1_j, s2_j), (n_k, s1_k, s2_k) = mom.src_j, mom.src_k
    s2 = float(s2_j.sum() + s2_k.sum())

    def cost(lr: float) -> float:
        r = math.exp(lr)
        pk = f(r * sig_j + b_k)                # image k from each code of image j
        pj = f(sig_k / r + b_j)                # image j from each code of image k
        return float(n_j @ (pk * pk) - 2.0 * (s1_j @ pk)
                     + n_k @ (pj * pj) - 2.0 * (s1_k @ pj) + s2)

    c0 = max(cost(math.log(r0)), 0.0)
    span = math.log(RATIO_SPAN)
    opt = minimize_scalar(cost, bounds=(math.log(r0) - span, math.log(r0) + span),
                          method="bounded", options={"xatol": 1e-6})
    c1, lr = max(float(opt.fun), 0.0), float(opt.x)
    if not c1 < c0:
        c1, lr = c0, math.log(r0)
    return c0, c1, math.exp(lr)


def channel_agreement(data: BracketData, g: ArrayLike, a: ArrayLike | None = None,
                      b: ArrayLike | None = None, *, codes: tuple[int, int] | None = None,
                      max_pixels: int = MAX_PIXELS, channel: str | None = None,
                      pairs_of: "tuple[PairMoments, ...] | None" = None) -> ChannelAgreement:
    """The agreement of one channel of a bracket with the curve ``g`` (every code) and the
    exposures ``a``, offsets ``b`` (nominal times and 0 when not given).

    ``pairs_of``: the pairs' code moments (:func:`pair_moments`) to count instead of the
    bracket's own pixels, e.g. those of pixels the curve was not fitted to."""
    g = np.asarray(g, np.float64)
    N = data.n_images
    a = np.asarray(data.t if a is None else a, np.float64)
    b = np.zeros(N) if b is None else np.asarray(b, np.float64)
    lo, hi = code_range(data.levels) if codes is None else codes
    zall = np.asarray(data.z)
    f = inverse(g)
    pairs = []
    sse = sse_f = 0.0
    n_all = 0
    moments = pair_moments(data, (lo, hi)) if pairs_of is None else pairs_of
    for j in range(N - 1):
        k = j + 1
        r0 = float(a[k] / a[j])
        mom = moments[j]
        n = int(mom.n)
        if n == 0:
            pairs.append(PairAgreement(j, k, 0, float("nan"), float("nan"), r0, float("nan")))
            continue
        c0, c1, ratio = fit_ratio(mom, f, g - b[j], g - b[k], b[j], b[k], r0)
        pairs.append(PairAgreement(j, k, 2 * n, _rms(c0, 2 * n), _rms(c1, 2 * n), r0, ratio))
        sse += c0
        sse_f += c1
        n_all += 2 * n
    cols = _sample_columns(data.n_pixels, max_pixels)
    z = zall[:, cols]
    ok = (z >= lo) & (z <= hi)
    gz = g[np.clip(z, 0, g.size - 1)]
    # each image from the blend of the others: eq. 9 with the weights of eq. 18,
    # w_i ∝ a_i / σ(a_i, z_i), σ taken as g'(z_i) (the output noise, the same for every image),
    # over the others' readable codes
    slope = np.maximum(np.gradient(g), 1e-12 * max(float(g[-1] - g[0]), 1e-300))
    w = np.where(ok, a[:, None] / slope[np.clip(z, 0, g.size - 1)], 0.0)
    lin = w * (gz - b[:, None]) / a[:, None]
    tot, wsum = lin.sum(axis=0), w.sum(axis=0)
    sse_b = 0.0
    n_b = 0
    for k in range(N):
        others = wsum - w[k]
        m = ok[k] & (others > 0)
        if not m.any():
            continue
        E = (tot[m] - lin[k, m]) / others[m]
        e = f(a[k] * E + b[k]) - z[k, m]
        sse_b += float(e @ e)
        n_b += int(m.sum())
    return ChannelAgreement(channel or data.channel, tuple(pairs), _rms(sse, n_all),
                            _rms(sse_f, n_all),
                            _rms(sse_b, n_b), n_all, n_b, sse, sse_f, sse_b)


def agreement(brackets: Mapping[str, BracketData], responses: Mapping[str, Any], *,
              codes: tuple[int, int] | None = None, max_pixels: int = MAX_PIXELS,
              pairs_of: Mapping[str, tuple[PairMoments, ...]] | None = None) -> Agreement:
    """The agreement of every channel of ``brackets`` with ``responses[channel]`` (anything
    with ``g``, ``a``, ``b``: a :class:`ccdcore.response.tsin.estimator.ChannelResponse`, or a
    mapping with those keys), pooled over the channels. ``pairs_of``: per channel, the pairs' code
    moments to count (:func:`channel_agreement`)."""
    out = []
    for name, data in brackets.items():
        r = responses[name]
        get = (lambda key: r[key]) if isinstance(r, Mapping) else (lambda key: getattr(r, key))
        out.append(channel_agreement(data, get("g"), get("a"), get("b"), codes=codes,
                                     max_pixels=max_pixels, channel=name,
                                     pairs_of=None if pairs_of is None else pairs_of[name]))
    first = next(iter(brackets.values()))
    rng = code_range(first.levels) if codes is None else tuple(codes)
    n = sum(c.n for c in out)
    nb = sum(c.n_blend for c in out)
    return Agreement(tuple(out), (int(rng[0]), int(rng[1])), _rms(sum(c.sse for c in out), n),
                     _rms(sum(c.sse_fitted for c in out), n),
                     _rms(sum(c.sse_blend for c in out), nb))
