"""Multilayer perceptron on standardised inputs and outputs (thesis Chapter 4), in torch.

Full-batch L-BFGS (or Adam) on ``MSE + weight_decay Σ‖W‖²`` with early stopping on the validation block;
why this stands in for the thesis's Bayesian regularisation (``trainbr``): docs/learn.md "Models".
Seeded and deterministic: a private RNG stream, no shuffling, one thread, float64.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from ..errors import QrInputError
from ..parallel import torch_one_thread
from .base import Model, Scaler, check_xy, meta_of

ACTIVATIONS = ("linear", "relu", "tanh")


_READY = False


def _torch():
    """torch on one thread; the first call pays torch.optim's one-time lazy imports (~2 s), not a fit."""
    global _READY
    import torch

    if not _READY:
        torch_one_thread(torch)
        torch.optim.LBFGS([torch.zeros(1, requires_grad=True)])
        _READY = True
    return torch


def build_net(d_in: int, d_out: int, layers: int, neurons: int, activation: str):
    torch = _torch()
    nn = torch.nn
    act = {"linear": nn.Identity, "relu": nn.ReLU, "tanh": nn.Tanh}[activation]
    mods, d = [], d_in
    for _ in range(layers):
        mods += [nn.Linear(d, neurons), act()]
        d = neurons
    mods.append(nn.Linear(d, d_out))
    return nn.Sequential(*mods).double()


class ANN(Model):
    kind = "ann"
    DEFAULTS = {
        "layers": 2,
        "neurons": 3,
        "activation": "linear",
        "weight_decay": 1e-4,
        "optimizer": "lbfgs",  # lbfgs | adam
        "lr": None,  # default 1.0 for L-BFGS, 0.01 for Adam
        "max_iter": 3000,
        "check_every": 1,
        "patience": 30,
        "seed": 0,
    }

    @staticmethod
    def prepare() -> None:
        _torch()

    @classmethod
    def config(cls, cfg) -> dict:
        cfg = super().config(cfg)
        if cfg["activation"] not in ACTIVATIONS:
            raise QrInputError(None, f"unknown activation '{cfg['activation']}'",
                               f"use one of {', '.join(ACTIVATIONS)}")
        if cfg["optimizer"] not in ("lbfgs", "adam"):
            raise QrInputError(None, f"unknown optimizer '{cfg['optimizer']}'", "use lbfgs or adam")
        if int(cfg["layers"]) < 0 or int(cfg["neurons"]) < 1:
            raise QrInputError(None, f"layers={cfg['layers']} neurons={cfg['neurons']}",
                               "give layers >= 0 and neurons >= 1")
        return cfg

    def fit(self, X, y, val=None) -> "ANN":
        torch = _torch()
        X, y = check_xy(X, y)
        c = self.cfg
        self.xs, self.ys = Scaler.fit(X), Scaler.fit(y)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(c["seed"] or 0))
            self.net = build_net(X.shape[1], y.shape[1], int(c["layers"]), int(c["neurons"]), c["activation"])
        Xt = torch.from_numpy(self.xs(X))
        yt = torch.from_numpy(self.ys(y))
        Xv = yv = None
        if val is not None and len(val[0]) > 0:
            Xv = torch.from_numpy(self.xs(np.asarray(val[0], dtype=float)))
            yv = torch.from_numpy(self.ys(np.asarray(val[1], dtype=float).reshape(len(val[0]), -1)))
        self.info = self._train(Xt, yt, Xv, yv)
        return self

    def _train(self, Xt, yt, Xv, yv) -> dict:
        torch = _torch()
        c, net = self.cfg, self.net
        weights = [m.weight for m in net if isinstance(m, torch.nn.Linear)]
        wd = float(c["weight_decay"])

        def objective():
            loss = torch.mean((net(Xt) - yt) ** 2)
            return loss + wd * sum((w**2).sum() for w in weights) if wd > 0 else loss

        every = int(c["check_every"])
        step = _stepper(torch, c, net, objective, every)
        best, best_state, best_it, bad, it, stop = np.inf, None, 0, 0, 0, "max_iter"
        last = np.inf
        while it < int(c["max_iter"]):
            step()
            it += every
            with torch.no_grad():
                loss = float(objective())
                if not np.isfinite(loss):
                    raise RuntimeError("ANN training diverged (non-finite loss); lower model.lr")
                converged, last = abs(last - loss) <= 1e-12 * max(1.0, abs(loss)), loss
                if Xv is not None:
                    v = float(torch.mean((net(Xv) - yv) ** 2))
                    if v < best * (1 - 1e-6):
                        best, best_state, best_it, bad = v, copy.deepcopy(net.state_dict()), it, 0
                    else:
                        bad += 1
                        if bad >= int(c["patience"]):
                            stop = "early_stopping"
                            break
            if converged:
                stop = "converged"
                break
        if best_state is not None:
            net.load_state_dict(best_state)
        else:
            best_it = it
        return {"iterations": it, "best_iteration": best_it, "stopped": stop, "train_objective": last,
                "val_mse_standardised": None if Xv is None else best}

    def predict(self, X) -> np.ndarray:
        torch = _torch()
        X, _ = check_xy(X)
        with torch.no_grad():
            out = self.net(torch.from_numpy(self.xs(X))).numpy()
        return self.ys.inverse(out)

    def collapse(self) -> tuple[np.ndarray, np.ndarray]:
        """``(W, b)`` in input units of a network with linear activations (thesis eq. 4.36).

        ``W = W_L ... W_1 W_0`` and ``b = W_L ... W_1 b_0 + ... + b_L`` on the
        standardised scale, then mapped back through the input and output scalers.
        """
        if self.cfg["activation"] != "linear" and int(self.cfg["layers"]) > 0:
            raise QrInputError(None, f"a {self.cfg['activation']} network is not an affine map",
                               "collapse() needs activation=linear")
        torch = _torch()
        Ws, bs = None, None
        for m in self.net:
            if isinstance(m, torch.nn.Linear):
                A, a = m.weight.detach().numpy(), m.bias.detach().numpy()
                Ws, bs = (A, a) if Ws is None else (A @ Ws, A @ bs + a)
        W = self.ys.std[:, None] * Ws / self.xs.std[None, :]
        b = self.ys.std * (bs - Ws @ (self.xs.mean / self.xs.std)) + self.ys.mean
        return W, b

    def mlflow_flavor(self) -> tuple[str, object]:
        """A self-contained torch module: input scaling, the net, output scaling (as two affine layers)."""
        torch = _torch()

        def affine(scale, shift):
            layer = torch.nn.Linear(len(scale), len(scale)).double()
            with torch.no_grad():
                layer.weight.copy_(torch.diag(torch.from_numpy(np.asarray(scale, dtype=float))))
                layer.bias.copy_(torch.from_numpy(np.asarray(shift, dtype=float)))
            return layer

        module = torch.nn.Sequential(affine(1 / self.xs.std, -self.xs.mean / self.xs.std),
                                     *copy.deepcopy(self.net), affine(self.ys.std, self.ys.mean))
        return "pytorch", module.eval()

    def _save_weights(self, path: Path) -> None:
        torch = _torch()
        state = {"state_dict": self.net.state_dict()}
        for name, a in (("x_mean", self.xs.mean), ("x_std", self.xs.std), ("y_mean", self.ys.mean),
                        ("y_std", self.ys.std)):
            state[name] = torch.from_numpy(np.asarray(a, dtype=float))
        torch.save(state, path / "weights.pt")

    @classmethod
    def _load(cls, path: Path, doc: dict) -> "ANN":
        torch = _torch()
        m = cls(doc["config"], meta_of(doc))
        state = torch.load(path / "weights.pt", weights_only=True)
        m.xs = Scaler(state["x_mean"].numpy(), state["x_std"].numpy())
        m.ys = Scaler(state["y_mean"].numpy(), state["y_std"].numpy())
        c = m.cfg
        m.net = build_net(len(m.xs.mean), len(m.ys.mean), int(c["layers"]), int(c["neurons"]), c["activation"])
        m.net.load_state_dict(state["state_dict"])
        m.info = doc.get("info", {})
        return m


def _stepper(torch, c, net, objective, every: int):
    """One check interval of the optimiser (``model.optimizer``): ``every`` L-BFGS iterations (strong Wolfe line
    search) or ``every`` Adam steps on ``objective``."""
    if c["optimizer"] == "lbfgs":
        opt = torch.optim.LBFGS(net.parameters(), lr=float(c["lr"] or 1.0), max_iter=every, max_eval=25 * every,
                                history_size=20, line_search_fn="strong_wolfe", tolerance_grad=1e-10,
                                tolerance_change=1e-14)

        def closure():
            opt.zero_grad()
            loss = objective()
            loss.backward()
            return loss

        return lambda: opt.step(closure)
    opt = torch.optim.Adam(net.parameters(), lr=float(c["lr"] or 0.01))

    def step():
        for _ in range(every):
            opt.zero_grad()
            objective().backward()
            opt.step()

    return step
