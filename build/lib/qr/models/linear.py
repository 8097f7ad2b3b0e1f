"""Closed-form ridge regression: ``y = W x + b`` (the affine map a linear ANN collapses to, eq. 4.36).

Minimises ``mean ||y - W x - b||^2 / k + alpha ||W_s||^2`` with ``W_s`` the
weights on standardised inputs (the intercept is not penalised), solved as one
least-squares problem on the augmented system, so ``alpha = 0`` is ordinary
least squares.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import Model, Scaler, check_xy, meta_of


class Ridge(Model):
    kind = "linear"
    DEFAULTS = {"alpha": 1e-6}

    def fit(self, X, y, val=None) -> "Ridge":
        X, y = check_xy(X, y)
        xs = Scaler.fit(X)
        Xs = xs(X)
        y_mean = y.mean(axis=0)
        n, d = Xs.shape
        lam = float(self.cfg["alpha"])
        A = np.vstack([Xs, np.sqrt(n * lam) * np.eye(d)]) if lam > 0 else Xs
        B = np.vstack([y - y_mean, np.zeros((d, y.shape[1]))]) if lam > 0 else y - y_mean
        Ws = np.linalg.lstsq(A, B, rcond=None)[0]  # (d, k) on standardised inputs
        self.W = (Ws / xs.std[:, None]).T  # (k, d) in input units
        self.b = y_mean - self.W @ xs.mean
        return self

    def predict(self, X) -> np.ndarray:
        X, _ = check_xy(X)
        return X @ self.W.T + self.b

    def collapse(self) -> tuple[np.ndarray, np.ndarray]:
        """``(W, b)`` in input units: ``y = W x + b``."""
        return self.W.copy(), self.b.copy()

    def mlflow_flavor(self) -> tuple[str, object]:
        """scikit-learn's ``LinearRegression`` holding ``W`` and ``b`` (no qr needed to load it)."""
        from sklearn.linear_model import LinearRegression

        lin = LinearRegression()
        lin.coef_, lin.intercept_, lin.n_features_in_ = self.W.copy(), self.b.copy(), self.W.shape[1]
        if self.meta.get("feature_names"):
            lin.feature_names_in_ = np.asarray(self.meta["feature_names"], dtype=object)
        return "sklearn", lin

    def _save_weights(self, path: Path) -> None:
        np.savez(path / "weights.npz", W=self.W, b=self.b)

    @classmethod
    def _load(cls, path: Path, doc: dict) -> "Ridge":
        m = cls(doc["config"], meta_of(doc))
        with np.load(path / "weights.npz", allow_pickle=False) as z:
            m.W, m.b = z["W"], z["b"]
        m.info = doc.get("info", {})
        return m
