import numpy as np

from qr import frames


def test_rotation_matches_thesis_eq_4_17():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    for qi, R in zip(q, frames.quat_to_rot(q)):
        w, v = qi[0], qi[1:]
        expected = (w**2 - v @ v) * np.eye(3) + 2 * np.outer(v, v) + 2 * w * frames.skew(v)
        np.testing.assert_allclose(R, expected, atol=1e-12)


def test_body_to_world_convention():
    # 90° yaw: body x points along world y
    q = np.array([[np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]])
    R = frames.quat_to_rot(q)
    np.testing.assert_allclose(frames.to_world(R, np.array([[1.0, 0, 0]])), [[0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(frames.to_body(R, np.array([[0, 1.0, 0]])), [[1, 0, 0]], atol=1e-12)


def test_quat_multiply_composes_rotations_and_keeps_sign():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(2, 10, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    ab = frames.quat_multiply(a, b)
    np.testing.assert_allclose(frames.quat_to_rot(ab), frames.quat_to_rot(a) @ frames.quat_to_rot(b), atol=1e-12)
    # Hamilton product of i and j is k
    np.testing.assert_allclose(frames.quat_multiply([0, 1, 0, 0], [0, 0, 1, 0]), [0, 0, 0, 1])
    np.testing.assert_allclose(frames.quat_multiply(-a, b), -ab)


def test_make_continuous_removes_sign_flips_and_skips_gaps():
    t = np.linspace(0, 2, 50)
    q = np.column_stack([np.cos(t / 2), np.zeros_like(t), np.zeros_like(t), np.sin(t / 2)])
    flipped = q.copy()
    flipped[10:20] *= -1
    flipped[30] *= -1
    flipped[25] = np.nan
    out = frames.make_continuous(flipped)
    ok = np.isfinite(out[:, 0])
    np.testing.assert_allclose(out[ok], q[ok])
    assert np.isnan(out[25]).all()


def test_skew_is_cross_product():
    a, b = np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.7, -1.1])
    np.testing.assert_allclose(frames.skew(a) @ b, np.cross(a, b))


def test_the_compiled_twins_agree_with_the_scipy_conventions():
    """qr.frames_compiled (the filters' fast path, the plant, the rollout) = qr.frames (scipy)."""
    from scipy.spatial.transform import Rotation

    from qr import frames_compiled as fc

    rng = np.random.default_rng(5)
    for _ in range(200):
        a, b = Rotation.random(2, random_state=rng).as_quat(scalar_first=True)
        phi = rng.normal(size=3) * rng.choice([1e-5, 1e-2, 1.0])
        assert np.allclose(fc.quat_to_R(a), frames.quat_to_rot(a), atol=1e-14)
        assert np.allclose(fc.qmul_s(*a, *b), frames.quat_multiply(a, b), atol=1e-14)
        assert np.allclose(fc.qexp_s(*phi), Rotation.from_rotvec(phi).as_quat(scalar_first=True), atol=1e-14)
        assert np.allclose(fc.qlog_s(*a), Rotation.from_quat(a, scalar_first=True).as_rotvec(), atol=1e-12)
        assert np.allclose(fc.qmul_s(*a, a[0], -a[1], -a[2], -a[3]), [1, 0, 0, 0], atol=1e-14)
        assert np.allclose(fc.R_entries(*a), frames.quat_to_rot(a).ravel(), atol=1e-14)
        assert np.allclose(fc.cross(phi, a[1:]), np.cross(phi, a[1:]), atol=1e-14)
        # the angle of a⁻¹ ⊗ b, sign of either quaternion aside
        ang = (Rotation.from_quat(a, scalar_first=True).inv() * Rotation.from_quat(b, scalar_first=True)).magnitude()
        assert abs(fc.quat_angle(a, -b) - ang) < 1e-7
