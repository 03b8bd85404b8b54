"""How often the heading-bias calibration gate fires on synthetic residuals without a bias
(issue 37; :func:`sonarmap.team.calibration.gated_bias`).

Each draw: ``n`` edge lengths uniform in 0.5-1 m and heading residuals that are AR(1)
noise along the route (lag-one correlation ``--phi``, 0.01 rad standard deviation), as an
optimised graph's are, with no bias. One JSON row per ``n``: the fraction of draws the
gate applies a bias (its nominal level is 4.6 %), and the same for the ordinary error
alone at the normal's 2 standard errors, for comparison.

Usage::

    python -m benchmarks.calibration_gate_null [--sizes 300 1000] [--draws 1500]
        [--phi 0.9] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from sonarmap.team.calibration import SIGNIFICANCE, bias_fit, gated_bias


def ar1(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    """AR(1) noise of ``n`` values, lag-one correlation ``phi``, standard deviation
    0.01 (radians)."""
    eps = rng.normal(0.0, 0.01 * math.sqrt(1 - phi**2), n)
    out = np.empty(n)
    out[0] = rng.normal(0.0, 0.01)
    for t in range(1, n):
        out[t] = phi * out[t - 1] + eps[t]
    return out


def null_rate(n: int, draws: int, phi: float, seed: int) -> dict[str, float]:
    """The gate's and the ordinary error's firing rates over ``draws`` draws of ``n``
    edges (see the module's docstring)."""
    rng = np.random.default_rng(seed)
    fired = fired_iid = 0
    for _ in range(draws):
        d = rng.uniform(0.5, 1.0, n)
        fit = bias_fit(d, ar1(rng, n, phi))
        fired += gated_bias(0.0, fit) != 0.0
        fired_iid += abs(fit.step) > SIGNIFICANCE * fit.stderr_iid
    return {
        "edges": n,
        "draws": draws,
        "phi": phi,
        "seed": seed,
        "gate_rate": fired / draws,
        "iid_rate": fired_iid / draws,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", type=int, default=[300, 1000])
    ap.add_argument("--draws", type=int, default=1500)
    ap.add_argument("--phi", type=float, default=0.9)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    if not 0.0 <= a.phi < 1.0:
        ap.exit(2, f"--phi: {a.phi} is not in [0, 1)\n")
    if a.draws < 1 or min(a.sizes) < 2:
        ap.exit(2, "--draws must be at least 1 and every --sizes at least 2\n")
    for n in a.sizes:
        print(json.dumps(null_rate(n, a.draws, a.phi, a.seed)), flush=True)


if __name__ == "__main__":
    main()
