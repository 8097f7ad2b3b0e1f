"""The simulation study (thesis Chapter 5) flies the Crazyflie firmware's Lee controller too
(simulate.controller=lee): its steady offset under a constant wind is the hand-derived f / (m Kpos_P), and the
disturbance estimate in its feed-forward cancels it, as with the thesis's LQR."""

import numpy as np
import pytest

from qr.effects import parse_effect_spec
from qr.sim.disturbance import CatalogForce
from qr.sim.study import Plant, Reference, SimSettings, fly


def test_the_lee_controllers_offset_under_wind_is_f_over_m_kp(hummingbird):
    wind = [parse_effect_spec("wind_force:fx=0.5,fy=-0.25,fz=0")]
    p = np.array([0.0, 0.0, 1.0])
    hover = Reference(lambda t: (p, np.zeros(3), np.zeros(3), 0.0, 0.0), 8.0)
    lee = SimSettings(controller="lee")
    end = fly(hover, Plant(hummingbird, wind), None, lee).log.iloc[-1]
    kp = 7.0  # conf/controller/lee.yaml's Kpos_P: no position integral, so the offset stays
    assert end["px"] == pytest.approx(0.5 / (hummingbird.mass * kp), rel=0.02)
    assert end["py"] == pytest.approx(-0.25 / (hummingbird.mass * kp), rel=0.02)
    comp = fly(hover, Plant(hummingbird, wind), CatalogForce(wind, hummingbird), lee).log.iloc[-1]
    assert abs(comp["px"]) < 1e-4 and abs(comp["py"]) < 1e-4
    lqr = fly(hover, Plant(hummingbird, wind), None, SimSettings()).log.iloc[-1]
    assert abs(lqr["px"] - end["px"]) > 0.01  # a different controller: a different offset
