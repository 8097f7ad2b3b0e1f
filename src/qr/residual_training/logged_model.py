"""The residual as a self-contained torch module, with an example input and output: what MLflow logs
(``mlflow.pytorch``, with its signature)."""

from __future__ import annotations

import numpy as np


def logged_model(net) -> tuple:
    """(module, example features, its wrench) of a :class:`qr.rollout_torch.ResidualNet`: five feature rows
    across ±1 input scale of the mean."""
    import torch

    module = mlflow_module(net)
    X = np.asarray(net.input_mean.numpy()[None, :] + net.input_scale.numpy()[None, :] * np.linspace(-1, 1, 5)[:, None])
    with torch.no_grad():
        y = module(torch.as_tensor(X)).numpy()
    return module, X, y


def mlflow_module(net):
    """A self-contained torch module of the residual (features φ → body wrench), for ``mlflow.pytorch``:
    the input normalisation and the output scale as fixed affine layers around the MLP."""
    import copy

    import torch

    def affine(scale, shift):
        layer = torch.nn.Linear(len(scale), len(scale), dtype=torch.float64)
        with torch.no_grad():
            layer.weight.copy_(torch.diag(torch.as_tensor(scale, dtype=torch.float64)))
            layer.bias.copy_(torch.as_tensor(shift, dtype=torch.float64))
        return layer

    act = torch.nn.Tanh if net.activation == "tanh" else torch.nn.ReLU
    layers = []
    for k, layer in enumerate(net.layers):
        layers.append(copy.deepcopy(layer))
        if k < len(net.layers) - 1:
            layers.append(act())
    mean, scale = net.input_mean.numpy(), net.input_scale.numpy()
    out = net.output_scale.numpy()
    return torch.nn.Sequential(affine(1 / scale, -mean / scale), *layers, affine(out, np.zeros_like(out))).eval()
