"""A learned body-wrench residual a vehicle file may carry (docs/spec/hybrid.md): a small MLP.

``[F_b, τ_b] = s_out ⊙ MLP((φ − μ) / σ)`` at the CG, added to the vehicle's wrench by every plant that flies
the vehicle; ``φ`` holds only what is known at that instant (never an acceleration, never a later sample).
The vehicle-file block and the ``.npz`` weights (format ``qr.mlp/1``): docs/learn.md "A residual trained
through the rollout".
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from .allowed import is_number
from .errors import QrInputError

FORMAT = "qr.mlp/1"
GROUPS = {"v_b": 3, "omega": 3, "g_b": 3, "u": 4, "u2": 4}
ORDER = ("v_b", "omega", "g_b", "u", "u2")  # the order of the groups in φ, whatever order they are given in
OUTPUTS = ("fx", "fy", "fz", "tx", "ty", "tz")
ACTIVATIONS = ("tanh", "relu")
MAX_LAYERS = 8


@dataclass(frozen=True)
class Residual:
    """The network and its scaling (arrays in float64)."""

    inputs: tuple[str, ...]
    activation: str
    weights: tuple[np.ndarray, ...]  # W_k (out, in)
    biases: tuple[np.ndarray, ...]
    input_mean: np.ndarray
    input_scale: np.ndarray
    output_scale: np.ndarray  # (6,)
    rotor_speed_scale: float

    @property
    def layers(self) -> list[int]:
        return [self.weights[0].shape[1]] + [W.shape[0] for W in self.weights]


def ordered(inputs) -> tuple[str, ...]:
    return tuple(g for g in ORDER if g in inputs)


def feature_names(inputs) -> list[str]:
    names = {"v_b": ["vbx", "vby", "vbz"], "omega": ["wx", "wy", "wz"], "g_b": ["gbx", "gby", "gbz"],
             "u": [f"u{i}" for i in range(1, 5)], "u2": [f"u{i}^2" for i in range(1, 5)]}
    return [n for g in ordered(inputs) for n in names[g]]


def features(inputs, v_b, omega, g_b, u, rotor_speed_scale: float) -> np.ndarray:
    """``φ`` (N, d) from arrays (N, 3), (N, 3), (N, 3), (N, 4)."""
    s = np.asarray(u, float) / rotor_speed_scale
    parts = {"v_b": v_b, "omega": omega, "g_b": g_b, "u": s, "u2": s * s}
    return np.column_stack([np.asarray(parts[g], float) for g in ordered(inputs)])


def forward(res: Residual, phi: np.ndarray) -> np.ndarray:
    """The wrench (N, 6) for features ``φ`` (N, d) in NumPy: its recorded size (:func:`rms_size`) and the
    export's statement of it at hover (qr.export.mapping)."""
    z = (np.atleast_2d(phi) - res.input_mean) / res.input_scale
    for k, (W, b) in enumerate(zip(res.weights, res.biases)):
        z = z @ W.T + b
        if k < len(res.weights) - 1:
            z = np.tanh(z) if res.activation == "tanh" else np.maximum(z, 0.0)
    return z * res.output_scale


# ---- packed for the compiled plant (qr.sim.plant: the tail of its parameter vector) ----------------

def pack(res: Residual) -> np.ndarray:
    """``[flags of v_b, omega, g_b, u, u2 (5), rotor_speed_scale, activation (0 tanh, 1 relu), L, d_0..d_L,
    μ, σ, W_0, b_0, …, s_out]`` (W row-major)."""
    head = [float(g in res.inputs) for g in ORDER]
    head += [res.rotor_speed_scale, float(ACTIVATIONS.index(res.activation)), float(len(res.weights))]
    head += [float(d) for d in res.layers]
    parts = [np.asarray(head), res.input_mean, res.input_scale]
    for W, b in zip(res.weights, res.biases):
        parts += [W.ravel(), b]
    parts.append(res.output_scale)
    return np.concatenate(parts).astype(float)


# ---- the vehicle file's block ------------------------------------------------------------------

def block(res: Residual, model_file: str, note: str, size: Size | None = None) -> dict:
    """The vehicle file's ``residual`` mapping (``model_file``: the .npz, relative to the YAML; ``size``: its
    RMS over the training flights, :func:`rms_size`, which ``qr export`` states where a simulator lacks it)."""
    r = lambda a: [float(f"{x:.17g}") for x in np.asarray(a, float)]  # noqa: E731  (every digit: same model)
    return {"model": model_file, "format": FORMAT, "inputs": list(ordered(res.inputs)),
            "features": feature_names(res.inputs), "outputs": list(OUTPUTS), "activation": res.activation,
            "layers": res.layers,
            "scaling": {"rotor_speed_scale": float(res.rotor_speed_scale), "input_mean": r(res.input_mean),
                        "input_scale": r(res.input_scale), "output_scale": r(res.output_scale)},
            **({"size": size.record()} if size is not None else {}),
            "note": note}


@dataclass(frozen=True)
class Size:
    """The wrench's RMS over the training flights (force N, torque N m: of the vector's length and per body
    axis), 6 significant digits: the vehicle file's ``residual.size``."""

    rms_force: float
    rms_torque: float
    rms_force_xyz: tuple[float, float, float]
    rms_torque_xyz: tuple[float, float, float]
    samples: int
    flights: tuple[str, ...]
    OVER: ClassVar[str] = "every sample of the training windows: the filter's estimated states, the rotor speeds acting"

    def record(self) -> dict:
        return {"rms_force": self.rms_force, "rms_torque": self.rms_torque, "rms_force_xyz": list(self.rms_force_xyz),
                "rms_torque_xyz": list(self.rms_torque_xyz), "samples": self.samples, "flights": list(self.flights),
                "over": self.OVER}


def rms_size(res: Residual, v_b, omega, g_b, u, flights) -> Size:
    """The wrench's :class:`Size` over the states ``v_b, omega, g_b`` (N, 3) and rotor speeds ``u`` (N, 4) of the
    named training ``flights``."""
    w = forward(res, features(res.inputs, v_b, omega, g_b, u, res.rotor_speed_scale))
    rms = lambda a: float(np.sqrt(np.mean(a * a))) if len(a) else 0.0  # noqa: E731
    six = lambda x: float(f"{x:.6g}")  # noqa: E731
    return Size(six(rms(np.linalg.norm(w[:, :3], axis=1))), six(rms(np.linalg.norm(w[:, 3:], axis=1))),
                tuple(six(rms(w[:, k])) for k in range(3)), tuple(six(rms(w[:, k])) for k in range(3, 6)),
                int(len(w)), tuple(str(f) for f in flights))


def recorded_size(raw_block) -> Size | None:
    """The block's ``size`` (:meth:`Size.record`) if it is one (a file from before the record has none)."""
    size = raw_block.get("size") if isinstance(raw_block, dict) else None
    try:
        rms, xyz = [float(size[k]) for k in ("rms_force", "rms_torque")], \
            [tuple(float(x) for x in size[k]) for k in ("rms_force_xyz", "rms_torque_xyz")]
        ok = all(map(math.isfinite, rms)) and all(len(v) == 3 and all(map(math.isfinite, v)) for v in xyz) \
            and isinstance(size["flights"], list) and int(size["samples"]) >= 0
    except (TypeError, KeyError, ValueError):
        return None
    return Size(*rms, *xyz, int(size["samples"]), tuple(size["flights"])) if ok else None


def weights_bytes(res: Residual) -> bytes:
    """The ``.npz`` of the weights (``W0, b0, …``), in memory."""
    arrays = {}
    for k, (W, b) in enumerate(zip(res.weights, res.biases)):
        arrays[f"W{k}"], arrays[f"b{k}"] = np.asarray(W, float), np.asarray(b, float)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def save_weights(res: Residual, path) -> None:
    """The ``.npz`` (written by the caller's atomic folder or path)."""
    with open(path, "wb") as f:
        f.write(weights_bytes(res))


def absolute(raw_block, base_dir: Path):
    """The block with ``model`` made absolute against the folder of the YAML that holds it."""
    if isinstance(raw_block, dict) and isinstance(raw_block.get("model"), str) \
            and not os.path.isabs(raw_block["model"]):
        return {**raw_block, "model": str((Path(base_dir) / raw_block["model"]).resolve())}
    return raw_block


def relative(raw_block, yaml_dir: Path):
    """The block with ``model`` written relative to the folder of the YAML it goes into."""
    if isinstance(raw_block, dict) and isinstance(raw_block.get("model"), str) and os.path.isabs(raw_block["model"]):
        return {**raw_block, "model": os.path.relpath(raw_block["model"], Path(yaml_dir).resolve())}
    return raw_block


def _numbers(x, n: int) -> bool:
    return (isinstance(x, list) and len(x) == n
            and all(is_number(v) and math.isfinite(float(v)) for v in x))


def load(raw, path) -> Residual:
    """The vehicle key ``residual`` validated and its weights read (one :class:`QrInputError` line if not)."""
    fix = "give residual as qr learn residual writes it (model: FILE.npz, inputs, activation, layers, scaling)"
    if not isinstance(raw, dict):
        raise QrInputError(path, "vehicle key 'residual' is not a mapping", fix)
    missing = [k for k in ("model", "inputs", "activation", "scaling") if k not in raw]
    if missing:
        raise QrInputError(path, f"vehicle key 'residual' lacks {', '.join(missing)}", fix)
    if raw.get("format", FORMAT) != FORMAT:
        raise QrInputError(path, f"residual format {raw['format']!r} is not {FORMAT}", fix)
    inputs = raw["inputs"]
    if (not isinstance(inputs, list) or not inputs or any(g not in GROUPS for g in inputs)
            or len(set(inputs)) != len(inputs)):
        raise QrInputError(path, f"residual inputs {inputs!r} are not distinct names from {', '.join(ORDER)}", fix)
    if raw["activation"] not in ACTIVATIONS:
        raise QrInputError(path, f"residual activation {raw['activation']!r}", f"use one of {', '.join(ACTIVATIONS)}")
    if "outputs" in raw and list(raw["outputs"]) != list(OUTPUTS):
        raise QrInputError(path, f"residual outputs {raw['outputs']!r} are not {list(OUTPUTS)}", fix)
    sc = raw["scaling"]
    n_in = sum(GROUPS[g] for g in inputs)
    if not isinstance(sc, dict) or not (is_number(sc.get("rotor_speed_scale")) and sc["rotor_speed_scale"] > 0
                                        and math.isfinite(sc["rotor_speed_scale"])):
        raise QrInputError(path, "residual scaling lacks a positive rotor_speed_scale", fix)
    for key, n in (("input_mean", n_in), ("input_scale", n_in), ("output_scale", len(OUTPUTS))):
        if not _numbers(sc.get(key), n):
            raise QrInputError(path, f"residual scaling.{key} is not {n} finite numbers", fix)
    if any(float(v) <= 0 for k in ("input_scale", "output_scale") for v in sc[k]):
        raise QrInputError(path, "residual scaling has a scale that is not positive", fix)
    model = raw["model"]
    if not isinstance(model, str) or not model:
        raise QrInputError(path, f"residual model {model!r} is not a file name", fix)
    where = Path(model) if os.path.isabs(model) or path is None else Path(path).parent / model
    try:
        with np.load(where, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k], float) for k in z.files}
    except FileNotFoundError:
        raise QrInputError(path, f"residual model file {where} does not exist",
                           "keep the .npz beside the vehicle file, as qr learn residual wrote them") from None
    except (OSError, ValueError) as e:
        raise QrInputError(path, f"residual model file {where} is not a NumPy .npz ({e})", fix) from None
    n_layers = sum(1 for k in arrays if k.startswith("W"))
    if not 1 <= n_layers <= MAX_LAYERS or set(arrays) != {f"{p}{k}" for k in range(n_layers) for p in "Wb"}:
        raise QrInputError(path, f"residual model file {where} does not hold W0, b0, ... (1 to {MAX_LAYERS} layers)",
                           fix)
    Ws = tuple(arrays[f"W{k}"] for k in range(n_layers))
    bs = tuple(arrays[f"b{k}"] for k in range(n_layers))
    d = n_in
    for k, (W, b) in enumerate(zip(Ws, bs)):
        if W.ndim != 2 or W.shape[1] != d or b.shape != (W.shape[0],):
            raise QrInputError(path, f"residual layer {k} has W {W.shape} and b {b.shape} after {d} values", fix)
        d = W.shape[0]
    if d != len(OUTPUTS):
        raise QrInputError(path, f"residual network ends in {d} values, not {len(OUTPUTS)}", fix)
    if "layers" in raw and list(raw["layers"]) != [n_in] + [W.shape[0] for W in Ws]:
        raise QrInputError(path, f"residual layers {raw['layers']} do not match the model file", fix)
    if not all(np.isfinite(a).all() for a in (*Ws, *bs)):
        raise QrInputError(path, f"residual model file {where} holds a non-finite weight", fix)
    return Residual(ordered(inputs), raw["activation"], Ws, bs, np.asarray(sc["input_mean"], float),
                    np.asarray(sc["input_scale"], float), np.asarray(sc["output_scale"], float),
                    float(sc["rotor_speed_scale"]))


def of(vehicle) -> Residual | None:
    """The vehicle's residual (loaded with the vehicle), or None."""
    return getattr(vehicle, "residual", None)
