"""The thesis filters use exactly the matrices the thesis prints (§4.2.1), and filterpy receives them.

Every expected matrix below is typed from the thesis text, not computed by
qr: Φ (4.8, 4.19 corrected, 4.32), Q (4.6a, 4.16a/4.20, 4.31a), R (4.6b,
4.16b, 4.31b), H (4.10, 4.26, 4.33).  The ``exact`` discretisation is checked
against Van Loan's matrix-exponential construction (scipy.linalg.expm).
"""

import numpy as np
import pytest
import yaml
from scipy.linalg import expm

from conftest import ROOT
from qr.estimation import attitude_eskf, chain, motor_kf, position_kf, settings
from qr.frames import quat_to_rot

I3, Z3 = np.eye(3), np.zeros((3, 3))
DTS = [0.01, 0.0137, 0.1]  # regular 100 Hz, a jittered step, a dropout gap


def blocks(rows):
    return np.block(rows)


@pytest.mark.parametrize("dt", DTS)
def test_position_filter_matrices(dt):
    phi_48 = blocks([[I3, dt * I3, dt**2 / 2 * I3, dt**3 / 6 * I3],
                     [Z3, I3, dt * I3, dt**2 / 2 * I3],
                     [Z3, Z3, I3, dt * I3],
                     [Z3, Z3, Z3, I3]])
    q_46a = 100 * blocks([[np.zeros((9, 9)), np.zeros((9, 3))], [np.zeros((3, 9)), 0.1 * I3]])
    r_46b = np.diag([0.0002**2] * 3)
    h_410 = np.hstack([I3, np.zeros((3, 9))])
    np.testing.assert_array_equal(position_kf.transition(dt), phi_48)
    np.testing.assert_allclose(position_kf.process_noise(dt, position_kf.THESIS_Q, "thesis"), q_46a, rtol=1e-15)
    np.testing.assert_array_equal(position_kf.measurement_noise(position_kf.THESIS_R), r_46b)
    np.testing.assert_array_equal(position_kf.H, h_410)


@pytest.mark.parametrize("dt", DTS)
def test_motor_filter_matrices(dt):
    np.testing.assert_array_equal(motor_kf.transition(dt), [[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]])  # 4.32
    np.testing.assert_allclose(motor_kf.process_noise(dt, motor_kf.THESIS_Q, "thesis"),
                               10000 * np.diag([0, 0, 0.1]), rtol=1e-15)  # 4.31a
    np.testing.assert_array_equal(motor_kf.measurement_noise(motor_kf.THESIS_R), [[1.0]])  # 4.31b
    np.testing.assert_array_equal(motor_kf.H, [[1, 0, 0]])  # 4.33


@pytest.mark.parametrize("dt", DTS)
def test_eskf_matrices_with_eq_4_19_corrected(dt):
    R = quat_to_rot(np.array([0.8, 0.2, -0.4, 0.4]) / np.linalg.norm([0.8, 0.2, -0.4, 0.4]))
    F_418 = blocks([[Z3, R.T, Z3, Z3], [Z3, Z3, I3, Z3], [Z3, Z3, Z3, I3], [Z3, Z3, Z3, Z3]])
    np.testing.assert_array_equal(attitude_eskf.F_matrix(R), F_418)
    printed_419 = np.eye(12) + F_418 * dt + F_418 @ F_418 * dt**2  # as printed: the 1/2 is missing
    corrected = np.eye(12) + F_418 * dt + F_418 @ F_418 * dt**2 / 2
    Phi = attitude_eskf.transition(R, dt, "thesis")
    np.testing.assert_allclose(Phi, corrected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(printed_419 - Phi, F_418 @ F_418 * dt**2 / 2, atol=1e-15)
    G_421 = np.vstack([np.zeros((9, 3)), I3])
    Q_416a = 500 * np.diag([1, 0.1, 1])
    np.testing.assert_allclose(attitude_eskf.process_noise(R, dt, attitude_eskf.THESIS_Q, "thesis"),
                               G_421 @ Q_416a @ G_421.T * dt**2, rtol=1e-15)  # 4.20
    np.testing.assert_array_equal(attitude_eskf.measurement_noise(attitude_eskf.THESIS_R), np.diag([0.001**2] * 3))
    np.testing.assert_array_equal(attitude_eskf.H, np.hstack([I3, np.zeros((3, 9))]))  # 4.26


def test_filterpy_receives_the_thesis_matrices(monkeypatch):
    """The reference path hands filterpy exactly these F, Q, R, H (recorded from its predict/update)."""
    from filterpy.kalman import KalmanFilter

    seen = {"F": [], "Q": [], "R": [], "H": []}
    predict, update = KalmanFilter.predict, KalmanFilter.update

    def spy_predict(self, u=None, B=None, F=None, Q=None):
        seen["F"].append(F.copy())
        seen["Q"].append(Q.copy())
        return predict(self, u, B, F, Q)

    def spy_update(self, z, R=None, H=None):
        seen["R"].append(self.R.copy())
        seen["H"].append(self.H.copy())
        return update(self, z, R, H)

    monkeypatch.setattr(KalmanFilter, "predict", spy_predict)
    monkeypatch.setattr(KalmanFilter, "update", spy_update)
    t = np.array([0.0, 0.01, 0.0237, 0.0337])
    position_kf.filter_reference(t, np.ones((4, 3)), position_kf.THESIS_Q, position_kf.THESIS_R)
    np.testing.assert_array_equal(seen["F"][1], position_kf.transition(t[2] - t[1]))
    np.testing.assert_array_equal(seen["Q"][1][9:, 9:], 10 * I3)
    np.testing.assert_array_equal(seen["R"][0], 0.0002**2 * I3)
    np.testing.assert_array_equal(seen["H"][0], np.hstack([I3, np.zeros((3, 9))]))


@pytest.mark.parametrize("m", [3, 4])
def test_exact_discretisation_is_van_loan(m):
    """``exact``: Φ = exp(A dt) and Q = ∫ Φ G q Gᵀ Φᵀ, by Van Loan's block exponential."""
    dt, q = 0.013, 7.0
    A = np.diag(np.ones(m - 1), 1)
    G = np.zeros((m, 1))
    G[-1] = 1
    M = np.block([[-A, G @ G.T * q], [np.zeros((m, m)), A.T]]) * dt
    E = expm(M)
    Phi = E[m:, m:].T
    Q = Phi @ E[:m, m:]
    np.testing.assert_allclose(chain.transition(m, dt), Phi, rtol=1e-13, atol=1e-16)
    np.testing.assert_allclose(chain.process_noise(m, dt, q, "exact"), Q, rtol=1e-10, atol=1e-22)


def test_exact_eskf_transition_is_the_matrix_exponential():
    R = quat_to_rot(np.array([0.6, 0.0, 0.8, 0.0]))
    dt = 0.02
    np.testing.assert_allclose(attitude_eskf.transition(R, dt, "exact"), expm(attitude_eskf.F_matrix(R) * dt),
                               atol=1e-15)


def test_thesis_config_is_the_library_default():
    """filter=thesis composes to qr.estimation.DEFAULTS, written once (the structured config FilterNode:
    conf/filter/thesis.yaml only selects it), and they carry the printed numbers."""
    from qr.config import compose, to_dict

    assert yaml.safe_load((ROOT / "conf" / "filter" / "thesis.yaml").read_text()) == \
        {"defaults": ["schema", "_self_"], "name": "thesis"}
    conf = to_dict(compose(["filter=thesis"]))["filter"]
    assert conf == settings.DEFAULTS
    assert conf["position"] == {"q": 100 * 0.1, "r": 0.0002**2}
    assert (conf["attitude"]["q"], conf["attitude"]["r"]) == ([500.0, 50.0, 500.0], 0.001**2)
    assert conf["motor"] == {"q": 10000 * 0.1, "r": 1.0}
