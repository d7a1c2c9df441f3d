"""Eq. 17 of Tsin, Ramesh & Kanade (2001) for :mod:`ccdcore.response.tsin.estimator`: the noise
terms σ_s², σ_c1², σ_c2² from the pools' MAD sigmas by non-negative least squares, with their
errors.

Public objects
--------------
noise_fit(X, sig, n)
    ``(σ_s², σ_c1², σ_c2²)``, their standard errors and the reduced chi-square from the pools'
    regressors and MAD sigmas.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

__all__ = ["noise_fit"]

#: relative efficiency of the MAD for Gaussian data (weights of the eq. 17 fit)
_MAD_EFFICIENCY = 0.37


def noise_fit(X: NDArray, sig: NDArray, n: NDArray) -> tuple[NDArray, NDArray, float]:
    """Eq. 17 by non-negative least squares: ``(σ_s², σ_c1², σ_c2²)``, their standard errors and
    the reduced chi-square. Rows: per pool, the regressors ``X`` (mean over its pixels of
    Σ_i c_i² (g - b), Σ_i c_i², Σ_i c_i² g'²) and the measured MAD sigma ``sig``; weights from
    the MAD's sampling variance (2 σ⁴ / (0.37 n))."""
    y = sig ** 2
    sw = np.sqrt(_MAD_EFFICIENCY * n / 2.0) / np.maximum(y, 1e-30)
    A = X * sw[:, None]
    scale = np.maximum(np.abs(A).max(axis=0), 1e-30)
    theta_s, _ = nnls(A / scale, y * sw)
    theta = theta_s / scale
    dof = max(1, y.size - 3)
    chi2 = float(np.sum((A @ theta - y * sw) ** 2)) / dof
    try:
        cov = np.linalg.inv(A.T @ A) * max(chi2, 1.0)
        err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        err = np.full(3, np.nan)
    return theta, err, chi2
