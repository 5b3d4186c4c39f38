"""The reference results page: the paper's numbers beside a run's, the rescored factor experiments
and the figures, from real run folders (the committed run of tests/data)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd

from scart_bench.reports import reference
from scart_bench.reports.results import load_runs

FIXTURE = Path(__file__).parent / "data" / "run_made_before_the_rooms"


def test_a_rescored_variant_changes_only_its_protocol(tmp_path):
    run = tmp_path / "runs" / "quick-seed0"
    shutil.copytree(FIXTURE, run)
    out = reference.rescored(run, "alpha-0.10", {"alpha": 0.10})
    proto = json.loads((out / "config.json").read_text())["identity"]["protocol"]
    assert proto["flight_rule"]["alpha"] == proto["row_rule"]["alpha"] == 0.10
    assert json.loads((run / "config.json").read_text())["identity"]["protocol"]["flight_rule"]["alpha"] == 0.05
    # the same saved scores: the flight scores agree, only the threshold moved
    a, b = (pd.read_csv(p / "flight_scores.csv").set_index("flight_id")["score"] for p in (run, out))
    pd.testing.assert_series_equal(a.sort_index(), b.sort_index())
    assert (out / "metrics.csv").is_file() and not (out / "cache").exists()


def test_the_page_puts_the_paper_beside_the_runs_with_factors_and_figures(tmp_path):
    run = tmp_path / "runs" / "quick-seed0"
    shutil.copytree(FIXTURE, run)
    runs = load_runs([run])
    variants = {name: load_runs([reference.rescored(run, name, changes)])
                for name, (_, changes) in reference.VARIANTS.items()}
    files = reference.write_page(tmp_path / "docs" / "results.md", "quick", [0], runs, variants, 60.0,
                                 "python -m scart_bench.reports.reference --profile quick --seeds 0")
    page = files[0].read_text()
    assert "| statistical | 59.7 / 86.2 / 100 |" in page  # the paper's row beside ours
    assert "flagged anywhere" in page and "alpha = 10 %" in page and "no burn-in" in page
    assert "--profile quick --seeds 0" in page  # the command that regenerates it
    assert all(f.is_file() and f.stat().st_size > 1000 for f in files[1:]) and len(files) == 3
    assert "![tp_by_family](results/tp_by_family.png)" in page
    assert "Retrained configurations (Telemanom on TensorFlow; Telemanom with its own dynamic threshold)" not in page
    assert "The gap (TP simulation - TP csv, mean over the detectors) is largest for" in page  # csv vs simulation


def test_a_retrained_configuration_runs_on_each_seeds_dataset_and_is_compared(tmp_path, monkeypatch):
    """TRAINED (e.g. Telemanom on TensorFlow): the same dataset, seed and protocol, one detector
    retrained with other parameters, and a table of both with whether they agree."""
    from run_fixtures import write_dataset

    from scart_bench.benchmark.config import RunConfig
    from scart_bench.benchmark.runner import run_benchmark

    dataset = write_dataset(tmp_path / "ds")
    run = tmp_path / "runs" / "test-seed0"
    run_benchmark(RunConfig(detectors=["statistical"], dataset=dataset, out=run, progress=False))
    monkeypatch.setattr(reference, "TRAINED", {
        "statistical-window-25": reference.Retrained("Statistical with a 25-row window", "statistical", {"window": 25}),
        "needs-a-module": reference.Retrained("a configuration whose module is missing", "statistical",
                                              needs="no_such_module_here"),
    })
    out = reference.retrained(run, "statistical-window-25", jobs=1)
    config = json.loads((out / "config.json").read_text())
    assert config["dataset"]["path"] == json.loads((run / "config.json").read_text())["dataset"]["path"]
    assert (out / "metrics.csv").is_file() and (out / "wall_s.json").is_file()
    assert reference.retrained(run, "needs-a-module", jobs=1) is None
    files = reference.write_page(tmp_path / "results.md", "quick", [0], load_runs([run]), {}, 1.0, "cmd",
                                 {"statistical-window-25": load_runs([out])})
    page = files[0].read_text()
    assert "**Statistical with a 25-row window** (`window = 25`; 1 seeds" in page
    assert "| statistical (statistical-window-25) |" in page and "Its means within the default's pooled 95 % intervals" in page


def test_flights_combining_actions_are_counted_by_how_many_they_combine(monkeypatch):
    """The paper grid's 2- and 3-scenario configurations go under 'k actions combined', with their
    flights' detections summed, so the family table stays one column per action."""
    pooled = pd.DataFrame({"detector": ["d"] * 4, "mode": ["simulation"] * 4,
                           "value": ["bias", "bias+drift", "drift+sinusoid", "bias+drift+sinusoid"],
                           "n": [10, 4, 6, 5], "detected": [5, 1, 5, 5]})
    monkeypatch.setattr(reference, "pooled_tp", lambda runs, dimension: pooled)
    fam = reference.tp_by_family([]).set_index("value")
    assert fam.loc["2 actions combined", "n"] == 10 and fam.loc["2 actions combined", "tp_rate"] == 0.6
    assert fam.loc["3 actions combined", "tp_rate"] == 1.0 and fam.loc["bias", "tp_rate"] == 0.5
    assert reference.family_order(fam.index) == ["bias", "2 actions combined", "3 actions combined"]


def test_a_retrained_configuration_can_change_the_alarm_rule(tmp_path, monkeypatch):
    """Telemanom's own dynamic threshold is a retrained configuration with a protocol change: the
    variant run carries the changed rule, the rest of the protocol is the run's."""
    from run_fixtures import write_dataset

    from scart_bench.benchmark.config import RunConfig
    from scart_bench.benchmark.runner import run_benchmark

    run = tmp_path / "runs" / "test-seed0"
    run_benchmark(RunConfig(detectors=["statistical"], dataset=write_dataset(tmp_path / "ds"), out=run, progress=False))
    assert reference.TRAINED["telemanom-own-threshold"].protocol == {"alarm_rule": "own"}
    monkeypatch.setattr(reference, "TRAINED", {
        "statistical-own": reference.Retrained("Statistical, own alarms", "statistical", protocol={"alarm_rule": "own"})})
    out = reference.retrained(run, "statistical-own", jobs=1)
    before, after = (json.loads((p / "config.json").read_text())["protocol"] for p in (run, out))
    assert before["alarm_rule"] == "calibrated" and after["alarm_rule"] == "own"
    assert {k: v for k, v in after.items() if "alarm" not in k} == {k: v for k, v in before.items() if "alarm" not in k}
    page = reference.write_page(tmp_path / "results.md", "quick", [0], load_runs([run]), {}, 1.0, "cmd",
                                {"statistical-own": load_runs([out])})[0].read_text()
    assert "**Statistical, own alarms** (`alarm_rule = 'own'`; 1 seeds" in page


def test_the_other_profiles_runs_in_the_runs_folder_give_the_grid_comparison(tmp_path, monkeypatch):
    """A paper-profile page shows the quick profile's runs found beside it, per detector, with each
    profile's flight counts; runs missing a paper detector are not taken for finished."""
    monkeypatch.setattr(reference, "PAPER", {"statistical": reference.PAPER["statistical"]})
    root = tmp_path / "runs"
    for name in ("paper-seed0", "quick-seed0", "quick-seed1", "quick-seed2"):
        shutil.copytree(FIXTURE, root / name)
    (root / "quick-seed2" / "metrics.csv").write_text("detector,status\nrdp,OK\n")  # not finished
    (root / "quick-seed10.alpha").mkdir()  # not a run of the profile
    found = reference.other_profiles(root, "paper")
    assert list(found) == ["quick"] and [p.name for p in found["quick"]] == ["quick-seed0", "quick-seed1"]
    others = {k: load_runs(v) for k, v in found.items()}
    page = reference.write_page(tmp_path / "results.md", "paper", [0], load_runs([root / "paper-seed0"]), {}, 1.0,
                                "cmd", None, others)[0].read_text()
    table = page[page.index("**Grid composition"):]
    assert "| Detector | quick (" in table and "2 seeds) | paper (" in table and "1 seed) |" in table
    assert "| statistical | " in table
    assert "they are on the quick profile's page ([results-quick.md](results-quick.md))" in page  # not retrained here
    assert "Every flight of the paper profile flies the paper's 30 m square on the 3DR Iris" in page  # and says why


def test_attacks_that_changed_no_value_keep_their_detectability_column(tmp_path):
    """breakdown.csv's "n/a" bin reads back as NaN: the page still counts those flights, in their own
    column, and the per-bin table gives each detector's TP per bin."""
    run = tmp_path / "runs" / "quick-seed0"
    shutil.copytree(FIXTURE, run)
    b = pd.read_csv(run / "breakdown.csv", keep_default_na=False)
    na = b[b["dimension"] == "detectability_bin"].assign(value="n/a", n=3, detected=1)
    pd.concat([b, na]).to_csv(run / "breakdown.csv", index=False)
    page = reference.write_page(tmp_path / "results.md", "quick", [0], load_runs([run]), {}, 1.0,
                                "cmd")[0].read_text()
    table = page[page.index("## Per detectability bin"):]
    assert "| Detector | 3-10 sd (2) | n/a (3) |" in table and "| statistical | " in table
    assert "| statistical | 50.0 | 33.3 |" in table  # 1 of 2 flights at 3-10 sd, 1 of 3 with no value changed


def test_the_strength_line_names_who_catches_the_strong_attacks():
    """The verdict on strong attacks (>= 10 sd) names the detectors at 99 % or more, or the best one."""
    def pooled(rates):
        rows = [{"detector": d, "value": b, "mode": "all", "n": 1000, "detected": int(1000 * r)}
                for d, r in rates.items() for b in (">=10 sd", "<1 sd")]
        return reference._summed(pd.DataFrame(rows))

    rule = pd.DataFrame(index=[])
    line = next(x for x in reference.why([], rule, pooled({"rdp": 0.994, "goad": 0.97}), pd.DataFrame())
                if "strength" in x)
    assert "rdp catches 99 % or more of the attacks that move a field by 10" in line and "goad" not in line
    line = next(x for x in reference.why([], rule, pooled({"rdp": 0.90, "goad": 0.97}), pd.DataFrame())
                if "strength" in x)
    assert "no detector catches 99 % of the attacks" in line and "(the best, goad: 97.0 %)" in line


def test_an_interrupted_run_is_resumed_not_reused_as_complete(tmp_path, monkeypatch):
    """A run folder whose metrics list a job UNFINISHED (the run was stopped before it ran) is run again
    by the reference and zoo commands; a run whose every job finished (OK or failed) is reused."""
    from scart_bench.benchmark import reference_runs

    run = tmp_path / "quick-seed0"
    run.mkdir()
    rows = pd.DataFrame({"detector": ["statistical", "pca", "kmeans"], "status": ["OK", "ERROR", "UNFINISHED"]})
    rows.to_csv(run / "metrics.csv", index=False)
    assert reference_runs.finished(run, ["statistical", "pca"])  # an ERROR is a finished job, shown as such
    assert not reference_runs.finished(run, ["statistical", "kmeans"])
    calls = []
    monkeypatch.setattr("scart_bench.benchmark.runner.run_benchmark", lambda cfg: calls.append(cfg.detectors))
    reference_runs.run_seeds("quick", [0], 1, tmp_path, tmp_path / "data", detectors=["statistical", "kmeans"])
    assert calls == [["statistical", "kmeans"]]  # resumed
    reference_runs.run_seeds("quick", [0], 1, tmp_path, tmp_path / "data", detectors=["statistical", "pca"])
    assert calls == [["statistical", "kmeans"]]  # reused, nothing run
