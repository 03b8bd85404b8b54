"""Experiments, reports, compare and sweeps."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from html import unescape
from pathlib import Path

import pandas as pd
import pytest

from sonarmap import experiments
from sonarmap.cli import main
from sonarmap.errors import ConfigError, InputError
from sonarmap.experiments import EXPERIMENTS, METHODS, MethodSpec, run_experiment
from sonarmap.sweep import load_sweep, run_sweep, summarise


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        main(args)
        code = 0
    except SystemExit as e:
        code = int(e.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def doorways_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("exp") / "doorways"
    run_experiment("doorways", out, quick=True)
    return out


@pytest.mark.slow
def test_doorways_experiment_outputs(doorways_report: Path) -> None:
    d = doorways_report
    for name in ("report.html", "metrics.csv", "metrics.json", "doorways.png"):
        assert (d / name).is_file(), name
    rows = json.loads((d / "metrics.json").read_text())  # strict JSON: no NaN
    assert [r["method"] for r in rows] == [m.label for m in METHODS]
    html = (d / "report.html").read_text()
    assert html.count("<img ") == 1
    assert "data:image/png;base64," in html
    assert "tuned inverse" in html
    assert "held-out &#x27;corridor&#x27; scenes, seeds 1000 to 1000" in html
    assert '"seed": 1000' in unescape(html)
    assert all(r["seed"] == 1000 for r in rows)
    summary = json.loads((d / "summary.json").read_text())
    assert [r["method"] for r in summary] == [m.label for m in METHODS]


@pytest.mark.slow
def test_compare_agrees_with_the_experiment(
    doorways_report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sonarmap.scenarios import make_scenario

    scene = make_scenario("corridor", seed=1000)
    scene.write(tmp_path / "a-scene-folder-with-a-name-long-enough-to-wrap-a-terminal-title")
    truth = tmp_path / "a-scene-folder-with-a-name-long-enough-to-wrap-a-terminal-title"
    maps = sorted((doorways_report / "maps").glob("*.yaml"))
    code, out, err = run(
        ["compare", str(truth / "truth.yaml"), *map(str, maps), "--json", str(tmp_path / "c.json")],
        capsys,
    )
    assert code == 0, err
    assert f"{len(scene.passages)} passages, 0 small obstacles" in out
    got = {Path(r["map"]).stem: r for r in json.loads((tmp_path / "c.json").read_text())}
    for r in json.loads((doorways_report / "metrics.json").read_text()):
        g = got[r["method"]]
        assert g["passages"] == len(scene.passages)
        for key in ("f1", "f1_all", "passage_f1", "width_error"):
            assert g[key] == pytest.approx(r[key], nan_ok=True)
        for key in ("passages_open", "passages_detected", "false_openings"):
            assert g[key] == r[key]


@pytest.mark.parametrize("name", [n for n in EXPERIMENTS if n not in ("doorways", "real")])
@pytest.mark.slow
def test_other_experiments_quick(name: str, tmp_path: Path) -> None:
    report = run_experiment(name, tmp_path, quick=True)
    html = report.read_text()
    assert html.count("<img ") >= 1
    assert "<table>" in html
    assert json.loads((tmp_path / "metrics.json").read_text())
    if name == "passages":
        summary = json.loads((tmp_path / "summary.json").read_text())
        by = {r["method"]: r for r in summary}
        assert set(by) == {m.label for m in METHODS}
        assert all(r["passages"] == 5 for r in summary)  # one quick scene of five gaps
        per = json.loads((tmp_path / "passages.json").read_text())
        assert {r["seed"] for r in per} == {1000}
    if name == "boxes":  # thesis 002's two maps, its stochastic set among the methods
        rows = json.loads((tmp_path / "metrics.json").read_text())
        assert {r["map"] for r in rows} == {"layout1", "layout2"}
        assert "stochastic-thesis002" in {r["method"] for r in rows}
        assert (tmp_path / "boxes-layout2.png").is_file()


def test_an_experiment_maps_the_methods_it_is_given(tmp_path: Path) -> None:
    specs = [MethodSpec("inv", "inverse"), MethodSpec("inv-flat", "inverse", {"falloff_deg": 0.0})]
    before = experiments.METHODS
    run_experiment("passages", tmp_path / "a", quick=True, methods=specs)
    rows = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert [r["method"] for r in rows] == ["inv", "inv-flat"]
    assert sorted(p.name for p in (tmp_path / "a" / "maps" / "seed1000").glob("*.yaml")) == [
        "inv-flat.yaml",
        "inv.yaml",
    ]
    # The two settings map differently, and the module's list is left as it was.
    assert rows[0]["f1_all"] != rows[1]["f1_all"]
    assert experiments.METHODS is before
    for bad in ([], [specs[0], MethodSpec("inv", "counting")]):
        with pytest.raises(ConfigError, match="methods: want one or more distinct labels"):
            run_experiment("passages", tmp_path / "b", quick=True, methods=bad)
    assert not (tmp_path / "b").exists()


def test_unknown_experiment(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(["experiment", "magic", "-o", str(tmp_path)], capsys)
    assert code == 2
    assert "Invalid value for 'name'" in err
    code, _, err = run(["experiment", "real", "-o", str(tmp_path)], capsys)
    assert code == 2
    assert "experiment 'real' needs a log (--log)" in err
    code, _, err = run(["experiment", "doorways", "--log", "x.log", "-o", str(tmp_path)], capsys)
    assert code == 2
    assert "--log and --rig belong to the 'real' experiment" in err


SMALL = """
scenarios:
  tiny: {scenario: doorways, size: 4.0, corridor_width: 1.6, door_widths: [0.8], speed: 0.5}
seeds: [0]
metrics: [f1, width_error]
methods:
  inverse: {p_occ: [0.55, 0.6]}
  counting: {}
"""


def test_sweep_file_errors(tmp_path: Path) -> None:
    cases = [
        (
            "scenarios: {doorways: {}}\nmethods: {inverse: {bogus: [1]}}\n",
            r"methods.inverse: unknown parameter 'bogus'; valid: p_occ",
        ),
        ("scenarios: {doorways: {}}\nmethods: {magic: {}}\n", r"unknown method 'magic'"),
        (
            "scenarios: {atrium: {}}\nmethods: {inverse: {}}\n",
            r"scenarios.atrium: unknown scenario",
        ),
        (
            "scenarios: {doorways: {}}\nmethods: {inverse: {p_occ: [2.0]}}\n",
            r"parameter 'p_occ' must be in \(0.5, 1.0\)",
        ),
        (
            "scenarios: {doorways: {}}\nmethods: {inverse: {}}\nmetrics: [speed]\n",
            r"unknown metric\(s\) \['speed'\]",
        ),
        ("methods: {inverse: {}}\n", r"missing key 'scenarios'"),
        (
            "scenarios: {gaps: {}}\nmethods: {inverse: {}}\n",
            r"scenarios.gaps: scene family 'gaps' is held out for testing",
        ),
        (
            "scenarios: {doorways: {}}\nseeds: [0, 1000]\nmethods: {inverse: {}}\n",
            r"scenarios.doorways: seed 1000 is held out for testing",
        ),
        (
            "scenarios: {d: {scenario: doorways, model: {kind: sonic}}}\nmethods: {inverse: {}}\n",
            r"scenarios.d.model: kind must be acoustic or thrun",
        ),
    ]
    for text, match in cases:
        (tmp_path / "s.yaml").write_text(text)
        with pytest.raises(InputError, match=match):
            load_sweep(tmp_path / "s.yaml")


@pytest.mark.slow
def test_sweep_on_a_local_cluster_via_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "s.yaml").write_text(SMALL)
    code, out, err = run(
        ["sweep", str(tmp_path / "s.yaml"), "-o", str(tmp_path / "res"), "--workers", "1"], capsys
    )
    assert code == 0, err
    df = pd.read_parquet(tmp_path / "res" / "results.parquet")
    # inverse: its defaults and two settings; counting: its defaults.
    assert len(df) == 4
    assert set(df["method"]) == {"inverse", "counting"}
    best = pd.read_csv(tmp_path / "res" / "best.csv")
    assert set(best["metric"]) == {"f1", "width_error"}
    assert "best parameters" in out


@pytest.mark.slow
def test_sweep_on_a_scheduler_address(tmp_path: Path) -> None:
    from dask.distributed import LocalCluster

    (tmp_path / "s.yaml").write_text(SMALL)
    cfg = load_sweep(tmp_path / "s.yaml")
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        df = run_sweep(cfg, scheduler=cluster.scheduler_address)
    assert len(df) == 4
    best = summarise(df, ["f1"])
    inverse = df[df["method"] == "inverse"]
    top = inverse.sort_values("f1", kind="stable").iloc[-1]["params"]
    assert best[best["method"] == "inverse"]["best_params"].item() == top


@pytest.mark.slow
def test_sweep_unreachable_scheduler(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "s.yaml").write_text(SMALL)
    code, _, err = run(
        [
            "sweep",
            str(tmp_path / "s.yaml"),
            "-o",
            str(tmp_path / "r"),
            "--scheduler",
            "tcp://127.0.0.1:9",
        ],
        capsys,
    )
    assert code == 2
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in err
    assert not (tmp_path / "r").exists()


def _browser() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.mark.skipif(
    _browser() is None, reason="no Chromium on this machine (.ci/run installs Debian's chromium)"
)
@pytest.mark.slow
def test_report_in_headless_chromium(doorways_report: Path, tmp_path: Path) -> None:
    browser = _browser()
    assert browser is not None
    cmd = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--virtual-time-budget=10000",
        "--dump-dom",
        (doorways_report / "report.html").resolve().as_uri(),
    ]
    proc = subprocess.run(
        cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "HOME": str(tmp_path)}
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    body = re.search(r"<body([^>]*)>", proc.stdout)
    assert body is not None, proc.stdout[:500]
    attrs = dict(re.findall(r'([\w-]+)="([^"]*)"', body.group(1)))
    assert int(attrs["data-figures"]) >= 1
    assert attrs["data-figures-loaded"] == attrs["data-figures"]
    assert int(attrs["data-tables"]) >= 1


@pytest.mark.slow
def test_passages_experiment_on_a_scene_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sonarmap.scenarios import make_scenario

    # A scene folder as a user would bring it: written files, not a built-in name.
    make_scenario("passages", widths=(0.3, 0.7), posts=(0.1,)).write(tmp_path / "mine")
    (tmp_path / "mine" / "readings.csv").unlink()  # readings come from the trajectory
    code, _, err = run(
        [
            "experiment",
            "passages",
            "--quick",
            "--scene",
            str(tmp_path / "mine"),
            "-o",
            str(tmp_path / "exp"),
        ],
        capsys,
    )
    assert code == 0, err
    summary = {r["method"]: r for r in json.loads((tmp_path / "exp" / "summary.json").read_text())}
    assert summary["stochastic"]["passages"] == 2
    rows = json.loads((tmp_path / "exp" / "metrics.json").read_text())
    code, _, err = run(
        [
            "compare",
            str(tmp_path / "mine" / "truth.yaml"),
            *map(str, sorted((tmp_path / "exp" / "maps" / "seed0").glob("*.yaml"))),
            "--json",
            str(tmp_path / "cmp.json"),
        ],
        capsys,
    )
    assert code == 0, err
    got = {Path(r["map"]).stem: r for r in json.loads((tmp_path / "cmp.json").read_text())}
    for r in rows:
        assert got[r["method"]]["passages_detected"] == r["passages_detected"]
        assert got[r["method"]]["size_error"] == pytest.approx(r["size_error"], nan_ok=True)


@pytest.mark.slow
def test_experiment_scene_parameters(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(
        [
            "experiment",
            "passages",
            "--quick",
            "--param",
            "widths=0.3,0.6",
            "-o",
            str(tmp_path / "exp"),
        ],
        capsys,
    )
    assert code == 0, err
    per = json.loads((tmp_path / "exp" / "passages.json").read_text())
    assert sorted({r["true_width"] for r in per}) == [0.3, 0.6]
    code, _, err = run(
        [
            "experiment",
            "doorways",
            "--scene",
            str(tmp_path),
            "--param",
            "size=5",
            "-o",
            str(tmp_path / "x"),
        ],
        capsys,
    )
    assert code == 2
    assert "either a scene folder or scene parameters" in err
