"""Vision observation models (3d, exact 3d, tc, lc) against exact two-frame geometry."""

from __future__ import annotations

import numpy as np
import pytest

from _vision_truth import imu_samples, make_rig, sigma_cloud, true_pixels, two_frames
from svains.frontend.types import Egomotion
from svains.geometry.rotation import quat_to_rotmat, so3_exp
from svains.models.vision_3d import predict_pixels_3d, predict_pixels_3d_exact
from svains.models.vision_common import camera_motion, feature_rows, stack_pixels
from svains.models.vision_imu import imu_increment
from svains.models.vision_lc import (
    egomotion_from_state_pair,
    egomotion_measurement,
    predict_egomotion_lc,
)
from svains.models.vision_tc import predict_pixels_tc

RIG = make_rig()
OMEGA_B = np.array([0.3, -0.5, 0.8])  # rad/s, |ω| = 0.99
A_W = np.array([0.5, -0.4, 0.3])  # m/s²


def _err_3d(dt_s: float, omega_B: np.ndarray, a_W: np.ndarray) -> float:
    tf = two_frames(RIG, dt_s, omega_B, a_W)
    return float(np.abs(predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, dt_s, RIG) - true_pixels(tf)).max())


def test_3d_exact_variant_matches_geometry() -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W)
    pred = predict_pixels_3d_exact(tf.x_k, tf.p_Ckm1_F, RIG, tf.R_W_Bkm1, tf.p_W_Bkm1)
    np.testing.assert_allclose(pred, true_pixels(tf), atol=1e-9)


def test_3d_exact_rotation_only_leaves_translation_error() -> None:
    # With a = 0 the paper's Δt v(t_k) displacement is exact, so exact rotation alone suffices.
    tf = two_frames(RIG, 0.5, OMEGA_B, np.zeros(3))
    pred = predict_pixels_3d_exact(tf.x_k, tf.p_Ckm1_F, RIG, tf.R_W_Bkm1, dt_s=0.5)
    np.testing.assert_allclose(pred, true_pixels(tf), atol=1e-9)
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W)
    pred = predict_pixels_3d_exact(tf.x_k, tf.p_Ckm1_F, RIG, tf.R_W_Bkm1, dt_s=0.5)
    assert np.abs(pred - true_pixels(tf)).max() > 1e-3


@pytest.mark.parametrize(
    ("omega_B", "a_W"),
    [(OMEGA_B, np.zeros(3)), (np.zeros(3), A_W), (OMEGA_B, A_W)],
    ids=["rotation", "acceleration", "both"],
)
def test_3d_small_motion_error_is_second_order(omega_B: np.ndarray, a_W: np.ndarray) -> None:
    dts = np.array([0.1, 0.05, 0.025])
    errs = np.array([_err_3d(dt, omega_B, a_W) for dt in dts])
    slope = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert 1.9 < slope < 2.1, (errs, slope)
    # Measured: Δt|ω| ≈ 0.1 rad with a = 0.71 m/s² gives 1.25 px (f = 450 px, depths 5-20 m).
    assert errs[0] < 1.5


def test_3d_matches_exact_when_not_moving() -> None:
    tf = two_frames(RIG, 0.5, np.zeros(3), np.zeros(3))
    np.testing.assert_allclose(
        predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, 0.5, RIG), true_pixels(tf), atol=1e-9
    )


def test_tc_equals_3d_on_noise_free_data() -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W)
    X = sigma_cloud(tf.x_k)
    tc = predict_pixels_tc(X, tf.uv_left_prev, tf.uv_right_prev, 0.5, RIG)
    td = predict_pixels_3d(X, tf.p_Ckm1_F, 0.5, RIG)
    np.testing.assert_allclose(tc, td, atol=1e-8)


def test_tc_exp_rotation_matches_exact_rotation_3d() -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, np.zeros(3))
    tc = predict_pixels_tc(tf.x_k, tf.uv_left_prev, tf.uv_right_prev, 0.5, RIG, rotation="exp")
    # With a = 0 and constant ω the remaining approximation is r_c, which eq. 16 gets right
    # only to first order in the rotation: check TC-exp is much closer than TC-linear.
    lin = predict_pixels_tc(tf.x_k, tf.uv_left_prev, tf.uv_right_prev, 0.5, RIG)
    z = true_pixels(tf)
    assert np.abs(tc - z).max() < 0.5 * np.abs(lin - z).max()


@pytest.mark.parametrize("model", ["3d", "3d_exact", "tc", "lc"])
def test_vectorised_equals_loop(model: str) -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W)
    X = sigma_cloud(tf.x_k)

    def h(x: np.ndarray) -> np.ndarray:
        if model == "3d":
            return predict_pixels_3d(x, tf.p_Ckm1_F, 0.5, RIG)
        if model == "3d_exact":
            return predict_pixels_3d_exact(x, tf.p_Ckm1_F, RIG, tf.R_W_Bkm1, tf.p_W_Bkm1)
        if model == "tc":
            return predict_pixels_tc(x, tf.uv_left_prev, tf.uv_right_prev, 0.5, RIG)
        return predict_egomotion_lc(x, 0.5, RIG)

    batch = h(X)
    loop = np.stack([h(x) for x in X])
    width = 6 if model == "lc" else 4 * len(tf.p_Ckm1_F)
    assert batch.shape == (len(X), width)
    np.testing.assert_allclose(batch, loop, rtol=1e-12, atol=1e-9)
    assert np.ptp(batch, axis=0).max() > 0.1  # the sigma points really differ


def test_lc_matches_exact_egomotion_to_second_order() -> None:
    errs = []
    for dt in (0.1, 0.05):
        tf = two_frames(RIG, dt, OMEGA_B, A_W)
        R_ck, p_ck = egomotion_from_state_pair(
            tf.R_W_Bkm1, tf.p_W_Bkm1, quat_to_rotmat(tf.x_k[6:10]), tf.x_k[0:3], RIG
        )
        z, cov = egomotion_measurement(Egomotion(R_ck, p_ck, np.eye(6)))
        pred = predict_egomotion_lc(tf.x_k, dt, RIG)
        # Constant ω: the rotation part is exact.
        np.testing.assert_allclose(pred[:3], z[:3], atol=1e-12)
        errs.append(np.abs(pred[3:] - z[3:]).max())
        np.testing.assert_array_equal(cov, np.eye(6))
    assert 3.5 < errs[0] / errs[1] < 4.5, errs


def test_camera_motion_linear_is_first_order_of_exp() -> None:
    tf = two_frames(RIG, 0.01, OMEGA_B, A_W)
    R_lin, r_lin = camera_motion(tf.x_k, 0.01, RIG, "linear")
    R_exp, r_exp = camera_motion(tf.x_k, 0.01, RIG, "exp")
    np.testing.assert_array_equal(r_lin, r_exp)
    diff = np.abs(R_lin - R_exp).max()
    assert 1e-6 < diff < (0.01 * np.linalg.norm(OMEGA_B)) ** 2
    np.testing.assert_allclose(R_exp[0] @ R_exp[0].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R_exp[0], so3_exp(-0.01 * OMEGA_B @ RIG.R_B_C), atol=1e-14)


def test_stack_pixels_and_feature_rows_agree() -> None:
    uvl = np.arange(6.0).reshape(3, 2)
    uvr = 10 + np.arange(6.0).reshape(3, 2)
    z = stack_pixels(uvl, uvr)
    np.testing.assert_array_equal(z[:4], [0, 1, 10, 11])
    np.testing.assert_array_equal(z[feature_rows([2])], [4, 5, 14, 15])


def test_bad_shapes_raise_clear_errors() -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W, n_features=5)
    with pytest.raises(ValueError, match=r"p_Ckm1_F must be \(M, 3\)"):
        predict_pixels_3d(tf.x_k, tf.p_Ckm1_F[:, :2], 0.5, RIG)
    with pytest.raises(ValueError, match="nx >= 13"):
        predict_pixels_3d(tf.x_k[None, :10], tf.p_Ckm1_F, 0.5, RIG)
    with pytest.raises(ValueError, match="differ"):
        predict_pixels_tc(tf.x_k, tf.uv_left_prev, tf.uv_right_prev[:3], 0.5, RIG)
    with pytest.raises(ValueError, match="dt_s is required"):
        predict_pixels_3d_exact(tf.x_k, tf.p_Ckm1_F, RIG, tf.R_W_Bkm1)
    with pytest.raises(ValueError, match="rotation must be one of"):
        camera_motion(tf.x_k, 0.5, RIG, rotation="quadratic")
    with pytest.raises(ValueError, match="finite 6x6"):
        egomotion_measurement(Egomotion(np.eye(3), np.zeros(3), np.full((6, 6), np.nan)))


def test_3d_exp_rotation_removes_constant_rate_error() -> None:
    # Constant ω, a = 0: the only error left by "exp" is the lever-arm term O((Δt|ω|)² |c_B|).
    tf = two_frames(RIG, 0.5, OMEGA_B, np.zeros(3))
    z = true_pixels(tf)
    lin = np.abs(predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, 0.5, RIG) - z).max()
    exp = np.abs(predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, 0.5, RIG, rotation="exp") - z).max()
    assert exp < 0.1 * lin, (exp, lin)
    tc = predict_pixels_tc(tf.x_k, tf.uv_left_prev, tf.uv_right_prev, 0.5, RIG, rotation="exp")
    np.testing.assert_allclose(
        tc, predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, 0.5, RIG, rotation="exp"), atol=1e-8
    )


@pytest.mark.parametrize("dt_s", [0.05, 0.5])
def test_imu_increment_makes_3d_and_tc_exact(dt_s: float) -> None:
    g_W = np.array([0.0, 0.0, -9.81])
    tf = two_frames(RIG, dt_s, OMEGA_B, A_W)
    t_ns, gyro, accel = imu_samples(tf, OMEGA_B, A_W, g_W)
    inc = imu_increment(t_ns, gyro, accel, 0, round(dt_s * 1e9), g_W)
    R_k = quat_to_rotmat(tf.x_k[6:10])
    np.testing.assert_allclose(inc.dR_Bkm1_Bk, tf.R_W_Bkm1.T @ R_k, atol=1e-12)
    z = true_pixels(tf)
    pred = predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, dt_s, RIG, rotation="imu", imu=inc)
    # Midpoint-rule error on J_B only (rotation is exact for a constant rate): ~1e-4 px.
    assert np.abs(pred - z).max() < 1e-3
    paper = np.abs(predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, dt_s, RIG) - z).max()
    assert np.abs(pred - z).max() < 1e-3 * paper
    tc = predict_pixels_tc(tf.x_k, tf.uv_left_prev, tf.uv_right_prev, dt_s, RIG, "imu", inc)
    np.testing.assert_allclose(tc, pred, atol=1e-8)


def test_imu_rotation_requires_increment() -> None:
    tf = two_frames(RIG, 0.5, OMEGA_B, A_W, n_features=3)
    with pytest.raises(ValueError, match="needs the IMU increment"):
        predict_pixels_3d(tf.x_k, tf.p_Ckm1_F, 0.5, RIG, rotation="imu")


def test_imu_increment_bias_correction_matches_reintegration() -> None:
    # Sigma points of a biased state shift the increment to first order in the bias offset.
    g_W = np.array([0.0, 0.0, -9.81])
    tf = two_frames(RIG, 0.2, OMEGA_B, A_W)
    t_ns, gyro, accel = imu_samples(tf, OMEGA_B, A_W, g_W)
    bg0, ba0 = np.array([0.01, -0.02, 0.005]), np.array([0.1, 0.05, -0.2])
    db_g, db_a = np.array([0.004, 0.003, -0.005]), np.array([0.05, -0.04, 0.03])
    inc0 = imu_increment(t_ns, gyro, accel, 0, 200_000_000, g_W, bg0, ba0)
    inc1 = imu_increment(t_ns, gyro, accel, 0, 200_000_000, g_W, bg0 + db_g, ba0 + db_a)
    x = np.concatenate([tf.x_k, bg0 + db_g, ba0 + db_a])
    ref = predict_pixels_3d(x[:13], tf.p_Ckm1_F, 0.2, RIG, rotation="imu", imu=inc1)
    corrected = predict_pixels_3d(x, tf.p_Ckm1_F, 0.2, RIG, rotation="imu", imu=inc0)
    uncorrected = predict_pixels_3d(x[:13], tf.p_Ckm1_F, 0.2, RIG, rotation="imu", imu=inc0)
    err_c = np.abs(corrected - ref).max()
    err_u = np.abs(uncorrected - ref).max()
    assert err_u > 0.3 and err_c < 0.01 * err_u, (err_c, err_u)


def test_lc_imu_rotation_matches_exact_egomotion() -> None:
    g_W = np.array([0.0, 0.0, -9.81])
    tf = two_frames(RIG, 0.2, OMEGA_B, A_W)
    t_ns, gyro, accel = imu_samples(tf, OMEGA_B, A_W, g_W)
    inc = imu_increment(t_ns, gyro, accel, 0, 200_000_000, g_W)
    R_ck, p_ck = egomotion_from_state_pair(
        tf.R_W_Bkm1, tf.p_W_Bkm1, quat_to_rotmat(tf.x_k[6:10]), tf.x_k[0:3], RIG
    )
    z, _ = egomotion_measurement(Egomotion(R_ck, p_ck, np.eye(6)))
    pred = predict_egomotion_lc(tf.x_k, 0.2, RIG, rotation="imu", imu=inc)
    np.testing.assert_allclose(pred, z, atol=1e-6)
    paper = predict_egomotion_lc(tf.x_k, 0.2, RIG)
    assert np.abs(paper[3:] - z[3:]).max() > 1e-3  # the paper's translation is O(Δt²) off
