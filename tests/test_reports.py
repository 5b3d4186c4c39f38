"""Reports: leaderboard over runs, the HTML page in headless Chromium, escaping, and the figures.

Runs are made by the real benchmark (``scart-bench run``) on the small synthetic dataset of
:mod:`run_fixtures` with its cheap plugin detectors. The browser test drives Debian's
``chromium`` over the DevTools protocol on a pipe (``--remote-debugging-pipe``: no port, no extra
Python package); CI installs it with ``apt-get update && apt-get install -y chromium``.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from urllib.parse import unquote

import matplotlib.colors
import matplotlib.image
import numpy as np
import pandas as pd
import pytest
from run_fixtures import ATTACK_US, plugin, write_dataset

from scart_bench.benchmark.intervals import wilson
from scart_bench.cli.main import main
from scart_bench.dataset import open_dataset
from scart_bench.reports.figures import ATTACK_WINDOW_COLOUR, axes_extent, column_of, label_windows
from scart_bench.reports.leaderboard import build_leaderboard, headline

CHROMIUM = Path("/usr/bin/chromium")
APT = "apt-get update && apt-get install -y chromium"
EVIL = "<script>alert(1)</script>"
DETS = ["--plugin", plugin("ZScore"), "--plugin", plugin("Diff"), "--plugin", plugin("FailFit")]


# -- fixtures: two runs of the same configuration on two datasets ---------------------------------

@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path]:
    """Run A: zscore_test and diff_test; run B (another dataset seed): zscore_test and a detector
    that fails, so diff_test is missing from B."""
    root = tmp_path_factory.mktemp("report_runs")
    a, b = root / "runA", root / "runB"
    ds_a, ds_b = write_dataset(root / "ds0", seed=0), write_dataset(root / "ds1", seed=1)
    assert main(["run", "--profile", "quick", "--detectors", "zscore_test,diff_test", *DETS, "--dataset",
                 str(ds_a), "--out", str(a), "--jobs", "2"]) == 0
    assert main(["run", "--profile", "quick", "--detectors", "zscore_test,fail_fit_test", *DETS, "--dataset",
                 str(ds_b), "--out", str(b), "--jobs", "2"]) == 3  # a failed job
    return a, b


@pytest.fixture(scope="module")
def report(runs, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "out"
    assert main(["report", *map(str, runs), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def evil_run(runs, tmp_path_factory) -> Path:
    """Run A under a folder name with markup, its zscore_test renamed ``<script>alert(1)</script>`` in
    every results table and a plugin spec with markup in config.json. (The runner refuses such a
    name for a real job, since it cannot name a job folder; a report must still show it as text.)"""
    src = runs[0]
    dst = tmp_path_factory.mktemp("evil") / 'run<b>&"x"'
    shutil.copytree(src, dst)
    for name in ("metrics.csv", "flight_scores.csv", "breakdown.csv", "results.csv"):
        df = pd.read_csv(dst / name, keep_default_na=False, dtype=str)
        df["detector"] = df["detector"].replace("zscore_test", EVIL)
        df.to_csv(dst / name, index=False)
    config = json.loads((dst / "config.json").read_text())
    config["detectors"] = [EVIL if d == "zscore_test" else d for d in config["detectors"]]
    config["plugins"].append("<img src=x onerror=alert(2)>:Evil")
    config["name"] = dst.name
    (dst / "config.json").write_text(json.dumps(config))
    return dst


# -- a minimal DevTools client over --remote-debugging-pipe ---------------------------------------

class Chromium:
    """Headless Chromium driven over the DevTools protocol on fds 3/4 (NUL-separated JSON)."""

    def __init__(self):
        self.profile = tempfile.mkdtemp(prefix="chromium-")
        to_r, self._to_w = os.pipe()
        self._from_r, from_w = os.pipe()
        args = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                f"--user-data-dir={self.profile}", "--remote-debugging-pipe", "about:blank"]
        self._log = open(Path(self.profile) / "stderr.log", "w")  # noqa: SIM115 - closed in close()
        self.proc = subprocess.Popen(["bash", "-c", f'exec "$@" 3<&{to_r} 4>&{from_w}', "chromium", *args],
                                     pass_fds=(to_r, from_w), stdout=subprocess.DEVNULL, stderr=self._log)
        os.close(to_r)
        os.close(from_w)
        self._buf, self._id, self.events = b"", 0, []

    def _next(self, timeout: float) -> dict:
        end = time.monotonic() + timeout
        while b"\0" not in self._buf:
            ready, _, _ = select.select([self._from_r], [], [], max(0.0, end - time.monotonic()))
            if not ready:
                raise TimeoutError("chromium did not answer in time")
            chunk = os.read(self._from_r, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed the DevTools pipe")
            self._buf += chunk
        raw, _, self._buf = self._buf.partition(b"\0")
        return json.loads(raw)

    def send(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 30) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}, **({"sessionId": session} if session else {})}
        os.write(self._to_w, json.dumps(msg).encode() + b"\0")
        while True:
            m = self._next(timeout)
            if m.get("id") == self._id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m["result"]
            self.events.append(m)

    def wait_for(self, method: str, timeout: float = 30) -> None:
        end = time.monotonic() + timeout
        while not any(e.get("method") == method for e in self.events):
            self.events.append(self._next(end - time.monotonic()))

    def open(self, page: Path, expression: str) -> tuple[dict, list[str]]:
        """Load a page; return the value of a JS expression evaluated in it (by DevTools, not by the
        page) and every console error, uncaught exception, error log entry and failed load."""
        self.events = []
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        sid = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Runtime", "Log", "Page", "Network"):
            self.send(f"{domain}.enable", session=sid)
        self.send("Page.navigate", {"url": page.resolve().as_uri()}, session=sid)
        self.wait_for("Page.loadEventFired")
        res = self.send("Runtime.evaluate", {"expression": f"JSON.stringify({expression})", "returnByValue": True},
                        session=sid)
        self.send("Target.closeTarget", {"targetId": target})
        return json.loads(res["result"]["value"]), self._errors()

    def _errors(self) -> list[str]:
        out = []
        for e in self.events:
            method, p = e.get("method"), e.get("params", {})
            if method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                out.append(f"console.{p['type']}: {p.get('args')}")
            elif method == "Runtime.exceptionThrown":
                out.append(f"exception: {p.get('exceptionDetails', {}).get('text')}")
            elif method == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
                out.append(f"log: {p['entry'].get('text')}")
            elif method == "Network.loadingFailed":
                out.append(f"load failed: {p}")
            elif method == "Network.requestWillBeSent":
                url = p.get("request", {}).get("url", "")
                if not url.startswith(("data:", "file:")):
                    out.append(f"network request: {url}")
        return out

    def close(self) -> None:
        try:
            self.send("Browser.close", timeout=10)
        except (OSError, RuntimeError, TimeoutError):
            pass
        try:
            self.proc.wait(15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._to_w)
        os.close(self._from_r)
        self._log.close()
        shutil.rmtree(self.profile, ignore_errors=True)


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: the browser test needs Debian's chromium ({APT})")
    b = Chromium()
    yield b
    b.close()


PAGE_FACTS = """{
  rows: Array.from(document.querySelectorAll('table.leaderboard tbody tr')).map(r => r.dataset.detector),
  images: Array.from(document.images).map(i => ({complete: i.complete, w: i.naturalWidth, h: i.naturalHeight})),
  scripts: document.querySelectorAll('script').length,
  cells: Array.from(document.querySelectorAll('table.leaderboard td.name')).map(td => td.textContent),
  links: Array.from(document.querySelectorAll('table.runs a')).map(a => a.href),
}"""


# -- (1) the page in a real browser ------------------------------------------------------------

def test_html_report_in_headless_chromium(report, browser):
    facts, errors = browser.open(report / "leaderboard.html", PAGE_FACTS)
    assert errors == []
    assert sorted(facts["rows"]) == ["diff_test", "fail_fit_test", "zscore_test"]  # a row per detector
    assert len(facts["images"]) >= 6
    assert all(i["complete"] and i["w"] > 0 and i["h"] > 0 for i in facts["images"]), facts["images"]
    assert facts["scripts"] == 0
    for link in facts["links"]:  # every run links its config.json, and the link resolves
        assert link.startswith("file://") and link.endswith("/config.json")
        assert Path(link[len("file://"):]).is_file()


def test_report_files_are_self_contained(report):
    page = (report / "leaderboard.html").read_text()
    assert "<script" not in page and "http://" not in page and "https://" not in page
    assert page.count('src="data:image/png;base64,') == len(list((report / "figures").glob("*.png")))
    assert {p.name for p in report.iterdir()} == {"leaderboard.md", "leaderboard.csv", "leaderboard.html", "figures"}


# -- (2) two runs: both shown, their mean, missing is not zero -----------------------------------

def test_two_runs_mean_and_missing(runs, report):
    a, b = (pd.read_csv(r / "metrics.csv").set_index("detector") for r in runs)
    board = pd.read_csv(report / "leaderboard.csv").set_index("detector")
    assert build_leaderboard(list(runs)).set_index("detector")["n_runs"].to_dict() == board["n_runs"].to_dict()

    z = board.loc["zscore_test"]
    assert z["n_runs"] == 2 and z["runs"] == 2 and z["status[runA]"] == "OK" and z["status[runB]"] == "OK"
    for metric in ("roc_auc", "tp_simulation", "point_f1"):
        both = [a.loc["zscore_test", metric], b.loc["zscore_test", metric]]
        assert z[f"{metric}_mean"] == pytest.approx(np.mean(both))
        assert z[f"{metric}_std"] == pytest.approx(np.std(both, ddof=1))
    assert a.loc["zscore_test", "roc_auc"] != b.loc["zscore_test", "roc_auc"]  # a real mean of two numbers
    heads = [headline(m.reset_index()).loc[0] for m in (a, b)]
    assert z["headline_mean"] == pytest.approx(np.mean(heads))

    d = board.loc["diff_test"]  # only in run A: its mean is run A's value, not halved by a zero
    assert d["status[runB]"] == "missing" and np.isnan(d["headline[runB]"]) and d["n_runs"] == 1
    assert d["roc_auc_mean"] == pytest.approx(a.loc["diff_test", "roc_auc"])
    f = board.loc["fail_fit_test"]  # failed in run B, missing in run A: no score at all, ranked last
    assert (f["status[runA]"], f["status[runB]"], f["n_runs"]) == ("missing", "ERROR", 0)
    assert np.isnan(f["headline_mean"]) and np.isnan(f["rank"]) and board.index[-1] == "fail_fit_test"

    md = (report / "leaderboard.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| ") and "diff_test" in line)
    assert "| missing |" in row and "| 0.0 % |" not in row
    # every rate with its Wilson interval over the flights of both runs; one run's bootstrap interval
    k = sum(round(m.loc["zscore_test", "tp_simulation"] * m.loc["zscore_test", "n_simulation"]) for m in (a, b))
    n = a.loc["zscore_test", "n_simulation"] + b.loc["zscore_test", "n_simulation"]
    assert (z["tp_simulation_lo"], z["tp_simulation_hi"]) == pytest.approx(wilson(k, n))
    assert z["tp_simulation_n"] == n
    assert (d["roc_auc_lo"], d["roc_auc_hi"]) == pytest.approx((a.loc["diff_test", "roc_auc_lo"],
                                                                a.loc["diff_test", "roc_auc_hi"]))
    zrow = next(line for line in md.splitlines() if line.startswith("| ") and "zscore_test" in line)
    lo, hi = wilson(k, n)
    assert f" \\[{100 * lo:.0f}-{100 * hi:.0f}\\] |" in zrow  # brackets escaped for Markdown
    links = re.findall(r"\[config\.json\]\(([^)]+)\)", md)
    assert len(links) == 2 and all((report / unquote(link)).resolve() == (run / "config.json").resolve()
                                   for link, run in zip(links, runs))
    page = (report / "leaderboard.html").read_text()
    assert "runA" in page and "runB" in page and '<td class="missing">missing</td>' in page
    assert '<td class="failed">ERROR</td>' in page and "boom in fit" in page


# -- (3) markup in names is shown as text ------------------------------------------------------

def test_markup_in_names_is_escaped(evil_run, runs, tmp_path, browser):
    out = tmp_path / "evil-report"
    assert main(["report", str(evil_run), str(runs[1]), "--out", str(out)]) == 0
    page = (out / "leaderboard.html").read_text()
    assert EVIL not in page and "<script" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert "<img src=x" not in page and "&lt;img src=x onerror=alert(2)&gt;" in page
    assert 'run<b>' not in page and "run&lt;b&gt;&amp;&quot;x&quot;" in page
    md = (out / "leaderboard.md").read_text()
    assert EVIL not in md and "&lt;script&gt;alert(1)&lt;/script&gt;" in md
    facts, errors = browser.open(out / "leaderboard.html", PAGE_FACTS)
    assert errors == [] and facts["scripts"] == 0
    assert EVIL in facts["cells"]  # the browser shows the name as literal text
    assert all(i["w"] > 0 for i in facts["images"])


# -- (4) the figures of one attacked flight ----------------------------------------------------

def _window_colour_columns(png: Path) -> tuple[np.ndarray, dict]:
    """Per pixel column of the axes, the fraction of its rows painted in the attack-window colour."""
    img = matplotlib.image.imread(png)[..., :3]
    ext = axes_extent(png)
    top, bottom = (int(round(v)) for v in ext["y_pixels"])
    want = np.array(matplotlib.colors.to_rgb(ATTACK_WINDOW_COLOUR))
    match = np.all(np.abs(img[top + 2:bottom - 2] - want) < 0.02, axis=2)
    return match.mean(axis=0), ext


@pytest.mark.parametrize("kind", ["trace", "score"])
def test_attack_window_is_shaded_where_the_labels_say(runs, tmp_path, kind):
    config = json.loads((runs[0] / "config.json").read_text())
    flight_dir = Path(config["dataset"]["path"]) / "flights" / "sim-000"
    out = tmp_path / "plots"
    assert main(["plot", str(flight_dir), "--run", str(runs[0]), "--detector", "zscore_test", "--out", str(out)]) == 0
    names = sorted(p.name for p in out.glob("*.png"))
    assert [n.split("_")[0] for n in names] == ["path", "score", "trace"]
    assert all(matplotlib.image.imread(out / n).shape[1] > 100 for n in names)

    nav = open_dataset(flight_dir.parent.parent).flight("sim-000")
    (start, end), = label_windows(nav["Timestamp"].to_numpy(), nav["Is_Anomaly"].to_numpy())
    ts, labelled = nav["Timestamp"].to_numpy(), nav["Is_Anomaly"].to_numpy() == 1
    assert start == ts[labelled].min() and end == ts[ts > ts[labelled].max()].min()
    assert (start, end) == ATTACK_US
    frac, ext = _window_colour_columns(next(out.glob(f"{kind}_*.png")))
    left, right = (int(round(v)) for v in ext["x_pixels"])
    c0, c1 = column_of(ext, start / 1e6), column_of(ext, end / 1e6)
    cols = np.arange(frac.size)
    inside = (cols > c0 + 2) & (cols < c1 - 2)
    outside = ((cols < c0 - 2) | (cols > c1 + 2)) & (cols > left + 2) & (cols < right - 2)
    assert inside.sum() > 100 and outside.sum() > 300
    assert frac[inside].min() > 0.5  # shaded from top to bottom, apart from the curves drawn over it
    assert frac[outside].max() == 0.0  # and nowhere else


# -- bad input ---------------------------------------------------------------------------------

def test_bad_input_is_a_usage_error(runs, tmp_path, capsys):
    empty = tmp_path / "not-a-run"
    empty.mkdir()
    shutil.copy(runs[0] / "config.json", empty / "config.json")
    assert main(["report", str(runs[0]), str(empty), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert str(empty) in err and "metrics.csv" in err
    assert main(["report", str(tmp_path / "nope"), "--out", str(tmp_path / "r")]) == 2
    assert str(tmp_path / "nope") in capsys.readouterr().err

    config = json.loads((runs[0] / "config.json").read_text())
    dataset = Path(config["dataset"]["path"])
    for bad in (dataset, tmp_path, dataset / "flights" / "no-such-flight"):
        assert main(["plot", str(bad), "--out", str(tmp_path / "p")]) == 2
        assert str(bad) in capsys.readouterr().err
    flight = dataset / "flights" / "normal-000"  # a training flight: never scored
    assert main(["plot", str(flight), "--run", str(runs[0]), "--detector", "zscore_test",
                 "--out", str(tmp_path / "p")]) == 2
    assert "normal-000" in capsys.readouterr().err
    assert main(["plot", str(flight), "--detector", "zscore_test"]) == 2
    assert "--run" in capsys.readouterr().err


# -- how certain a rank is ----------------------------------------------------------------------

def _flight_scores_run(tmp_path: Path, outcomes: dict[str, tuple[list[bool], list[bool]]]):
    """A run folder holding only flight_scores.csv: per detector, (detected per attacked flight,
    flagged per normal test flight); 20 simulation, 20 csv (4 copies per source) and 20 normal flights."""
    from scart_bench.reports.results import RunResults

    rows = []
    for det, (detected, flagged) in outcomes.items():
        for i, hit in enumerate(detected):
            mode = "simulation" if i < 20 else "csv"
            cluster = f"cfg{i}" if mode == "simulation" else f"src{(i - 20) // 4}"
            rows.append(dict(detector=det, flight_id=f"{mode}-{i}", role="test_attacked", mode=mode, score=1.0,
                             flagged=hit, outcome="detected" if hit else "missed", cluster=cluster))
        for i, fl in enumerate(flagged):
            rows.append(dict(detector=det, flight_id=f"normal-{i}", role="test_normal", mode="normal", score=1.0,
                             flagged=fl, outcome="", cluster=f"normal-{i}"))
    tmp_path.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(tmp_path / "flight_scores.csv", index=False)
    return RunResults(tmp_path, tmp_path.name, {}, pd.DataFrame())


def test_a_clear_winner_holds_its_rank_and_a_coin_toss_does_not(tmp_path):
    from scart_bench.reports.leaderboard import rank_certainty

    clear = _flight_scores_run(tmp_path / "clear", {
        "good": ([True] * 40, [False] * 20), "bad": ([False] * 40, [True] * 20)})
    assert rank_certainty([clear], ["good", "bad"]) == {"good": 1.0, "bad": 1.0}
    # a detects 25 of 40 attacked flights, b 24 others: one flight apart, the order is not settled
    a, b = [i < 25 for i in range(40)], [i >= 16 for i in range(40)]
    toss = _flight_scores_run(tmp_path / "toss", {"a": (a, [False] * 20), "b": (b, [False] * 20)})
    held = rank_certainty([toss], ["a", "b"])
    assert 0.3 < held["a"] < 0.9, held


def test_leaderboard_shows_how_certain_each_rank_is(runs, report):
    board = build_leaderboard([runs[0]])
    assert board["rank_certainty"].between(0, 1).all()
    # two detectors: whenever the first keeps its rank, so does the second
    assert board["rank_certainty"].iloc[0] == board["rank_certainty"].iloc[1]
    assert "Rank held" in (report / "leaderboard.md").read_text()
