"""The passivity law compiled: the kernel twin of :meth:`agents.passivity.PassivityController.law`
(whose docstring, and the module docstring of :mod:`agents.passivity`, state the equations).

:func:`law_step` evaluates the law at (q, q̇) with the controller's state (s, ṡ, σ), writes
the torque and every quantity of ``LawOutput`` into ``out`` (:data:`OUT` then τ_sync, τ_r⁰
and f), and integrates the state in place (the controller's integrator). The reference tables are
interpolated here too (:func:`table_point`, the twin of ``PassivityTables.__call__``).
``tests/test_kernels.py`` checks every output against the numpy law to 1e-12.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.kernels import kernel, pack, view1, view3
from ptrack_gym.kernels.linalg import solve_small
from ptrack_gym.kernels.path import cubic_interval

FloatArray = NDArray[np.float64]

#: The scalar outputs, in ``out``'s order (then τ_sync, τ_r⁰, f and the hold correction δ:
#: n entries each).
OUT = ("s_dd", "sigma_dot", "energy", "h_plus_w", "h_r", "phi", "psi", "pump_power",
       "dissipation", "sync_power", "s_tilde", "s_tilde_dot", "path_error",
       "r0_scale")  # fmt: skip
#: Entries of the gains vector before the diagonals of K and D and the torque box (n each).
GAINS = ("kappa", "R", "k_pump", "pump_metric", "speed_eps", "sync_rate", "sync_ratio",
         "saturation_aware", "implicit", "midpoint", "hold_filter_s",
         "direction_guard")  # fmt: skip


def law_tables(
    gains: FloatArray, knots: FloatArray, coeffs: FloatArray, period_s: float
) -> tuple[FloatArray, NDArray[np.int64]]:
    """The constant inputs of :func:`law_step`, packed: the gains vector (:data:`GAINS`, then
    K, D and the torque box τ_max), the tables' knots (N + 1,) and spline coefficients
    (4, N, 3n + 4), and the period."""
    return pack([gains, knots, coeffs, np.array([period_s])])


@kernel
def table_point(
    knots: FloatArray, coeffs: FloatArray, period: float, s: float, out: FloatArray
) -> None:
    """The interpolated table row at s (q_r, q_r', τ_r, M_r, M_r', W_r, W_r': 3n + 4) into
    ``out``. Twin: ``PassivityTables.__call__`` (scipy's periodic cubic spline)."""
    i, x = cubic_interval(knots, period, s)
    for c in range(coeffs.shape[2]):
        out[c] = ((coeffs[0, i, c] * x + coeffs[1, i, c]) * x + coeffs[2, i, c]) * x + coeffs[
            3, i, c
        ]


@kernel
def law_step(
    q: FloatArray,
    qd: FloatArray,
    mass: FloatArray,
    potential: float,
    bias: FloatArray,
    dt: float,
    state: FloatArray,
    hold_state: FloatArray,
    flat: FloatArray,
    layout: NDArray[np.int64],
    tau: FloatArray,
    out: FloatArray,
) -> None:
    """τ into ``tau`` and the law's outputs into ``out`` at (q, q̇) with M(q) = ``mass``,
    U(q) = ``potential``, C(q, q̇)q̇ + g(q) = ``bias`` (read only with the ``midpoint`` flag
    and dt > 0: τ then includes the hold correction δ of
    :meth:`~agents.passivity.PassivityController.hold_correction`) and the state
    ``state`` = (s, ṡ, σ), ``hold_state`` the hold's memory (updated: see
    :meth:`~agents.passivity.PassivityController.step_numpy`); then one step of ``dt`` in
    ``state``: ṡ ← ṡ + Δṡ, s ← s + dt ṡ, σ ← σ + dt σ̇, Δṡ the semi-implicit update of
    :meth:`~agents.passivity.PassivityController.step_numpy` (Δṡ = dt s̈ with the
    ``implicit`` flag off; dt = 0: evaluate only)."""
    n = q.shape[0]
    gains = view1(flat, layout, 0)
    knots, coeffs = view1(flat, layout, 1), view3(flat, layout, 2)
    period = view1(flat, layout, 3)[0]
    kappa, big_r, k_pump = gains[0], gains[1], gains[2]
    metric, speed_eps, sync_rate, sync_ratio = gains[3] > 0.5, gains[4], gains[5], gains[6]
    saturation_aware, implicit, midpoint = gains[7] > 0.5, gains[8] > 0.5, gains[9] > 0.5
    hold_filter, guard = gains[10], gains[11]
    k0, d0, b0 = len(GAINS), len(GAINS) + n, len(GAINS) + 2 * n  # offsets of K, D, the box
    s, sd, sigma = state[0], state[1], state[2]
    m = 3 * n + 4
    ref = np.empty(m)
    ref_sigma = np.empty(m)
    table_point(knots, coeffs, period, s, ref)
    table_point(knots, coeffs, period, sigma, ref_sigma)
    m_r, m_r_d = ref[3 * n], ref[3 * n + 1]
    w_r_sigma, w_r_d_sigma = ref_sigma[3 * n + 2], ref_sigma[3 * n + 3]
    tau_qd = np.empty(n)  # M(q) q̇
    speed2 = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += mass[i, j] * qd[j]
        tau_qd[i] = acc
        speed2 += qd[i] * acc
    speed2 = max(speed2, 0.0)
    speed = math.sqrt(speed2)
    sigma_dot = math.sqrt(speed2 / m_r)
    sync = 0.0
    if sync_rate > 0.0:
        x = min(sigma_dot / sync_ratio, 1.0)
        w = 1.0 - x * x * (3.0 - 2.0 * x)
        if w > 0.0:
            num, den = 0.0, 0.0
            for i in range(n):
                t_i = 0.0  # (M(q) q_r'(σ))_i
                for j in range(n):
                    t_i += mass[i, j] * ref_sigma[n + j]
                num += (q[i] - ref_sigma[i]) * t_i
                den += ref_sigma[n + i] * t_i
            sync = w * sync_rate * (num / den)
            sigma_dot = sigma_dot + sync
    s_t, s_td = s - sigma, sd - sigma_dot
    mu_j = w_r_d_sigma - kappa * s_t - big_r * s_td  # μ √M_r(s) (J)
    v_g = speed  # the direction's speed: v, or the guard's c |Δq̇|_M above it (μ > 0)
    if guard > 0.0 and dt > 0.0 and speed > speed_eps and hold_state[0] > 0.5 and mu_j > 0.0:
        turn2 = 0.0  # |Δq̇|²_M, Δq̇ = dt (a − b̂): the last period's expected velocity change
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += mass[i, j] * (hold_state[2 + n + j] - hold_state[2 + 2 * n + j])
            turn2 += (hold_state[2 + n + i] - hold_state[2 + 2 * n + i]) * acc
        v_g = max(speed, guard * dt * math.sqrt(max(turn2, 0.0)))
        if v_g > speed:  # σ̇₀ = v²/(v_g √M_r): the channel's power stays −μ √M_r σ̇₀
            sigma_dot = sigma_dot - (1.0 - speed / v_g) * math.sqrt(speed2 / m_r)
            s_td = sd - sigma_dot
            mu_j = w_r_d_sigma - kappa * s_t - big_r * s_td
    phi, err2, dphi_qr, qd_tau_r, damper = 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(n):
        err = q[i] - ref[i]
        dphi = gains[k0 + i] * err
        edot = qd[i] - ref[n + i] * sd  # ė = q̇ − q_r'(s) ṡ
        damp = gains[d0 + i] * edot
        phi += err * dphi
        err2 += err * err
        dphi_qr += (dphi + damp) * ref[n + i]
        damper += damp * edot
        qd_tau_r += qd[i] * ref[2 * n + i]
    phi *= 0.5
    psi = 0.5 * kappa * s_t**2
    mu = mu_j / math.sqrt(m_r)
    e_c = -kappa * s_t - big_r * s_td + dphi_qr
    h_plus_w = 0.5 * speed2 + potential + w_r_sigma
    h_r = 0.5 * m_r * (sd * sd - 1.0)
    f_r = -k_pump * h_r * sd
    s_dd = (-0.5 * m_r_d * (sd * sd - 1.0) + e_c + f_r) / m_r
    off = len(OUT)
    pump_power = 0.0
    # out's vector blocks first hold −∂φ/∂q − μ τ_q̇/v, τ_r⁰ and f; then, with the
    # saturation-aware scale α of τ_r⁰, τ_sync = α τ_r⁰ − ∂φ/∂q − μ τ_q̇/v and α τ_r⁰.
    for i in range(n):
        tau_r0 = (speed2 / m_r) * ref[2 * n + i] - (qd_tau_r / m_r) * tau_qd[i]
        f = -k_pump * h_plus_w * (tau_qd[i] if metric else qd[i])
        sync_rest = -gains[k0 + i] * (q[i] - ref[i]) - gains[d0 + i] * (qd[i] - ref[n + i] * sd)
        if speed > speed_eps:
            sync_rest = sync_rest - (mu / v_g) * tau_qd[i]
        pump_power += qd[i] * f
        out[off + i] = sync_rest
        out[off + n + i] = tau_r0
        out[off + 2 * n + i] = f
    alpha = 1.0
    if saturation_aware:  # τ = τ_rest + α τ_r⁰ inside max(τ_max, |τ_rest|) per joint
        rest = out[off : off + n] + out[off + 2 * n : off + 3 * n]
        alpha = fit_scale(rest, out[off + n : off + 2 * n], gains[b0 : b0 + n])
    for i in range(n):
        tau_r0 = alpha * out[off + n + i]
        tau_sync = tau_r0 + out[off + i]
        tau[i] = tau_sync + out[off + 2 * n + i]
        out[off + i] = tau_sync
        out[off + n + i] = tau_r0
        out[off + 3 * n + i] = 0.0
    if midpoint and dt > 0.0:
        qd_prev = hold_state[2 : 2 + n]
        acc_prev = hold_state[2 + n : 2 + 2 * n]
        b_hat = hold_state[2 + 2 * n : 2 + 3 * n]
        if hold_state[0] > 0.5 and hold_filter > 0.0:  # b̂ ← b̂ + λ (error − b̂)
            lam = 1.0 - math.exp(-dt / hold_filter)
            for i in range(n):
                error = acc_prev[i] - (qd[i] - qd_prev[i]) / hold_state[1]
                b_hat[i] += lam * (error - b_hat[i])
        hold_correction(
            mass, tau_qd, qd, tau, bias, b_hat, ref, m_r, alpha, big_r, k_pump, metric,
            speed_eps, saturation_aware, gains[b0 : b0 + n], dt, out[off + 3 * n : off + 4 * n],
        )  # fmt: skip
        rhs = np.empty(n)
        for i in range(n):
            tau[i] += out[off + 3 * n + i]
            rhs[i] = tau[i] - bias[i]
            qd_prev[i] = qd[i]
        hold_state[0] = 1.0 if solve_small(mass, rhs, acc_prev) else 0.0
        hold_state[1] = dt
    out[0] = s_dd
    out[1] = sigma_dot
    out[2] = h_plus_w + h_r + phi + psi
    out[3] = h_plus_w
    out[4] = h_r
    out[5] = phi
    out[6] = psi
    out[7] = pump_power + sd * f_r
    out[8] = big_r * s_td**2 + damper
    out[9] = mu_j * sync
    out[10] = s_t
    out[11] = s_td
    out[12] = math.sqrt(err2)
    out[13] = alpha
    if dt > 0.0:
        sd_dot = dt * s_dd
        if implicit:
            a, c, b = kappa, big_r, kappa * sigma_dot
            for i in range(n):
                a += gains[k0 + i] * ref[n + i] * ref[n + i]
                c += gains[d0 + i] * ref[n + i] * ref[n + i]
                b += gains[k0 + i] * ref[n + i] * qd[i]
            a, c, b = a / m_r, c / m_r, b / m_r
            # the pump's damping of ṡ, J = −∂(f_r/M_r)/∂ṡ: implicit past dt J = 1
            limit = max(dt * k_pump * (1.5 * sd * sd - 0.5) - 1.0, 0.0)
            sd_dot = dt * (s_dd + dt * (b - a * sd)) / (1.0 + c * dt + a * dt * dt + limit)
        sd_new = sd + sd_dot
        state[0] = s + dt * sd_new
        state[1] = sd_new
        state[2] = sigma + dt * sigma_dot


@kernel
def fit_scale(rest: FloatArray, r0: FloatArray, box: FloatArray) -> float:
    """The largest a ∈ [0, 1] with |rest_j + a r0_j| ≤ max(box_j, |rest_j|) for every j.
    Twin: :func:`agents.passivity.fit_scale`."""
    n = rest.shape[0]
    fits = True
    for i in range(n):
        if abs(rest[i] + r0[i]) > max(box[i], abs(rest[i])):
            fits = False
    if fits:
        return 1.0
    a = 1.0
    for i in range(n):
        if r0[i] != 0.0:
            sign = 1.0 if r0[i] > 0.0 else -1.0
            a = min(a, (max(box[i], abs(rest[i])) - sign * rest[i]) / abs(r0[i]))
    return max(a, 0.0)


@kernel
def hold_correction(
    mass: FloatArray,
    p: FloatArray,
    qd: FloatArray,
    tau: FloatArray,
    bias: FloatArray,
    accel_bias: FloatArray,
    ref: FloatArray,
    m_r: float,
    alpha: float,
    big_r: float,
    k_pump: float,
    metric: bool,
    speed_eps: float,
    saturation_aware: bool,
    box: FloatArray,
    dt: float,
    delta: FloatArray,
) -> None:
    """δ of the midpoint hold into ``delta`` (p = M q̇, ``accel_bias`` the acceleration
    error estimate b̂, ``ref`` the table row at s; 0 where
    M − (dt/2)B is singular). Twin: :meth:`agents.passivity.PassivityController.hold_correction`."""
    n = p.shape[0]
    tau_r = ref[2 * n : 3 * n]
    b = np.empty((n, n))
    speed2, power = 0.0, 0.0  # v² = q̇ᵀp, P = q̇ᵀτ_r
    for i in range(n):
        speed2 += qd[i] * p[i]
        power += qd[i] * tau_r[i]
    c_pp = 0.0
    if math.sqrt(max(speed2, 0.0)) > speed_eps:
        c_pp = -(alpha * power + big_r) / (m_r * speed2)
    for i in range(n):
        d_i = p[i] if metric else qd[i]
        for j in range(n):
            b[i, j] = (
                alpha * (2.0 * tau_r[i] * p[j] - p[i] * tau_r[j]) / m_r
                + c_pp * p[i] * p[j]
                - k_pump * d_i * p[j]
            )
    a = np.empty((n, n))
    rhs = np.empty(n)
    for i in range(n):
        rhs[i] = tau[i] - bias[i]
        for j in range(n):
            a[i, j] = mass[i, j] - 0.5 * dt * b[i, j]
            rhs[i] -= mass[i, j] * accel_bias[j]
    y = np.empty(n)
    if not solve_small(a, rhs, y):
        for i in range(n):
            delta[i] = 0.0
        return
    finite = True
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += b[i, j] * y[j]
        delta[i] = 0.5 * dt * acc
        finite = finite and math.isfinite(delta[i])
    if not finite:
        for i in range(n):
            delta[i] = 0.0
        return
    if saturation_aware:
        beta = fit_scale(tau, delta, box)
        for i in range(n):
            delta[i] *= beta
