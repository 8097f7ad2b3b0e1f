"""Gaussian-process regression, one GP per output axis (thesis Chapter 3), with scikit-learn kernels.

Kernels, mean, the hyperparameters' thinned subset (``hyper_subset``) and the DTC posterior above
``max_exact`` samples: docs/learn.md "Models".
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy.linalg import cho_solve, cholesky, solve_triangular

from ..errors import QrInputError
from .base import Model, Scaler, check_xy, meta_of
from .linear import Ridge

KERNELS = ("se_ard", "matern32_ard", "matern52_ard", "rq")
MEANS = ("ridge", "dot", "zero")
_CHUNK = 4000


def make_kernel(name: str, d: int, mean: str = "ridge", noise_init: float = 0.1):
    from sklearn.gaussian_process.kernels import (RBF, ConstantKernel, DotProduct, Matern, RationalQuadratic,
                                                  WhiteKernel)

    ls, lb = np.ones(d), (1e-2, 1e3)
    base = {"se_ard": lambda: RBF(ls, lb), "matern32_ard": lambda: Matern(ls, lb, nu=1.5),
            "matern52_ard": lambda: Matern(ls, lb, nu=2.5),
            "rq": lambda: RationalQuadratic(1.0, 1.0, lb, (1e-2, 1e3))}[name]()
    signal = ConstantKernel(1.0, (1e-3, 1e2)) * base
    if mean == "dot":
        signal = signal + ConstantKernel(0.1, (1e-4, 1e2)) * DotProduct(1.0, (1e-2, 1e2))
    return signal + WhiteKernel(noise_init, (1e-6, 2.0))


def _lbfgsb(ftol: float):
    """scikit-learn's default optimiser (L-BFGS-B on the log hyperparameters) with a set tolerance.

    scikit-learn's ``ftol`` (2.2e-9) spends most evaluations moving the log
    likelihood by less than 0.1 %; ``ftol=1e-6`` stops there.
    """
    from scipy.optimize import minimize

    def optimizer(obj_func, initial_theta, bounds):
        res = minimize(obj_func, initial_theta, method="L-BFGS-B", jac=True, bounds=bounds, options={"ftol": ftol})
        return res.x, res.fun

    return optimizer


def _even(n: int, m: int) -> np.ndarray:
    """At most ``m`` indices evenly spaced over ``range(n)`` (time order kept)."""
    return np.arange(n) if n <= m else np.unique(np.linspace(0, n - 1, m).round().astype(int))


def _chol(K: np.ndarray) -> np.ndarray:
    scale = float(np.mean(np.diag(K)))
    for jitter in (0.0, 1e-10, 1e-8, 1e-6, 1e-4):
        try:
            return cholesky(K + jitter * scale * np.eye(len(K)), lower=True)
        except np.linalg.LinAlgError:
            continue
    raise np.linalg.LinAlgError("kernel matrix not positive definite even with jitter")


def _fast_gpr_class():
    """scikit-learn's ``GaussianProcessRegressor`` with a cheaper marginal-likelihood gradient.

    The gradient needs ``K^-1``; scikit-learn solves ``n`` right-hand sides with
    the Cholesky factor, we invert from it with LAPACK ``potri`` (about 3x less
    work).  Value and gradient are the same (``tests/learn/test_models.py``).
    """
    from scipy.linalg.lapack import dpotri
    from sklearn.gaussian_process import GaussianProcessRegressor

    class FastGPR(GaussianProcessRegressor):
        def log_marginal_likelihood(self, theta=None, eval_gradient=False, clone_kernel=True):
            if theta is None or not eval_gradient:
                return super().log_marginal_likelihood(theta, eval_gradient, clone_kernel)
            if clone_kernel:
                kernel = self.kernel_.clone_with_theta(theta)
            else:
                kernel = self.kernel_
                kernel.theta = theta
            K, K_grad = kernel(self.X_train_, eval_gradient=True)
            K[np.diag_indices_from(K)] += self.alpha
            try:
                L = cholesky(K, lower=True, check_finite=False)
            except np.linalg.LinAlgError:
                return -np.inf, np.zeros_like(theta)
            y = np.asarray(self.y_train_, dtype=float).reshape(len(K))
            a = cho_solve((L, True), y, check_finite=False)
            lml = -0.5 * y @ a - np.log(np.diag(L)).sum() - 0.5 * len(K) * np.log(2 * np.pi)
            Kinv, info = dpotri(L, lower=1)
            if info != 0:
                return -np.inf, np.zeros_like(theta)
            Kinv = np.tril(Kinv) + np.tril(Kinv, -1).T
            inner = np.outer(a, a) - Kinv
            return lml, 0.5 * np.einsum("ij,ijk->k", inner, K_grad)

    return FastGPR


class _Posterior:
    """Posterior of one standardised GP axis: exact, or DTC on inducing inputs ``Z``."""

    def __init__(self, kernel, X: np.ndarray, r: np.ndarray, inducing: np.ndarray | None):
        self.signal, self.noise = kernel.k1, float(kernel.k2.noise_level)
        if inducing is None:
            K = self.signal(X)
            K[np.diag_indices_from(K)] += self.noise
            self.L = _chol(K)
            self.Z, self.w, self.La = X, cho_solve((self.L, True), r), None
            return
        self.Z = X[inducing]
        Kmm = self.signal(self.Z)
        A, b = Kmm * self.noise, np.zeros(len(self.Z))
        for i in range(0, len(X), _CHUNK):
            Kmc = self.signal(self.Z, X[i:i + _CHUNK])
            A += Kmc @ Kmc.T
            b += Kmc @ r[i:i + _CHUNK]
        self.L = _chol(Kmm)
        self.La = _chol(A / self.noise)  # Kmm + Kmn Knm / s2
        self.w = cho_solve((self.La, True), b / self.noise)

    def predict(self, Xq: np.ndarray, return_std: bool):
        mean, std = np.empty(len(Xq)), np.empty(len(Xq))
        for i in range(0, len(Xq), _CHUNK):
            Ks = self.signal(Xq[i:i + _CHUNK], self.Z)
            mean[i:i + _CHUNK] = Ks @ self.w
            if return_std:
                var = self.signal.diag(Xq[i:i + _CHUNK]) + self.noise
                var -= np.sum(solve_triangular(self.L, Ks.T, lower=True) ** 2, axis=0)
                if self.La is not None:
                    var += np.sum(solve_triangular(self.La, Ks.T, lower=True) ** 2, axis=0)
                std[i:i + _CHUNK] = np.sqrt(np.maximum(var, 0.0))
        return mean, std


class GPR(Model):
    kind = "gpr"
    DEFAULTS = {
        "kernel": "se_ard",
        "mean": "ridge",  # ridge | dot | zero
        "restarts": 0,  # extra optimiser starts, drawn from the bounds (seeded)
        "hyper_subset": 300,
        "opt_ftol": 1e-6,  # L-BFGS-B relative tolerance on the marginal likelihood
        "max_exact": 3000,
        "inducing": 1000,
        "noise_init": 0.1,  # initial noise variance / residual variance
        "ridge_alpha": 1e-6,
        "seed": 0,
    }

    @classmethod
    def config(cls, cfg) -> dict:
        cfg = super().config(cfg)
        if cfg["kernel"] not in KERNELS:
            raise QrInputError(None, f"unknown GPR kernel '{cfg['kernel']}'", f"use one of {', '.join(KERNELS)}")
        if cfg["mean"] not in MEANS:
            raise QrInputError(None, f"unknown GPR mean '{cfg['mean']}'", f"use one of {', '.join(MEANS)}")
        return cfg

    def fit(self, X, y, val=None) -> "GPR":
        from sklearn.exceptions import ConvergenceWarning
        from threadpoolctl import threadpool_limits

        GaussianProcessRegressor = _fast_gpr_class()

        X, y = check_xy(X, y)
        c = self.cfg
        self.xs = Scaler.fit(X)
        Xs = self.xs(X)
        if c["mean"] == "ridge":
            self.W, self.b = Ridge({"alpha": c["ridge_alpha"]}).fit(X, y).collapse()
        else:
            self.W, self.b = np.zeros((y.shape[1], X.shape[1])), y.mean(axis=0)
        r = y - (X @ self.W.T + self.b)
        self.r_scale = np.where(r.std(axis=0) > 0, r.std(axis=0), 1.0)
        self.Xs, self.rs = Xs, r / self.r_scale
        sub = _even(len(Xs), int(c["hyper_subset"]))
        thetas = []
        with threadpool_limits(1), warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            for j in range(y.shape[1]):
                kernel = make_kernel(c["kernel"], X.shape[1], c["mean"], float(c["noise_init"]))
                gp = GaussianProcessRegressor(kernel, alpha=1e-8, n_restarts_optimizer=int(c["restarts"]),
                                              optimizer=_lbfgsb(float(c["opt_ftol"])), random_state=int(c["seed"] or 0))
                gp.fit(Xs[sub], self.rs[sub, j])
                thetas.append(gp.kernel_.theta)
        self.theta = np.array(thetas)
        self._posteriors()
        self.info = {"n_hyper": int(len(sub)), "n_train": int(len(Xs)), "sparse": self.sparse,
                     "inducing": int(len(self.post[0].Z)) if self.sparse else None,
                     "hyperparameters": self.hyperparameters(), "basis": self.basis()}
        return self

    def _posteriors(self) -> None:
        from threadpoolctl import threadpool_limits

        c = self.cfg
        self.sparse = len(self.Xs) > int(c["max_exact"])
        Z = _even(len(self.Xs), int(c["inducing"])) if self.sparse else None
        kernel = make_kernel(c["kernel"], self.Xs.shape[1], c["mean"], float(c["noise_init"]))
        with threadpool_limits(1):
            self.post = [_Posterior(kernel.clone_with_theta(th), self.Xs, self.rs[:, j], Z)
                         for j, th in enumerate(self.theta)]

    def predict(self, X, return_std: bool = False):
        """Mean (N, k); with ``return_std`` also the predictive std (noise included) in output units."""
        from threadpoolctl import threadpool_limits

        X, _ = check_xy(X)
        Xs = self.xs(X)
        with threadpool_limits(1):
            parts = [p.predict(Xs, return_std) for p in self.post]
        mean = X @ self.W.T + self.b + np.column_stack([m for m, _ in parts]) * self.r_scale
        if not return_std:
            return mean
        return mean, np.column_stack([s for _, s in parts]) * self.r_scale

    def _names(self) -> list[str]:
        return list(self.meta.get("feature_names") or [f"x{i + 1}" for i in range(self.Xs.shape[1])])

    def hyperparameters(self) -> list[list[dict]]:
        """Per axis: ``[{name, initial, trained}]`` in data units (thesis Table 3.1)."""
        c, names = self.cfg, self._names()
        out = []
        for j, p in enumerate(self.post):
            s2 = float(self.r_scale[j] ** 2)
            signal = p.signal.k1 if c["mean"] == "dot" else p.signal
            const, base = signal.k1, signal.k2
            rows = [{"name": "process variance sigma_f^2", "initial": s2, "trained": const.constant_value * s2}]
            if c["kernel"] == "rq":
                rows += [{"name": "length scale (standardised inputs)", "initial": 1.0,
                          "trained": float(base.length_scale)},
                         {"name": "rq alpha", "initial": 1.0, "trained": float(base.alpha)}]
            else:
                for i, ls in enumerate(np.atleast_1d(base.length_scale)):
                    sx = float(self.xs.std[i])
                    rows.append({"name": f"length scale ({names[i]})", "initial": sx, "trained": float(ls) * sx})
            if c["mean"] == "dot":
                lin = p.signal.k2
                rows += [{"name": "linear-term variance", "initial": 0.1 * s2,
                          "trained": lin.k1.constant_value * s2},
                         {"name": "linear-term sigma_0", "initial": 1.0, "trained": float(lin.k2.sigma_0)}]
            rows.append({"name": "noise variance sigma_n^2", "initial": float(c["noise_init"]) * s2,
                         "trained": p.noise * s2})
            out.append(rows)
        return out

    def basis(self) -> list[dict] | None:
        """Per axis: the linear mean's coefficients ``beta`` in input units (thesis Table 3.2)."""
        if self.cfg["mean"] != "ridge":
            return None
        names = self._names()
        return [{"beta_0 (intercept)": float(self.b[j]),
                 **{f"beta ({n})": float(w) for n, w in zip(names, self.W[j])}} for j in range(len(self.b))]

    def mlflow_flavor(self) -> tuple[str, object]:
        """scikit-learn's estimator API around this GP (its linear mean and per-axis posteriors, exact or
        sparse, are not one scikit-learn object); loading it needs qr installed."""
        return "sklearn", SklearnGPR(self)

    def _save_weights(self, path: Path) -> None:
        np.savez(path / "gpr.npz", Xs=self.Xs, rs=self.rs, theta=self.theta, x_mean=self.xs.mean,
                 x_std=self.xs.std, W=self.W, b=self.b, r_scale=self.r_scale)

    @classmethod
    def _load(cls, path: Path, doc: dict) -> "GPR":
        m = cls(doc["config"], meta_of(doc))
        with np.load(path / "gpr.npz", allow_pickle=False) as z:
            m.Xs, m.rs, m.theta, m.W, m.b, m.r_scale = (z[k] for k in ("Xs", "rs", "theta", "W", "b", "r_scale"))
            m.xs = Scaler(z["x_mean"], z["x_std"])
        m._posteriors()
        m.info = doc.get("info", {})
        return m


try:
    from sklearn.base import BaseEstimator, RegressorMixin
except ImportError:  # pragma: no cover
    BaseEstimator = RegressorMixin = object


class SklearnGPR(RegressorMixin, BaseEstimator):
    """A fitted :class:`GPR` behind scikit-learn's estimator API (``predict``), for ``mlflow.sklearn``."""

    def __init__(self, model=None):
        self.model = model

    def fit(self, X, y):
        raise NotImplementedError("fit with qr.models.fit('gpr', ...); this wraps a fitted GPR")

    def predict(self, X):
        return self.model.predict(np.asarray(X, dtype=float))
