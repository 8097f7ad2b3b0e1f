"""What the named effects say about the vehicle file's own numbers.

A coefficient effect (a C_T or C_Q error, an inertia or mass error) is a factor
on a number in the vehicle file.  When that factor is gross (``GROSS``: 50 % or
more either way) the file itself is the finding: "C_Q in vehicle.yaml looks
×9.8 too small", with the value the data give.
"""

from __future__ import annotations

GROSS = 1.5  # a factor this far from 1, either way, is a wrong number in the file, not a small correction


def _factors(effect: dict, vehicle):
    """(vehicle-file key, symbol, file value, factor true/file, s.e. of the factor) of a coefficient effect."""
    p, se = effect["parameters"], effect.get("stderr", {})
    name = effect["name"]
    if name == "thrust_gain":
        yield "thrust_coeff", "C_T", vehicle.thrust_coeff, p["gain"], se.get("gain")
    elif name == "yaw_torque_gain":
        yield "torque_coeff", "C_Q", vehicle.torque_coeff, p["gain"], se.get("gain")
    elif name == "mass_error":
        m = vehicle.mass
        yield "mass", "m", m, 1 + p["dm"] / m, se.get("dm", 0) / m
    elif name == "inertia_error":
        for i, ax in enumerate(("xx", "yy", "zz")):
            J = float(vehicle.inertia[i])
            yield f"inertia[{i}]", f"J{ax}", J, 1 + p[f"dJ{ax}"] / J, se.get(f"dJ{ax}", 0) / J


def coefficient_checks(effects: list[dict], vehicle, vehicle_path) -> list[dict]:
    """One entry per vehicle-file number the named effects put off by ``GROSS`` or more."""
    out = []
    for e in effects:
        for key, sym, value, factor, se in _factors(e, vehicle):
            if not (factor >= GROSS or factor <= 1 / GROSS):
                continue
            x, word = (factor, "small") if factor > 1 else (1 / factor, "large")
            alike = [c for c in e.get("confounded_with", [])
                     if not (key in ("inertia[0]", "inertia[1]") and c == "yaw_torque_gain")]  # that is about z
            also = f" (or, confounded with it: {', '.join(alike)})" if alike else ""
            out.append({
                "key": key, "file_value": value, "estimate": value * factor, "factor": factor,
                "factor_stderr": se, "effect": e["name"],
                "statement": f"{sym} ({key}) in {vehicle_path} looks x{x:.2g} too {word}: the data give "
                             f"{value * factor:.4g}, the file says {value:.4g}{also}",
            })
    return out
