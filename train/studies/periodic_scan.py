"""A frequency-resolving scan of the periodic torque: the adversarial search's ``scan`` run.

A periodic torque's worst case is a narrow resonance in frequency × direction: random draws
and CMA-ES land near different peaks on different seeds. The scan resolves both without a
search over the direction. At each of ``scan_points`` frequencies f (log-spaced, inside the
searched range) it runs one episode per joint k with the whole amplitude on that joint,
beside one undisturbed episode, all from the same start phase. The family's torque on
joint j is A·w_j·sin(2πft + φ_j) with the weights w = τ_max ⊙ |x| / |τ_max ⊙ |x|| of its
direction x (the phases φ fixed by the reset seed). Each episode's error vector over the
cost window, e(t) = q(t) − q_r(s*(t)) (s* the path's closest point: |e| is the path
distance), is taken to superpose in the linear range of the closed loop:

    e_w(t) ≈ e₀(t) + Σ_k w_k (e_k(t) − e₀(t)),   cost(w)² ≈ wᵀQw + 2bᵀw + c,

with Δ_k = e_k − e₀, Q = mean ΔᵀΔ, b = mean Δᵀe₀, c = mean |e₀|² over the window. The
closest points of the episodes differ (the passivity controller's timing drifts freely), so
this is a heuristic for where to look, not a bound: on the iiwa at its resonance it
predicted 0.065 rad where the episode gave 0.051, and 0.036 / 0.045 for random weights
that gave 0.031 / 0.042. :func:`worst_weights` maximises the prediction over the
non-negative unit sphere; the ``scan_top`` best frequencies (local maxima along the grid
first) are then run as real episodes at their predicted worst weights (the direction
x ∝ w / τ_max, :func:`direction_for`).
Every scan episode is a real episode of the family and counts as a searched one; the
prediction only chooses where to look (``tests/test_periodic_scan.py`` checks it against
real episodes in the linear range).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from train.studies.worst_case import Outcome, episode, outcome

FloatArray = NDArray[np.float64]

#: The seed stream of the scan's start phase (the random draws' are (seed, 1, k)).
SCAN_STREAM = 2_000


def sphere_angles(x: Sequence[float]) -> list[float]:
    """The hyperspherical angles φ₁…φ_{d−1} of a nonzero vector's direction: the inverse
    of :func:`train.studies.worst_case.sphere_point` (each angle in [−π, π])."""
    v = np.asarray(x, dtype=np.float64)
    norm = float(np.linalg.norm(v))
    if v.ndim != 1 or v.size < 2 or not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f"a direction needs a finite nonzero vector of size >= 2, got {x!r}")
    v = v / norm
    d = v.size
    angles = [math.atan2(float(np.linalg.norm(v[k + 1 :])), float(v[k])) for k in range(d - 2)]
    angles.append(math.atan2(float(v[d - 1]), float(v[d - 2])))
    return angles


def scan_frequencies(frequency_hz: tuple[float, float], points: int) -> FloatArray:
    """``points`` frequencies (Hz), log-spaced at the centres of equal log-width cells of
    ``frequency_hz`` (none on a bound)."""
    lo, hi = np.log(frequency_hz[0]), np.log(frequency_hz[1])
    return np.exp(lo + (hi - lo) * (np.arange(points) + 0.5) / points)


def window_errors(record: Any, path: Any, window: tuple[float, float]) -> FloatArray:
    """The error vectors q − q_r(s*) (rad) over the cost ``window`` (s), shape (T, n)."""
    inside = (record.t_s > window[0]) & (record.t_s <= window[1] + 1e-9)
    return record.q[inside] - path.evaluate(record.path_s[inside])[0]


def scan_task(args: tuple[Any, ...]) -> tuple[Outcome, FloatArray]:
    """One scan episode (a worker's task): (env_id, controller, spec or None, reset_seed,
    episode_s, window, control_hz, failure_distance_rad, gains, s0) → its outcome and its
    :func:`window_errors`."""
    env_id, controller, spec, reset_seed, episode_s, window, hz, failure, gains, s0 = args
    record, path = episode(env_id, controller, spec, reset_seed, episode_s, hz, gains, s0)
    return outcome(record, window, failure), window_errors(record, path, window)


def quadratic(base: FloatArray, axes: Sequence[FloatArray]) -> tuple[FloatArray, FloatArray, float]:
    """(Q, b, c) of the predicted cost² wᵀQw + 2bᵀw + c (module docstring) from the
    undisturbed episode's error vectors ``base`` (T, n) and each axis episode's, over the
    same window."""
    deltas = np.stack([e - base for e in axes], axis=2)  # (T, n, k)
    steps = len(base)
    q_form = np.einsum("tik,til->kl", deltas, deltas) / steps
    b = np.einsum("tik,ti->k", deltas, base) / steps
    return q_form, b, float(np.sum(base * base) / steps)


def direction_for(weights: FloatArray, torque_limits_nm: FloatArray) -> FloatArray:
    """The family's direction x (unit) whose amplitude weights τ_max ⊙ |x| / |τ_max ⊙ |x||
    are ``weights`` (≥ 0, unit)."""
    x = np.asarray(weights, dtype=np.float64) / np.asarray(torque_limits_nm, dtype=np.float64)
    return x / np.linalg.norm(x)


def _cost_squared(
    q_form: FloatArray, b: FloatArray, c: float, w: FloatArray
) -> tuple[float, FloatArray]:
    """wᵀQw + 2bᵀw + c (rad²) and its gradient in w, 2(Qw + b) (Q symmetric)."""
    qw = q_form @ w
    return float(w @ qw + 2.0 * b @ w + c), 2.0 * (qw + b)


def predicted_cost(q_form: FloatArray, b: FloatArray, c: float, w: FloatArray) -> float:
    """sqrt(wᵀQw + 2bᵀw + c) (rad), the predicted cost under the amplitude weights w."""
    return math.sqrt(max(_cost_squared(q_form, b, c, w)[0], 0.0))


def worst_weights(q_form: FloatArray, b: FloatArray, c: float) -> tuple[FloatArray, float]:
    """The amplitude weights w ≥ 0, |w| = 1 that maximise wᵀQw + 2bᵀw + c, and the
    predicted cost (rad) there: L-BFGS-B over x ≥ 0 with w = x/|x|, from every axis, the
    uniform weights and |v| of Q's top eigenvector; the best of the local maxima."""
    n = len(b)

    def negative(x: FloatArray) -> tuple[float, FloatArray]:
        norm = float(np.linalg.norm(x))
        u = x / norm
        value, grad_u = _cost_squared(q_form, b, c, u)
        return -value, -(grad_u - (grad_u @ u) * u) / norm

    top = np.abs(np.linalg.eigh(q_form)[1][:, -1])
    starts = [*np.eye(n), np.full(n, 1.0 / math.sqrt(n)), top / np.linalg.norm(top)]
    best_u, best = starts[0], -math.inf
    for x0 in starts:
        res = minimize(negative, x0 + 1e-9, jac=True, method="L-BFGS-B", bounds=[(0.0, None)] * n)
        x = np.maximum(res.x, 0.0)
        if not np.any(x):
            continue
        u = x / np.linalg.norm(x)
        value = predicted_cost(q_form, b, c, u)
        if value > best:
            best_u, best = u, value
    return best_u, best


def top_frequencies(predicted: Sequence[float], top: int) -> list[int]:
    """The indices of the ``top`` frequencies to verify: the grid's local maxima of the
    predicted cost, highest first, then the other points, highest first."""
    p = np.asarray(predicted, dtype=np.float64)
    peaks = [
        i
        for i in range(len(p))
        if (i == 0 or p[i] >= p[i - 1]) and (i == len(p) - 1 or p[i] >= p[i + 1])
    ]
    order = sorted(peaks, key=lambda i: -p[i]) + sorted(
        (i for i in range(len(p)) if i not in peaks), key=lambda i: -p[i]
    )
    return order[:top]


#: The golden section's interior fraction, (3 − √5)/2.
GOLDEN = (3.0 - math.sqrt(5.0)) / 2.0


def golden_max(
    lo: float,
    mid: float,
    hi: float,
    value_mid: float,
    evaluate: Callable[[int, float], float],
    steps: int,
) -> tuple[float, float]:
    """Golden-section search for a maximum of ``evaluate`` on [lo, hi], from the interior
    point ``mid`` whose value is ``value_mid``: each of ``steps`` probes goes into the larger
    side of the bracket, ``evaluate(k, x)`` for the k-th probe; returns the best point and
    its value (never worse than ``mid``'s). Deterministic in the values, so a resumed run
    probes the same points."""
    a, x, b, fx = lo, mid, hi, value_mid
    for k in range(steps):
        u = x - GOLDEN * (x - a) if x - a > b - x else x + GOLDEN * (b - x)
        fu = evaluate(k, u)
        if fu > fx:
            a, b = (a, x) if u < x else (x, b)
            x, fx = u, fu
        else:
            a, b = (u, b) if u < x else (a, u)
    return x, fx


def grid_bracket(
    freqs: FloatArray, i: int, frequency_hz: tuple[float, float]
) -> tuple[float, float]:
    """The frequencies (Hz) around grid point ``i``: its neighbours, or the searched range's
    bound beyond the grid's ends."""
    lo = float(freqs[i - 1]) if i > 0 else float(frequency_hz[0])
    hi = float(freqs[i + 1]) if i < len(freqs) - 1 else float(frequency_hz[1])
    return lo, hi


def _axis_params(start_phase: float, frequency_hz: float, n: int) -> list[dict[str, float]]:
    """The trial parameters of the n axis episodes at one frequency (x = e_k)."""
    out = []
    for k in range(n):
        axis = np.zeros(n)
        axis[k] = 1.0
        angles = sphere_angles(axis)
        out.append({
            "start_phase": start_phase, "frequency_hz": float(frequency_hz),
            **{f"a{i}": a for i, a in enumerate(angles)},
        })  # fmt: skip
    return out


def scan_phases(start_phase: float, phases: int) -> list[float]:
    """The second stage's start phases (fractions of the period): ``phases`` more, evenly
    spaced around the period from ``start_phase`` (which the first stage ran)."""
    return [(start_phase + j / (phases + 1)) % 1.0 for j in range(1, phases + 1)]


def run_scan(
    study: Any,
    pool: Any,
    cfg: Any,
    controller: str,
    target: Any,
    start_phase: float,
    gains: Any,
    tell: Callable[[Any, Any, dict[str, Any], dict[str, Any], Outcome], None],
    progress: bool,
) -> None:
    """The scan of one search seed into ``study`` (module docstring): from ``start_phase``
    (a fraction of the path period), the axis episodes at every frequency; the
    ``scan_top`` frequencies predicted worst (:func:`top_frequencies`), each refined by
    ``cfg.scan_refine`` golden-section steps in log-frequency between its grid neighbours
    (:func:`golden_max`); then, with ``cfg.scan_phases``, the axis episodes at the
    ``cfg.scan_phase_top`` worst of them from that many more start phases; each point's
    (Q, b, c) kept in the study's user attributes; then the verified episodes: the
    ``scan_top`` (refined) frequencies and each second stage's worst point. Resumable: a
    point or a verified episode whose record was written is not run again (an interruption
    loses at most the batch in flight, never repeats one)."""
    n = target.n
    window, episode_s = target.window({}), target.episode_s()
    bases: dict[float, FloatArray] = {}  # undisturbed episodes (deterministic: rerun on resume)

    def task(spec: dict[str, Any] | None, phase: float) -> tuple[Any, ...]:
        s0 = phase * target.period_s
        return (cfg.env_id, controller, spec, cfg.reset_seed, episode_s, window,
                cfg.control_hz, cfg.failure_distance_rad, gains, s0)  # fmt: skip

    def run(params: list[dict[str, float]], key: str, phase: float, value: Any = None) -> list[Any]:
        for p in params:
            study.enqueue_trial(p)
        trials = [study.ask() for _ in params]
        found = [target.space(t) for t in trials]
        specs = [target.spec(p) for p in found]
        results = list(pool.map(scan_task, [task(spec, phase) for spec in specs]))
        if value is None:
            value = _form(bases[phase], results)
        study.set_user_attr(key, value)  # written before the trials: never run twice
        for trial, spec, p, (out, _) in zip(trials, specs, found, results, strict=True):
            tell(study, trial, spec, p, out)
        return results

    def scan_point(key: str, phase: float, f: float) -> None:
        if key in study.user_attrs:
            return
        if phase not in bases:
            bases[phase] = pool.submit(scan_task, task(None, phase)).result()[1]
        run(_axis_params(phase, f, n), key, phase)
        if progress:
            print(f"{study.study_name}: scanned {f:.3g} Hz at phase {phase:.3f}", flush=True)

    def predict(key: str) -> tuple[FloatArray, float]:
        form = study.user_attrs[key]
        if form["unstable"]:  # an axis episode failed: it is the worst there already
            return np.eye(n)[int(form["axis"])], float(cfg.failure_distance_rad)
        return worst_weights(np.array(form["q"]), np.array(form["b"]), float(form["c"]))

    freqs = scan_frequencies(cfg.frequency_hz, cfg.scan_points)
    for i, f in enumerate(freqs):
        scan_point(f"scan{i}", start_phase, float(f))
    first = [predict(f"scan{i}") for i in range(len(freqs))]
    chosen = top_frequencies([p for _, p in first], cfg.scan_top)

    def golden(
        key: str,
        phase: float,
        f: float,
        at_f: tuple[FloatArray, float],
        bracket: tuple[float, float],
        steps: int,
    ) -> tuple[float, FloatArray, float]:
        """The best of ``steps`` golden-section probes in log-frequency within ``bracket``
        (Hz) from ``f`` (whose prediction is ``at_f``), from start phase ``phase``:
        (Hz, weights, predicted cost); probe k's point is ``{key}_{k}``."""
        probes = {math.log(f): at_f}

        def probe(k: int, log_f: float) -> float:
            scan_point(f"{key}_{k}", phase, math.exp(log_f))
            probes[log_f] = predict(f"{key}_{k}")
            return probes[log_f][1]

        mid = math.log(f)
        lo, hi = math.log(bracket[0]), math.log(bracket[1])
        log_f, _ = golden_max(lo, mid, hi, at_f[1], probe, steps)
        return (f if log_f == mid else math.exp(log_f), *probes[log_f])

    def refine(j: int, i: int) -> tuple[float, FloatArray, float]:
        """Grid point i (the j-th chosen), refined between its grid neighbours."""
        bracket = grid_bracket(freqs, i, cfg.frequency_hz)
        return golden(f"refine{j}", start_phase, float(freqs[i]), first[i], bracket,
                      cfg.scan_refine)  # fmt: skip

    def refine_at(
        key: str, phase: float, f: float, at_f: tuple[FloatArray, float], cells: int
    ) -> tuple[float, FloatArray, float]:
        """``f`` refined at ``phase`` within ``cells`` grid cells either side (inside the
        searched range)."""
        ratio = (cfg.frequency_hz[1] / cfg.frequency_hz[0]) ** (cells / cfg.scan_points)
        bracket = (max(f / ratio, cfg.frequency_hz[0]), min(f * ratio, cfg.frequency_hz[1]))
        return golden(key, phase, f, at_f, bracket, cfg.scan_phase_refine)

    refined = [refine(j, i) for j, i in enumerate(chosen)]
    candidates = [(f"verified{j}", start_phase, *r) for j, r in enumerate(refined)]
    if cfg.scan_phases:
        # the first keeps the single stage's keys: a search from before scan_phase_top resumes
        by_cost = sorted(range(len(refined)), key=lambda j: -refined[j][2])
        phases = scan_phases(start_phase, cfg.scan_phases)
        for t, j in enumerate(by_cost[: cfg.scan_phase_top]):
            f_t, tag = refined[j][0], "" if t == 0 else f"{t}_"
            for m, phase in enumerate(phases):
                scan_point(f"phase{tag}{m}", phase, f_t)
            second = [predict(f"phase{tag}{m}") for m in range(len(phases))]
            m = int(np.argmax([p for _, p in second]))
            best = (f_t, *second[m])
            if cfg.scan_phase_refine:
                best = refine_at(f"rephase{t}", phases[m], f_t, second[m], 2)
            candidates.append((f"verified_phase{tag.rstrip('_')}", phases[m], *best))
    limits = np.asarray(target.torque_limits_nm, dtype=np.float64)
    for key, phase, f, weights, predicted in candidates:
        if key in study.user_attrs:
            continue
        direction = direction_for(weights, limits)
        params = {"start_phase": phase, "frequency_hz": f,
                  **{f"a{m}": a for m, a in enumerate(sphere_angles(direction))}}  # fmt: skip
        record = {"frequency_hz": f, "start_phase": phase, "predicted_cost": predicted,
                  "weights": [float(w) for w in weights]}  # fmt: skip
        results = run([params], key, phase, record)
        if progress:
            print(f"{study.study_name}: {f:.3g} Hz, phase {phase:.3f}: predicted "
                  f"{predicted:.3g} rad, ran {results[0][0].cost:.3g} rad", flush=True)  # fmt: skip


def _form(base: FloatArray, results: list[Any]) -> dict[str, Any]:
    """A point's record: (Q, b, c), or the first axis episode that went unstable (or ended
    early, so that its window does not match the undisturbed one)."""
    unstable = [
        k for k, (out, errors) in enumerate(results) if out.unstable or errors.shape != base.shape
    ]
    if unstable:
        return {"unstable": True, "axis": unstable[0]}
    q_form, b, c = quadratic(base, [errors for _, errors in results])
    return {"unstable": False, "q": q_form.tolist(), "b": b.tolist(), "c": c}
