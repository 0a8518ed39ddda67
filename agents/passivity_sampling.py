"""What a control period does to the passivity law: per-step growth factors of its fast loops.

A digital controller evaluates the law at samples t_k = k dt and holds its torque until the
next one (a zero-order hold). Four loops of the law are fast enough, on a path's slow
stretches (small M_r(s)) or at a light wrist, to feel dt. Each has a closed-form map per
control step, linearised on the reference (q = q_r(s), q̇ = q_r'(s), ṡ = σ̇ = 1, σ = s) and
frozen at s; its spectral radius ρ is the factor by which a perturbation grows per step.
``docs/control_rates.md`` shows them against dt and against simulation.

1. **Phase loop**: the virtual system s, the arm's position x along the path and the
   controller's σ (which integrates the arm's speed σ̇ = ẋ), in path units and per unit
   M_r: s̈ = −a_K(s − x) − a_κ(s − σ) − c(ṡ − ẋ), ẍ = the opposite; a_K = q_r'ᵀK q_r'/M_r
   (φ's springs along the path), a_κ = κ/M_r (ψ), c = (R + q_r'ᵀD q_r')/M_r (the dampers),
   all growing like 1/M_r(s) on a slow stretch. The relative motion of s and x is damped
   at 2c; explicit on both sides (symplectic Euler for s, the torque held from the sample
   for x) its step flips sign and grows once c dt > 1. The default scheme is implicit in a
   and c on the virtual side and holds R's feedback at the midpoint on the arm's side:
   ρ ≤ 1 while c dt ≤ 2 (:data:`PHASE_DAMPING_LIMIT`) and a_K dt² ≤ 1.
2. **Velocity turning** (the arm, through τ_r⁰ and the μ channel): the velocity feedback
   of the law on the reference acts in span{u, w}, u = q_r', w = M⁻¹τ_r, as

   .. math::

       A = \\begin{pmatrix} (2W_r' - R)/M_r - k M_r &
           -\\Gamma/M_r - W_r'(W_r' - R)/M_r^2 + k W_r' \\\\
           2 & -2 W_r'/M_r \\end{pmatrix}, \\quad \\Gamma = \\tau_r^T M^{-1} \\tau_r,

   whose eigenvalues are −(R/M_r + kM_r)/2 ± iω_v, ω_v² ≈ 2(ΓM_r − W_r'²)/M_r² (Cauchy–
   Schwarz keeps it ≥ 0): the work-free τ_r⁰ turns the velocity like a gyroscopic force.
   Held from the sample, the step is explicit Euler, ρ = max|1 + λ dt| > 1 once
   ω_v² dt > R/M_r + kM_r; held at the midpoint, ρ = max|(1 + λdt/2)/(1 − λdt/2)| ≤ 1.
3. **Spring modes** (the arm, φ): a mode of frequency ω of M(q)⁻¹K under a zero-order hold
   on a continuous arm, with the damper D = cK dt: per step (x, v dt) ↦ the matrix of
   :func:`spring_growth`, det = 1 − cθ² + θ²/2 with θ = ω dt. Without a damper (c = 0, the
   paper's law) ρ > 1 at every dt — the hold feeds the spring ½K dt of negative damping,
   and nothing in the paper's law damps a mode across the path; with
   c > ½, ρ < 1 iff c θ² < 2 (θ < √2 at c = 1): :func:`max_period_s`, the controller's
   stated rate limit, keeps θ ≤ :func:`spring_angle_limit` (c) (1 at c = 1, 1/√2 at c = 0).
4. **The virtual pump** (the virtual system alone): f_r = −k H_r ṡ, H_r = ½M_r(ṡ² − 1),
   adds −k ½(ṡ² − 1)ṡ ≈ −k(ṡ − 1) to s̈ near ṡ = 1. The implicit step covers a and c, not
   this term: per step ṡ − 1 ↦ (1 − k dt)(ṡ − 1) (:func:`pump_growth`), ρ > 1 once
   k dt > 2. k = λ/M̄_r is a rate of the path's mean inertia, not of the arm's energy loop
   (that one, k M_r(s), is held at the midpoint), so a light arm with a stiff pump reaches
   it first: the two-link at its fight-tuned λ = 23 1/s (M̄_r ≈ 0.08, k ≈ 300 1/s) diverged
   undisturbed at 100 Hz on 5 of 12 random paths (k dt 2.8–5.7). The stated limit keeps
   k dt ≤ :data:`PUMP_LIMIT` = 1 (monotone decay, a factor 2 inside the growth boundary).
   Off the reference the term is cubic, −k ½(ṡ² − 1)ṡ, and its slope k(3ṡ² − 1)/2 grows
   with ṡ: an explicit step runs away at any rate once ṡ is thrown past √(1 + 4/(k dt))
   (≈ 3.0 at 250 Hz on the tuned two-link), so the controller's step turns implicit in it
   where its slope times dt passes 1 (:class:`~agents.passivity.PassivityController`).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from agents.base import FloatArray
from agents.passivity_tables import PassivityTables
from ptrack_gym.robots.model import RobotModel


class PassivityGains(Protocol):
    """What the sampled loops read of :class:`agents.passivity.PassivityGains` (which
    imports this module for its rate limit: a structural type keeps the imports one way)."""

    kappa: float
    R: float
    k_pump: float

    def stiffness(self, n: int) -> FloatArray:
        """K as n diagonal entries (N·m/rad)."""
        ...

    def damping(self, n: int) -> FloatArray:
        """D as n diagonal entries (N·m·s/rad)."""
        ...


#: The grid rows (of the tables' 2048) the loops are evaluated on.
ROWS = 128
#: The largest c dt (c the phase loop's damping rate, loop 1) the rate limit admits: inside
#: the range where the default scheme's phase loop keeps ρ ≤ 1 for a_K dt² ≤ 1 (what the
#: spring limit allows; :func:`phase_growth`, ``docs/control_rates.md``).
PHASE_DAMPING_LIMIT = 2.0

#: The largest k dt (k the virtual pump's rate, loop 4) the rate limit admits: ṡ − 1 decays
#: monotonically there; it grows per step once k dt > 2 (:func:`pump_growth`).
PUMP_LIMIT = 1.0


def _rows(tables: PassivityTables, count: int = ROWS) -> FloatArray:
    """Every ``len(grid) // count``-th table row (q_r, q_r', τ_r, M_r, M_r', W_r, W_r')."""
    return tables.columns[:: max(1, len(tables.grid_s) // count)]


def phase_growth(
    tables: PassivityTables,
    gains: PassivityGains,
    dt_s: float,
    integrator: str = "implicit",
    hold: str = "midpoint",
) -> FloatArray:
    """ρ per step of the phase loop (loop 1 of the module docstring) at the rows of
    :func:`_rows`, shape (rows,): the largest |λ| of the step's map of (s, ṡ, x, ẋ, σ)
    apart from the common motion (λ = 1, the path's time shift), with the virtual system
    stepped by ``integrator`` ("implicit" or "symplectic", as the controller's), σ by
    explicit Euler, and the arm, a continuous plant, under a torque held from the sample or
    (``hold="midpoint"``) with R's feedback at the period's midpoint."""
    n = tables.n
    rows = _rows(tables)
    qd, m_r = rows[:, n : 2 * n], rows[:, 3 * n]
    k, d = gains.stiffness(n), gains.damping(n)
    a_k = np.einsum("ij,j,ij->i", qd, k, qd) / m_r
    a_kappa = gains.kappa / m_r
    c = (gains.R + np.einsum("ij,j,ij->i", qd, d, qd)) / m_r
    c_hold = gains.R / m_r if hold == "midpoint" else np.zeros_like(m_r)
    out = np.empty(len(rows))
    for i in range(len(rows)):
        coef = (a_k[i], a_kappa[i], c[i], c_hold[i])
        cols = [_phase_step(e, *coef, dt_s, integrator) for e in np.eye(5)]
        lam = np.linalg.eigvals(np.column_stack(cols))
        relative = lam[np.abs(lam - 1.0) > 1e-6]
        out[i] = np.abs(relative).max() if relative.size else 1.0
    return out


def _phase_step(
    y: FloatArray,
    a_k: float,
    a_kappa: float,
    c: float,
    c_hold: float,
    dt: float,
    integrator: str,
) -> FloatArray:
    """One control step of the phase loop from y = (s, ṡ, x, ẋ, σ) (:func:`phase_growth`)."""
    s, sd, x, xd, sigma = y
    pull = a_k * (s - x) + a_kappa * (s - sigma) + c * (sd - xd)  # on the arm; −pull on s
    a = a_k + a_kappa
    if integrator == "symplectic":
        sd_new = sd - dt * pull
    else:  # the controller's semi-implicit step; b = (a_K + a_κ) ẋ in path units
        sd_new = sd + dt * (-pull + dt * a * (xd - sd)) / (1.0 + c * dt + a * dt * dt)
    accel = pull / (1.0 + 0.5 * dt * c_hold)  # the arm's, held over the step
    return np.array(
        [s + dt * sd_new, sd_new, x + dt * xd + 0.5 * dt * dt * accel, xd + dt * accel,
         sigma + dt * xd]
    )  # fmt: skip


def turning_matrices(
    tables: PassivityTables, model: RobotModel, gains: PassivityGains
) -> tuple[FloatArray, FloatArray]:
    """(A, ω_v): the 2 × 2 velocity feedback A of loop 2 in the basis (q_r', M⁻¹τ_r) at
    each row of :func:`_rows`, shape (rows, 2, 2) (1/s), and its turning rate
    ω_v = |Im λ(A)| (rad/s), shape (rows,)."""
    n = tables.n
    rows = _rows(tables)
    out = np.empty((len(rows), 2, 2))
    for i, row in enumerate(rows):
        q, tau_r = row[:n], row[2 * n : 3 * n]
        m_r, w_d = row[3 * n], row[3 * n + 3]
        gamma = float(tau_r @ np.linalg.solve(model.mass_matrix(q), tau_r))
        big_r, k = gains.R, gains.k_pump
        top_right = -gamma / m_r - w_d * (w_d - big_r) / m_r**2 + k * w_d
        out[i] = [[(2.0 * w_d - big_r) / m_r - k * m_r, top_right], [2.0, -2.0 * w_d / m_r]]
    return out, np.abs(np.linalg.eigvals(out).imag).max(axis=1)


def turning_growth(
    tables: PassivityTables,
    model: RobotModel,
    gains: PassivityGains,
    dt_s: float,
    hold: str = "midpoint",
) -> FloatArray:
    """ρ per step of the velocity turning (loop 2) at the rows of :func:`_rows`, with the
    torque held from the sample (explicit Euler) or at the midpoint (Cayley); (rows,)."""
    lam = np.linalg.eigvals(turning_matrices(tables, model, gains)[0]) * dt_s
    factor = (1.0 + lam) if hold == "sample" else (1.0 + 0.5 * lam) / (1.0 - 0.5 * lam)
    return np.abs(factor).max(axis=1)


def spring_growth(theta: float | FloatArray, c: float) -> FloatArray:
    """ρ per step of a spring mode (loop 3): θ = ω dt (rad), c = D/(K dt); a continuous
    plant under a zero-order hold,

    .. math::

        \\begin{pmatrix} x \\\\ v\\,dt \\end{pmatrix}_{k+1} =
        \\begin{pmatrix} 1 - \\theta^2/2 & 1 - c\\theta^2/2 \\\\
        -\\theta^2 & 1 - c\\theta^2 \\end{pmatrix}
        \\begin{pmatrix} x \\\\ v\\,dt \\end{pmatrix}_k."""
    theta = np.atleast_1d(np.asarray(theta, dtype=np.float64))
    out = np.empty(theta.shape)
    for i, t in enumerate(theta):
        t2 = t * t
        step = np.array([[1.0 - 0.5 * t2, 1.0 - 0.5 * c * t2], [-t2, 1.0 - c * t2]])
        out[i] = np.abs(np.linalg.eigvals(step)).max()
    return out


def spring_angle_limit(c: float) -> float:
    """The largest θ = ω dt (rad per control period) the rate limit admits for a spring mode
    with damper share c = D/(K dt): 1/√c for c ≥ 1 — a factor √2 inside θ = √(2/c), where
    :func:`spring_growth` reaches 1 — and, below c = 1, from 1 (c = 1) down to 1/√2 (c = 0)
    linearly. With c ≤ ½ an isolated mode grows at every θ (by about (½ − c)θ²/2 per step)
    and only the law's dissipation through the phase holds it (``docs/control_rates.md``)."""
    if c >= 1.0:
        return 1.0 / math.sqrt(c)
    return (1.0 + (math.sqrt(2.0) - 1.0) * max(c, 0.0)) / math.sqrt(2.0)


def phase_rate(tables: PassivityTables, gains: PassivityGains) -> float:
    """max over the path of c(s) = (R + q_r'ᵀD q_r')/M_r(s) (1/s), the phase loop's damping
    rate (loop 1), over every row of the tables."""
    n = tables.n
    cols = tables.columns
    qd, m_r = cols[:, n : 2 * n], cols[:, 3 * n]
    return float(np.max((gains.R + np.einsum("ij,j,ij->i", qd, gains.damping(n), qd)) / m_r))


def pump_growth(k_pump: float, dt_s: float) -> float:
    """Per-step factor |1 − k dt| of ṡ − 1 under the virtual pump alone (loop 4), stepped
    explicitly; k the pump gain (1/s on the virtual side), dt the control period (s)."""
    return abs(1.0 - k_pump * dt_s)


def max_period_s(
    omega_rad_s: float,
    damping_over_stiffness_s: float,
    phase_rate_1_s: float = 0.0,
    pump_rate_1_s: float = 0.0,
) -> float:
    """The longest dt with ω dt ≤ :func:`spring_angle_limit` (c) at c = d/dt, d = min_j
    D_j/K_j (s), ω the fastest spring mode on the path (rad/s), c_phase dt ≤
    :data:`PHASE_DAMPING_LIMIT`, c_phase = :func:`phase_rate` (1/s), and k dt ≤
    :data:`PUMP_LIMIT`, k = ``pump_rate_1_s`` the virtual pump's gain. ω dt / θ(d/dt) grows
    with dt, so the springs' dt_max is 1/(ω² d) where that is ≤ d (there c ≥ 1), else the
    root of √2 ω dt² − dt − (√2 − 1) d = 0."""
    springs = math.inf
    if omega_rad_s > 0.0:
        d = max(damping_over_stiffness_s, 0.0)
        short = 1.0 / (omega_rad_s**2 * d) if d > 0.0 else math.inf
        if short <= d:
            springs = short
        else:
            a = math.sqrt(2.0) * omega_rad_s
            springs = (1.0 + math.sqrt(1.0 + 4.0 * a * (math.sqrt(2.0) - 1.0) * d)) / (2.0 * a)
    phase = PHASE_DAMPING_LIMIT / phase_rate_1_s if phase_rate_1_s > 0.0 else math.inf
    pump = PUMP_LIMIT / pump_rate_1_s if pump_rate_1_s > 0.0 else math.inf
    return min(springs, phase, pump)
