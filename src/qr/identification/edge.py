"""Threshold decisions that come out the same on every machine.

A statistic is a sum of many products, and its last digits depend on the order the BLAS kernel (chosen
per processor) and the thread count add them in.  A decision that compares it with a threshold is
decided by those digits when the two agree to within ``EDGE`` (relative): such a margin is numerical
noise, not evidence.  It is then decided the conservative way, the same everywhere (the effect is not
added, the set not accepted), and recorded "on the edge" with its margin for the selection table.
``EDGE`` is far above the rounding of a sum of 10⁷ terms (~1e-12 relative) and far below any margin a
setting expresses (1 % of a loss, 0.1 of a t statistic).
"""

from __future__ import annotations

from dataclasses import dataclass, field

EDGE = 1e-9


def margin(value: float, threshold: float) -> float:
    """``value - threshold`` relative to the threshold's size (to the value's where the threshold is 0)."""
    scale = abs(threshold) or abs(value) or 1.0
    return (value - threshold) / scale


@dataclass
class Margins:
    """The margins of a chain of decisions (e.g. one step of the selection): the closest one, and
    whether any was on the edge."""

    closest: float = float("inf")
    on_edge: list[str] = field(default_factory=list)

    def at_least(self, value: float, threshold: float, what: str = "", on_edge: bool = False) -> bool:
        """``value >= threshold``; ``on_edge`` (the conservative answer) when within ``EDGE`` of it."""
        m = margin(value, threshold)
        if abs(m) < abs(self.closest):
            self.closest = m
        if abs(m) <= EDGE:
            self.on_edge.append(what or "a threshold")
            return on_edge
        return m > 0

    def at_most(self, value: float, threshold: float, what: str = "", on_edge: bool = False) -> bool:
        """``value <= threshold``; ``on_edge`` when within ``EDGE`` of it."""
        return self.at_least(-value, -threshold, what, on_edge)


def rank_key(loss: float) -> float:
    """A loss rounded to ``EDGE`` (relative) for ordering: sets whose losses tie to numerical noise are
    then ordered by the next key (simplicity, names), the same everywhere."""
    if loss == 0 or loss != loss or abs(loss) == float("inf"):
        return loss
    from math import floor, log10

    digits = -int(floor(log10(abs(loss)))) + int(-log10(EDGE))
    return round(loss, digits)
