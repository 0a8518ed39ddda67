"""How much can a residual of a given authority gain over its base? A hand-made residual
answers before any training does.

The residual env's controller block observes e = q_r(s) − q, the error to the controller's
own reference point (``agents.residual.PRIOR_ERROR_FEATURES``: the passivity block's
``path_error_j_rad``, s its path parameter; a time-indexed base's ``e_j_rad``, s its clock).
The probe is the wrapper's control prior (``prior_gain_per_rad``) with the learned action
held at 0: bang-bang stiffness toward that point::

    a = clip(g · e, −1, 1)        (g = 1000 1/rad: saturated beyond 1 mrad)

so with the acceleration authority α the residual is τ_res = M(q) α a. It is no learner and
is not tuned; it bounds from below what the authority allows: if this simple feedback gains
little at α, a learned residual at α has little to find. Base (a = 0) and probe run on the
same seeds, so the ratio is paired. With ``--gate`` the wrapper's deadband gate (d₀ = d_g)
switches it off near the path, as the gated residuals are deployed.

Usage::

    ptrack probe-authority --env ptrack_gym/IiwaTrack-v0 --base passivity \\
        --base-gains tuned --control-hz 1000 --alpha 1 3 10 --gate 0.002 \\
        --disturbance none impulse periodic payload noise
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.registry import GAIN_CHOICES
from agents.residual import PRIOR_BASES
from train.evaluation.envs import build_env

#: The probe's gain g (1/rad): the action saturates beyond 1 mrad of error.
PROBE_GAIN = 1000.0


@dataclass(frozen=True)
class ProbeResult:
    """Mean path-distance RMS (rad) over the seeds, base alone and with the probe."""

    disturbance: str
    alpha: float
    gate_rad: float | None
    base_rms: float
    probe_rms: float

    @property
    def ratio(self) -> float:
        return self.probe_rms / self.base_rms


def probe(
    env_id: str,
    base: str,
    base_gains: str,
    control_hz: float,
    episode_s: float,
    disturbance: str,
    alpha: float,
    gate_rad: float | None,
    seeds: Sequence[int],
) -> ProbeResult:
    """Run the base (a = 0) and the probe's residual on ``seeds`` (see the module
    docstring) and return their mean path-distance RMS (rad)."""
    gate = {} if gate_rad is None else {"gate_rad": gate_rad, "gate_deadband_rad": gate_rad}
    rms: dict[float, list[float]] = {}
    for gain in (0.0, PROBE_GAIN):  # the base alone (a = 0, no prior), then the probe
        env = build_env(
            env_id, base, 0.0, control_hz, max(1, round(episode_s * control_hz)), "on_path",
            disturbance,
            residual_kwargs={"base_gains": base_gains, "scale_accel_rad_s2": alpha,
                             "prior_gain_per_rad": gain, **gate},
        )  # fmt: skip
        try:
            zero = np.zeros(env.action_space.shape, dtype=np.float32)
            for seed in seeds:
                env.reset(seed=seed)
                d2, done = [], False
                while not done:
                    _, _, term, trunc, info = env.step(zero)
                    d2.append(info["path_distance"] ** 2)
                    done = term or trunc
                rms.setdefault(gain, []).append(float(np.sqrt(np.mean(d2))))
        finally:
            env.close()
    return ProbeResult(
        disturbance, alpha, gate_rad, float(np.mean(rms[0.0])), float(np.mean(rms[PROBE_GAIN]))
    )


def main(argv: Sequence[str] | None = None) -> list[ProbeResult]:
    p = argparse.ArgumentParser(prog="ptrack probe-authority", description=__doc__)
    p.add_argument("--env", dest="env_id", default="ptrack_gym/IiwaTrack-v0")
    p.add_argument("--base", default="passivity", choices=PRIOR_BASES)
    p.add_argument("--base-gains", choices=GAIN_CHOICES, default="default")
    p.add_argument("--control-hz", type=float, default=1000.0)
    p.add_argument("--episode-s", type=float, default=5.0)
    p.add_argument("--alpha", type=float, nargs="+", default=[1.0, 3.0, 10.0], help="rad/s^2")
    p.add_argument("--gate", type=float, default=None, help="deadband gate d0 = d_g (rad)")
    p.add_argument("--disturbance", nargs="+", default=["impulse"], help="none | preset[:level]")
    p.add_argument("--seeds", type=int, nargs="+", default=[1000, 1001, 1002, 1003])
    args = p.parse_args(argv)
    results = []
    print("| disturbance | α (rad/s²) | gate (rad) | base (rad) | probe (rad) | × base |")
    print("|---|---:|---:|---:|---:|---:|")
    for dist in args.disturbance:
        text = dist if dist == "none" or ":" in dist else f"{dist}:1.0"
        for alpha in args.alpha:
            r = probe(args.env_id, args.base, args.base_gains, args.control_hz, args.episode_s,
                      text, alpha, args.gate, args.seeds)  # fmt: skip
            results.append(r)
            print(f"| {text} | {alpha:g} | {args.gate or '—'} | {r.base_rms:.3e} | "
                  f"{r.probe_rms:.3e} | {r.ratio:.2f} |", flush=True)  # fmt: skip
    return results


if __name__ == "__main__":
    main()
