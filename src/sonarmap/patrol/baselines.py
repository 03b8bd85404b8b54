"""Patrolling policies side by side on one real map: the potential field against the
literature's baselines (issue 36, goal 6).

Every policy runs on the same territory, the same starts (spread by farthest point, by
seed) and the same patrol graph (:class:`~sonarmap.patrol.graph.PatrolGraph`, measured by
:class:`~sonarmap.patrol.monitor.Monitor` in every run, whatever the policy walks on),
for each team size and seed. A run's row holds:

- ``mean_mtb``: the mean, after the warm-up (a fifth of the run), of the worst time since
  a place was last seen, seconds;
- ``graph_avg_idleness`` and ``graph_worst_idleness``: the patrol graph's average and
  worst idleness over the visits (patrolling_sim's metrics), seconds;
- ``blocked``: the share of robot-steps whose move was cancelled;
- ``never_seen``: the share of the reachable territory never seen;
- ``unreachable``: the share of the map's free cells no robot can reach (left out);
- ``x_real``: simulated seconds per wall-clock second.

:func:`baseline_claims` checks issue 36's orderings on the means over seeds. The
benchmark ``benchmarks.patrol_indoor`` and ``sonarmap patrol experiment baselines --map``
both run through here.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from .policies import POLICIES
from .simulation import PatrolConfig, run_patrol
from .territory import Territory

__all__ = [
    "BASELINE_POLICIES",
    "INDOOR",
    "REACTIVE_BASELINES",
    "baseline_claims",
    "baseline_run",
    "baseline_table",
    "plot_baselines",
    "run_baselines",
    "table_lines",
    "write_baselines",
]

#: The policies ``patrol experiment baselines --map`` runs by default.
BASELINE_POLICIES = ("potential", "random", "reactive", "cycle", "cr", "hcr", "sebs")
#: The reactive baselines the potential field should be at least as good as.
REACTIVE_BASELINES = ("reactive", "cr", "hcr", "sebs")
#: Issue 36's indoor robots: radius (m), speed (m/s), vision (m) and cell (m).
INDOOR: Mapping[str, float] = {"radius": 0.3, "speed": 1.0, "vision": 5.0, "cell": 0.1}
#: The least ratio of the random walk's mean MTB to the potential field's.
RANDOM_RATIO = 1.3
#: The most blocked share of robot-steps allowed.
BLOCKED_MAX = 0.05

Progress = Callable[[int, int], None]


def baseline_run(
    territory: Territory,
    config: PatrolConfig,
    robots: int,
    seed: int,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """One run's row (see the module's notes) of ``config`` with ``robots`` robots
    started by ``seed``; ``progress`` as :func:`~sonarmap.patrol.simulation.run_patrol`'s."""
    t0 = time.perf_counter()
    s = run_patrol(
        territory, config, robots=robots, seed=seed, graph=True, progress=progress
    ).summary()
    wall = time.perf_counter() - t0
    g = s["graph"]
    return {
        "policy": config.policy,
        "robots": robots,
        "traffic": config.traffic,
        "seed": seed,
        "mean_mtb": s["mean_mtb"],
        "graph_avg_idleness": g["avg_idleness"],
        "graph_worst_idleness": g["worst_idleness_visits"],
        "blocked": s["blocked_share"],
        "never_seen": s["never_seen"],
        "unreachable": s["unreachable_free_share"],
        "x_real": config.duration / wall if wall > 0 else math.inf,
    }


def run_baselines(
    territory: Territory,
    base: Mapping[str, Any],
    *,
    policies: Sequence[str] = BASELINE_POLICIES,
    robots: Sequence[int] = (1, 2, 4),
    seeds: Sequence[int] = (0, 1),
    map_name: str = "",
    progress: Progress | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Every policy x team size x seed on ``territory``, one at a time.

    Parameters
    ----------
    base : mapping
        :class:`~sonarmap.patrol.simulation.PatrolConfig`'s fields shared by every run
        (the policy aside), e.g. ``{**INDOOR, "duration": 1800.0}``; settings left
        ``auto`` (motion, traffic) resolve per policy.
    policies : sequence of str
        Names from :data:`~sonarmap.patrol.policies.POLICIES`.
    robots, seeds : sequence of int
        Team sizes (>= 1) and seeds (>= 0).
    map_name : str
        The ``map`` column of the rows.
    progress : callable, optional
        Called with (simulated seconds done, in all), over all the runs.
    on_row : callable, optional
        Called with each run's row as it finishes.

    Returns
    -------
    list of dict
        The rows (:func:`baseline_run`, plus ``map``), policy by policy, then team size,
        then seed.

    Raises
    ------
    ConfigError
        An unknown policy, no policy, a team size below 1, a negative seed or a bad
        setting in ``base``.
    """
    bad = [p for p in policies if p not in POLICIES]
    if bad or not policies:
        raise ConfigError(
            f"unknown policy {bad[0]!r}; valid: {', '.join(POLICIES)}"
            if bad
            else "give at least one policy"
        )
    if not robots or min(robots) < 1:
        raise ConfigError(f"robots must be >= 1, got {list(robots)}")
    if not seeds or min(seeds) < 0:
        raise ConfigError(f"seeds must be >= 0, got {list(seeds)}")
    # Every configuration checked before the first run.
    configs = {p: PatrolConfig(**{**base, "policy": p}) for p in policies}
    grid = list(itertools.product(policies, robots, seeds))
    steps = round(configs[policies[0]].duration / configs[policies[0]].dt)
    total = len(grid) * steps
    rows = []
    for k, (policy, n, seed) in enumerate(grid):

        def step(done: int, _: int, k: int = k) -> None:
            # Every 20th step: a bar redrawn every step costs more than the step.
            if progress is not None and (done % 20 == 0 or done == steps):
                progress(k * steps + done, total)

        row = {"map": map_name, **baseline_run(territory, configs[policy], n, seed, step)}
        rows.append(row)
        if on_row is not None:
            on_row(row)
    return rows


def baseline_table(rows: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per map, policy, traffic rule and team size, in the rows' order: the mean over
    seeds of mean MTB and the graph's idleness, the worst seed's blocked and never-seen
    shares, and the seeds' mean MTB each."""
    groups: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["map"], r["policy"], r["traffic"], r["robots"]), []).append(r)
    out = []
    for (m, policy, traffic, n), runs in groups.items():
        out.append(
            {
                "map": m,
                "policy": policy,
                "traffic": traffic,
                "robots": n,
                "mean_mtb": _mean(r["mean_mtb"] for r in runs),
                # Runs recorded before the graph was measured in every run have none.
                "graph_avg_idleness": _mean(r.get("graph_avg_idleness", math.nan) for r in runs),
                "graph_worst_idleness": _mean(
                    r.get("graph_worst_idleness", math.nan) for r in runs
                ),
                "blocked": max(r["blocked"] for r in runs),
                "never_seen": max(r["never_seen"] for r in runs),
                "seeds_mtb": [round(float(r["mean_mtb"]), 1) for r in runs],
                "runs": len(runs),
            }
        )
    return out


def _mean(values: Iterable[float]) -> float:
    v = [float(x) for x in values]
    return sum(v) / len(v) if v else math.nan


def baseline_claims(table: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Issue 36's claims on a :func:`baseline_table`, per map: the potential field's
    mean MTB at most the random walk's / 1.3 and at most every reactive baseline's,
    at every team size; per policy, the mean MTB falling as the team grows and the
    blocked share under 5 % (the worst seed); everything seen with the largest team.
    Each claim: ``claim``, ``measured`` and ``verdict`` (``holds``, ``fails`` or ``not tested``)."""
    claims: list[dict[str, Any]] = []

    def claim(text: str, measured: str, ok: bool | None) -> None:
        verdict = "not tested" if ok is None else ("holds" if ok else "fails")
        claims.append({"claim": text, "measured": measured, "verdict": verdict})

    for m in dict.fromkeys(r["map"] for r in table):
        mine = [r for r in table if r["map"] == m]
        mtb = {(r["policy"], r["robots"]): float(r["mean_mtb"]) for r in mine}
        sizes = sorted({int(r["robots"]) for r in mine})
        pot = {n: mtb.get(("potential", n), math.nan) for n in sizes}
        for other, need in (("random", RANDOM_RATIO), *((p, 1.0) for p in REACTIVE_BASELINES)):
            pairs = [(n, mtb[(other, n)] / pot[n]) for n in sizes if (other, n) in mtb]
            pairs = [(n, q) for n, q in pairs if math.isfinite(q)]
            if not pairs or not any(math.isfinite(v) for v in pot.values()):
                continue
            text = (
                f"{m}: the potential field beats the random walk by >= {need:g}x"
                if other == "random"
                else f"{m}: the potential field is at least as good as {other}"
            )
            shown = ", ".join(f"{n}: {q:.2f}x" for n, q in pairs)
            claim(text, f"{other} / potential mean MTB: {shown}", all(q >= need for _, q in pairs))
        for policy in dict.fromkeys(r["policy"] for r in mine):
            series = [mtb[(policy, n)] for n in sizes if (policy, n) in mtb]
            if len(series) > 1:
                claim(
                    f"{m}: {policy}'s mean MTB falls as the team grows",
                    ", ".join(f"{n}: {v:.0f} s" for n, v in zip(sizes, series, strict=False)),
                    all(b < a for a, b in itertools.pairwise(series)),
                )
        for policy in dict.fromkeys(r["policy"] for r in mine):
            worst = max((r for r in mine if r["policy"] == policy), key=lambda r: r["blocked"])
            claim(
                f"{m}: {policy}'s blocked share stays under {100 * BLOCKED_MAX:g} %",
                f"worst {100 * float(worst['blocked']):.1f} % ({worst['robots']} robots)",
                float(worst["blocked"]) < BLOCKED_MAX,
            )
        big = [r for r in mine if int(r["robots"]) == sizes[-1]]
        unseen = [r["policy"] for r in big if float(r["never_seen"]) > 0]
        claim(
            f"{m}: with {sizes[-1]} robots every reachable place is seen",
            "all policies" if not unseen else "not by " + ", ".join(unseen),
            not unseen,
        )
    return claims


def plot_baselines(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Mean MTB against the team's size, one line per policy (and traffic rule, when the
    rows have several) and one panel per map: the mean over the seeds, each seed a dot.
    Written to ``path`` (PNG); returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    maps = list(dict.fromkeys(r["map"] for r in rows))
    fig, axes = plt.subplots(1, len(maps), figsize=(5.0 * len(maps), 3.8), squeeze=False)
    for ax, name in zip(axes[0], maps, strict=True):
        mine = [r for r in rows if r["map"] == name]
        lines = list(dict.fromkeys((r["policy"], r["traffic"]) for r in mine))
        several = len({t for _, t in lines}) > 1
        for policy, traffic in lines:
            runs = [r for r in mine if (r["policy"], r["traffic"]) == (policy, traffic)]
            sizes = sorted({int(r["robots"]) for r in runs})
            mean = [_mean(r["mean_mtb"] for r in runs if r["robots"] == n) for n in sizes]
            label = f"{policy}, {traffic}" if several else str(policy)
            (line,) = ax.plot(sizes, mean, marker="o", label=label)
            ax.scatter(
                [r["robots"] for r in runs],
                [r["mean_mtb"] for r in runs],
                s=10,
                color=line.get_color(),
                alpha=0.5,
            )
        ax.set_xticks(sorted({int(r["robots"]) for r in mine}))
        ax.set_xlabel("robots")
        ax.set_ylabel("mean MTB [s]")
        ax.set_ylim(bottom=0.0)
        ax.set_title(str(name))
        ax.legend(fontsize="small")
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


#: The columns of ``table.csv`` and of the printed table, with their headings.
TABLE_COLUMNS = {
    "policy": "policy",
    "robots": "robots",
    "mean_mtb": "mean MTB [s]",
    "graph_avg_idleness": "graph avg idleness [s]",
    "graph_worst_idleness": "graph worst idleness [s]",
    "blocked": "blocked (worst seed)",
    "never_seen": "never seen (worst seed)",
}


def table_lines(table: Sequence[Mapping[str, Any]]) -> list[str]:
    """A :func:`baseline_table` as Markdown lines, one table per map."""
    out: list[str] = []
    for m in dict.fromkeys(r["map"] for r in table):
        out += [f"{m}:", "| " + " | ".join(TABLE_COLUMNS.values()) + " |"]
        out.append("|" + "---|" * len(TABLE_COLUMNS))
        for r in (r for r in table if r["map"] == m):
            out.append(
                f"| {r['policy']} | {r['robots']} | {r['mean_mtb']:.1f} "
                f"| {r['graph_avg_idleness']:.1f} | {r['graph_worst_idleness']:.1f} "
                f"| {r['blocked']:.3f} | {r['never_seen']:.3f} |"
            )
    return out


def write_baselines(
    folder: str | Path, rows: Sequence[Mapping[str, Any]], settings: Mapping[str, Any]
) -> list[Path]:
    """Write the runs ``rows`` into ``folder`` (created): ``runs.csv`` and ``runs.json``
    (every run, with ``settings``), ``table.csv`` (:func:`baseline_table`),
    ``claims.json`` (:func:`baseline_claims`), ``mtb.png`` (:func:`plot_baselines`) and
    ``report.html``. Returns the files written."""
    import pandas as pd

    from ..files import atomic_write_text, json_dumps
    from ..report import Report

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    table = baseline_table(rows)
    claims = baseline_claims(table)
    atomic_write_text(out / "runs.csv", pd.DataFrame(list(rows)).to_csv(index=False))
    atomic_write_text(
        out / "runs.json", json_dumps({"settings": dict(settings), "runs": list(rows)}) + "\n"
    )
    flat = [{k: v for k, v in r.items() if k != "seeds_mtb"} for r in table]
    atomic_write_text(out / "table.csv", pd.DataFrame(flat).to_csv(index=False))
    atomic_write_text(out / "claims.json", json_dumps(claims) + "\n")
    png = plot_baselines(rows, out / "mtb.png")
    report = Report("sonarmap patrol experiment: baselines")
    report.text(
        "The potential field against the literature's baselines on one map: every policy "
        "on the same starts and patrol graph, per team size and seed (means over seeds; "
        "blocked and never seen: the worst seed)."
    )
    report.table([{TABLE_COLUMNS[k]: r[k] for k in TABLE_COLUMNS} for r in table])
    report.figure(png, "Mean MTB against the team's size, one line per policy (each seed a dot).")
    report.heading("Issue 36's claims")
    report.table(claims)
    report.parameters(dict(settings))
    report.write(out / "report.html")
    return [out / n for n in ("runs.csv", "runs.json", "table.csv", "claims.json")] + [
        png,
        out / "report.html",
    ]
