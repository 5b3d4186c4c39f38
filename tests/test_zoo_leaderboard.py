"""The zoo leaderboard by one command (issue 50, acceptance 2): from an empty runs folder it makes the
datasets and runs, writes a page whose numbers recount from the runs' saved per-flight scores and job
timings, and a second invocation reruns nothing and writes the same page byte for byte."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from run_fixtures import write_dataset
from sklearn.metrics import roc_auc_score

from scart_bench.reports import zoo

DETECTORS = ["statistical", "pca", "kmeans"]
SEEDS = [0, 1]
OLD_RUN = Path(__file__).parent / "data" / "run_made_before_the_rooms"


def _fake_generator(made: list):
    """generate_dataset writing the small labelled dataset of run_fixtures (as this version's generator)."""
    from scart_bench.generator.engine.flight_batch import FLIGHT_DEFAULTS

    def generate(profile, out, seed=0, overwrite=False, **kwargs):
        made.append((profile, seed))
        if overwrite:
            shutil.rmtree(out, ignore_errors=True)
        write_dataset(Path(out), seed=seed)
        info = json.loads((Path(out) / "dataset.json").read_text())
        info["flight_defaults"] = FLIGHT_DEFAULTS
        (Path(out) / "dataset.json").write_text(json.dumps(info))
        return Path(out)

    return generate


def _table(page: str, title: str) -> pd.DataFrame:
    """The Markdown table under ``## title`` (the first one after it), cells as text, by detector."""
    part = page.split(f"## {title}\n", 1)[1]
    rows = [line for line in part.splitlines() if line.startswith("|")]
    end = next((i for i, line in enumerate(part.splitlines()) if line.startswith("## ")), None)
    if end is not None:
        rows = [line for line in part.splitlines()[:end] if line.startswith("|")]
    cells = [[c.strip() for c in r.strip("|").split(" | ")] for r in rows]
    return pd.DataFrame(cells[2:], columns=cells[0]).set_index("Detector")


def _recount(runs: Path, det: str) -> dict:
    """A detector's page figures recounted from each seed's flight_scores.csv, flights.csv and its job's
    status.json (not from metrics.csv)."""
    per_seed = []
    for seed in SEEDS:
        run = runs / f"quick-seed{seed}"
        fs = pd.read_csv(run / "flight_scores.csv")
        fs = fs[fs["detector"] == det]
        att = fs[fs["role"] == "test_attacked"]
        normal = fs[fs["role"] == "test_normal"]
        test = pd.concat([att, normal])
        status = json.loads((run / "jobs" / det / "status.json").read_text())
        flights = pd.read_csv(run / "flights.csv")
        per_seed.append({
            "tp_sim": (att[att["mode"] == "simulation"]["outcome"] == "detected").mean(),
            "tp_csv": (att[att["mode"] == "csv"]["outcome"] == "detected").mean(),
            "fa": normal["flagged"].astype(bool).mean(),
            "auc": roc_auc_score(test["role"] == "test_attacked", test["score"]),
            "fit_us": 1e6 * status["fit_seconds"] / flights.loc[flights["role"] == "train", "rows"].sum(),
            "score_us": 1e6 * status["score_seconds"] / status["rows_scored"],
        })
    df = pd.DataFrame(per_seed)
    out = {f"{k}_mean": df[k].mean() for k in df.columns} | {f"{k}_std": df[k].std(ddof=1) for k in df.columns}
    out["headline"] = (df["tp_sim"] + df["tp_csv"] + 1 - df["fa"]).mean() / 3
    return out


def test_one_command_from_an_empty_runs_folder_writes_a_page_that_recounts(tmp_path, monkeypatch):
    made: list = []
    monkeypatch.setattr("scart_bench.generator.generate.generate_dataset", _fake_generator(made))
    runs, data, out = tmp_path / "runs", tmp_path / "data", tmp_path / "docs" / "leaderboard.md"
    argv = ["--profile", "quick", "--seeds", "0,1", "--detectors", ",".join(DETECTORS), "--jobs", "1",
            "--runs", str(runs), "--data", str(data), "--out", str(out)]
    assert zoo.main(argv) == 0
    assert made == [("quick", 0), ("quick", 1)]  # the missing datasets were generated
    page = out.read_text()
    assert "python -m scart_bench.reports.zoo --profile quick --seeds 0,1 --detectors statistical,pca,kmeans" in page

    board = _table(page, "Ranking")
    assert set(board.index) == set(DETECTORS) and (board["Seeds OK"] == "2/2").all()
    recount = {det: _recount(runs, det) for det in DETECTORS}
    for det, r in recount.items():
        row = board.loc[det]
        for col, key in (("TP simulation", "tp_sim"), ("TP csv", "tp_csv"), ("False alarms", "fa")):
            assert row[col].startswith(f"{100 * r[f'{key}_mean']:.1f} ± {100 * r[f'{key}_std']:.1f} ["), (det, col)
        assert row["ROC-AUC"] == f"{r['auc_mean']:.3f} ± {r['auc_std']:.3f}", det
        assert row["Headline"] == f"{100 * r['headline']:.1f}", det
        assert float(row["Fit (us/row)"]) == pytest.approx(r["fit_us_mean"], abs=0.051), det
        assert float(row["Score (us/row)"]) == pytest.approx(r["score_us_mean"], abs=0.051), det
        assert row["Tag"] == ("paper" if det == "statistical" else "zoo")
    # ranked by the headline, best first; the rank certainty is a share and a range of ranks
    heads = [recount[d]["headline"] for d in board.index]
    assert heads == sorted(heads, reverse=True) and list(board["Rank"]) == ["1", "2", "3"]
    for _, row in board.iterrows():
        assert 0 <= int(row["Rank held"].removesuffix(" %")) <= 100
        lo, _, hi = row["Rank 95 %"].partition("-")
        assert 1 <= int(lo) <= int(row["Rank"]) <= int(hi or lo) <= 3

    # per attack family: detections pooled over the seeds, from the flights' actions
    fam = _table(page, "Per attack family")
    for det in DETECTORS:
        pooled = []
        for seed in SEEDS:
            run = runs / f"quick-seed{seed}"
            fs = pd.read_csv(run / "flight_scores.csv")
            action = pd.read_csv(run / "flights.csv").set_index("flight_id")["action"]
            fs = fs[(fs["detector"] == det) & (fs["role"] == "test_attacked")]
            pooled.append(fs.assign(action=fs["flight_id"].map(action)))
        p = pd.concat(pooled)
        for col in fam.columns:
            family = col.split(" (")[0]
            f = p[p["action"] == family]
            cells = [f"{100 * (f[f['mode'] == m]['outcome'] == 'detected').mean():.1f}" for m in ("simulation", "csv")]
            assert fam.at[det, col] == " / ".join(cells), (det, col)
    bins = _table(page, "Per detectability bin")
    n_attacked = sum(len(pd.read_csv(runs / f"quick-seed{s}" / "flight_scores.csv").query(
        "role == 'test_attacked' and detector == 'pca'")) for s in SEEDS)
    assert sum(int(c.split("(")[1].rstrip(")")) for c in bins.columns) == n_attacked

    # a second invocation: no dataset made, no job run again, the same page byte for byte
    stamps = {p: p.stat().st_mtime_ns for p in runs.glob("*/jobs/*/scores.npz")}
    assert zoo.main(argv) == 0
    assert made == [("quick", 0), ("quick", 1)]
    assert {p: p.stat().st_mtime_ns for p in runs.glob("*/jobs/*/scores.npz")} == stamps
    assert out.read_text() == page
    # a detector no run has yet is named, not shown as 0
    assert zoo.main([*argv[:5], "statistical,pca,kmeans,hbos", *argv[6:], "--render-only"]) == 0
    assert "Not in any run folder yet (no job has finished): hbos." in out.read_text()


def test_a_run_made_before_v3_is_read_from_its_v3_evaluation_or_refused(tmp_path, capsys):
    run = tmp_path / "runs" / "quick-seed0"
    shutil.copytree(OLD_RUN, run)
    out = tmp_path / "page.md"
    argv = ["--profile", "quick", "--seeds", "0", "--detectors", "statistical", "--runs", str(tmp_path / "runs"),
            "--render-only", "--out", str(out)]
    assert zoo.main(argv) == 2  # no v3 tables: refused in one line, naming the folder and the fix
    err = capsys.readouterr().err
    assert str(run) in err and "--phases ends" in err and not out.exists()

    ev = run / "evaluations" / "phases-ends"
    ev.mkdir(parents=True)
    for name in ("metrics.csv", "flight_scores.csv", "breakdown.csv"):
        shutil.copy(run / name, ev / name)
    metrics = pd.read_csv(ev / "metrics.csv")
    metrics.loc[metrics["detector"] == "statistical", "roc_auc"] = 0.123  # the page must read this one
    metrics.to_csv(ev / "metrics.csv", index=False)
    protocol = {"alarm_rule": "calibrated", "burn_in_s": 8.0, "end_transient_s": 2.0, "phases": "ends",
                "phase_margin_s": 3.0, "flight_rule": {"alpha": 0.05, "kind": "conformal", "margin": 0.05, "q": 0.999},
                "row_rule": {"alpha": 0.05, "kind": "conformal", "margin": 0.05, "q": 0.999}}
    (ev / "evaluation.json").write_text(json.dumps({"name": "phases-ends", "protocol": protocol}))
    assert zoo.main(argv) == 0
    page = out.read_text()
    assert "| statistical | paper |" in page and "| 0.123 |" in page
    assert "made before v3, read from its v3 evaluation" in page


def test_bad_input_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "page.md"
    base = ["--profile", "quick", "--runs", str(tmp_path / "runs"), "--data", str(tmp_path / "data"),
            "--out", str(out)]
    assert zoo.main([*base, "--detectors", "statistical,no_such_detector"]) == 2
    assert "no_such_detector" in capsys.readouterr().err
    assert zoo.main([*base, "--seeds", "0,x"]) == 2
    assert "--seeds" in capsys.readouterr().err
    assert zoo.main([*base, "--seeds", "0", "--timeout", "-1"]) == 2
    assert "--timeout" in capsys.readouterr().err
    assert zoo.main([*base, "--seeds", "0", "--render-only"]) == 2  # no run folder there
    assert "quick-seed0" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "runs").exists() and not (tmp_path / "data").exists()


def test_rank_certainty_separates_a_clear_order_from_a_coin_toss(tmp_path):
    """rank_table on flights where one detector catches every attack and one none (certain ranks), and
    two between them that catch as many attacks, different ones (a coin toss for 2nd and 3rd)."""
    from scart_bench.reports.results import RunResults

    ids = [f"a{i}" for i in range(40)] + [f"n{i}" for i in range(40)]
    catches = {"good": lambda i: True, "left": lambda i: i < 20, "right": lambda i: i >= 20, "bad": lambda i: False}
    rows = []
    for det, catch in catches.items():
        for i, fid in enumerate(ids):
            attacked = fid.startswith("a")
            detected = attacked and catch(i)
            rows.append({"detector": det, "flight_id": fid, "role": "test_attacked" if attacked else "test_normal",
                         "mode": ("simulation" if i % 2 else "csv") if attacked else "normal",
                         "flagged": detected, "outcome": "detected" if detected else ("missed" if attacked else ""),
                         "cluster": fid, "score": 0.0})
    pd.DataFrame(rows).to_csv(tmp_path / "flight_scores.csv", index=False)
    run = RunResults(tmp_path, "r", {}, pd.DataFrame())
    table = zoo.rank_table([run], list(catches), n_boot=400)
    assert table.at["good", "held"] == 1.0 and table.at["bad", "held"] == 1.0
    assert table.at["good", "above_next"] == 1.0 and np.isnan(table.at["bad", "above_next"])
    assert 0.3 < table.at["left", "held"] < 0.7 and 0.3 < table.at["left", "above_next"] < 0.7
    assert (table.at["left", "lo"], table.at["left", "hi"]) == (2, 3)
    assert (table.at["good", "lo"], table.at["good", "hi"]) == (1, 1)
