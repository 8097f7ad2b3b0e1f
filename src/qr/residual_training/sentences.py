"""The sentences ``qr learn residual``'s report and log share, each generated from the numbers it states."""

from __future__ import annotations

from ..rollout import QUANTITIES


def listed(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def split_sentence(split: dict) -> str:
    """Which flights train and which stop the training (``split``: :func:`qr.residual_fit.split`'s), by path."""
    if split["by"] == "time":
        return (f"1 flight given, {listed(split['training'])}: its windows ending before t = "
                f"{split['validation_from_s']:.2f} s train, those from t = {split['validation_from_s']:.2f} s on "
                "validate (early stopping; never trained on)")
    n = len(split["training"]) + len(split["validation"])
    return (f"{n} flights given: {len(split['training'])} train{'s' if len(split['training']) == 1 else ''} "
            f"({listed(split['training'])}), {len(split['validation'])} validate{'s' if len(split['validation']) == 1 else ''} "
            f"({listed(split['validation'])}: early stopping, never trained on"
            + ("; whole trajectories no training flight flies" if split["by"] == "trajectory" else "") + ")")


def kept_sentence(initial: float, epochs: list[float], fine_tuned: bool) -> str:
    """What is kept when no epoch's validation loss beat the start's."""
    best = min(epochs) if epochs else float("nan")
    return (f"no epoch improved the validation loss ({initial:.4g} at the start, {best:.4g} at best over "
            f"{len(epochs)} epoch(s)): the weights at the start are kept, "
            + ("the vehicle's own residual, unchanged by this training" if fine_tuned else
               "a network of zero output (the hybrid flies as the vehicle without a residual)"))


def change_sentence(H: int, val: dict) -> str:
    """The hybrid's validation error at h = H against the vehicle's, per signal (``val``: the ratios to
    rate_frozen of ``vehicle`` and ``hybrid``), each change with its numbers."""
    v, h = val["vehicle"], val["hybrid"]
    known = [q for q in QUANTITIES if v[q] is not None and h[q] is not None]
    lower = [q for q in known if h[q] < v[q]]
    higher = [q for q in known if h[q] > v[q]]
    same = [q for q in known if h[q] == v[q]]
    change = lambda q: f"{q} ({v[q]:.4g} -> {h[q]:.4g} x rate_frozen, {100 * (h[q] / v[q] - 1):+.2g} %)"  # noqa: E731
    parts = []
    if lower:
        parts.append("lowers the validation error of " + listed([change(q) for q in lower]))
    if higher:
        parts.append("raises that of " + listed([change(q) for q in higher]))
    if same:
        parts.append(("leaves " if parts else "leaves the validation error of ") + listed(same)
                     + " equal to the vehicle's to the last bit")
    missing = [q for q in QUANTITIES if q not in known]
    if missing:
        parts.append(f"has no validation error of {listed(missing)}")
    return f"At h = {H} the residual " + ("; it ".join(parts) if parts else "cannot be compared") + "."
