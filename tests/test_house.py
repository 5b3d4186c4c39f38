"""The house: the terminal table fits a terminal, ``--wide`` prints every column (issue 49)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from scart_bench.benchmark.results import paper_table
from scart_bench.benchmark.tables import PAPER_COLUMNS
from scart_bench.cli.common import terminal_table
from scart_bench.cli.main import main
from scart_bench.detectors.registry import BUILTINS

FIXTURE = Path(__file__).parent / "data" / "run_made_before_the_rooms"


def _quick_table() -> pd.DataFrame:
    """A metrics table as the quick profile's run makes it, every detector at its widest numbers."""
    rows = []
    for name in BUILTINS:  # the paper's eight and the zoo
        row = {"detector": name, "status": "OK", "message": ""}
        for _, key, _ in PAPER_COLUMNS:
            row |= {key: 1.0, f"{key}_lo": 1.0, f"{key}_hi": 1.0, f"{key}_prior": 0.5}
        row["delay_median_s"] = 123.45
        rows.append(row)
    rows[-1] |= {"status": "TIMEOUT", "message": "ran past 600 s"}
    return pd.DataFrame(rows)


def test_terminal_table_fits_a_120_column_terminal():
    table = terminal_table(_quick_table())
    lines = table.splitlines()
    assert len(lines) == 2 + len(BUILTINS)
    assert all(len(line) <= 120 for line in lines), max(lines, key=len)
    columns = [c.strip() for c in lines[0].strip("|").split("|")]
    assert len(columns) <= 10
    assert columns == ["Detector", "TP Simulation", "TP CSV", "TN No Attack", "False alarms", "ROC-AUC", "Status"]
    assert "| 100.0 % [100-100] |" in lines[2]
    assert len({len(line) for line in lines}) == 1  # aligned: every row as wide as the header
    assert "TIMEOUT" in lines[-1]


def test_wide_gives_the_paper_table_with_every_column():
    metrics = _quick_table()
    assert terminal_table(metrics, wide=True) == paper_table(metrics)
    head = [c.strip() for c in paper_table(metrics).splitlines()[0].strip("|").split("|")]
    assert head == ["Detector", *(c[0] for c in PAPER_COLUMNS), "Status"]


def test_score_prints_the_terminal_table_and_wide_every_column(tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(FIXTURE, run)
    assert main(["score", str(run)]) == 0
    short = capsys.readouterr().out.splitlines()
    assert main(["score", str(run), "--wide"]) == 0
    wide = capsys.readouterr().out.splitlines()
    assert short[0].startswith("| Detector    | TP Simulation |") and len(short[0]) <= 120
    assert wide[0] == paper_table(pd.read_csv(run / "metrics.csv")).splitlines()[0]
    assert "| Flagged anywhere CSV |" in wide[0] and "Flagged anywhere" not in short[0]
    assert short[3:] == wide[3:]  # the operating-point lines below the table are the same


def test_building_the_parser_imports_no_heavy_library():
    """``scart-bench --help`` starts in a fraction of a second: the parser imports no torch, numba, pandas,
    numpy or the generator's engine (each command imports what it needs when it runs)."""
    import json
    import subprocess
    import sys

    heavy = ("torch", "numba", "pandas", "numpy", "scart_bench.generator.engine", "scart_bench.benchmark.protocol")
    code = ("import json, sys\nfrom scart_bench.cli.main import build_parser\nbuild_parser()\n"
            f"print(json.dumps([m for m in {heavy!r} if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out) == []


def test_the_parsers_choices_are_the_librarys():
    from scart_bench.benchmark.protocol import DEFAULT_PHASE_MARGIN_S, PHASE_RULES
    from scart_bench.cli import common
    from scart_bench.generator.defense import RESPONSES
    from scart_bench.generator.mavlink import DEFAULT_FORWARD, DEFAULT_LISTEN

    assert (common.PHASE_RULES, common.DEFAULT_PHASE_MARGIN_S) == (PHASE_RULES, DEFAULT_PHASE_MARGIN_S)
    assert common.RESPONSES == RESPONSES
    assert (common.PROXY_LISTEN, common.PROXY_FORWARD) == (DEFAULT_LISTEN, DEFAULT_FORWARD)


def _in_a_thread(fn, stop, after_s: float = 0.5):
    """Run ``fn`` in a thread (not the main one: no signal handlers), set ``stop`` after ``after_s``; its result."""
    import threading
    import time

    out: dict = {}
    thread = threading.Thread(target=lambda: out.setdefault("result", fn()))
    thread.start()
    time.sleep(after_s)
    stop.set()
    thread.join(30)
    assert not thread.is_alive()
    return out["result"]


def test_a_program_runs_a_live_proxy_and_a_sitl_vehicle_without_the_command_line():
    """The live loops are library functions (issue 49): started from a thread, stopped by an event."""
    import threading

    pytest.importorskip("pymavlink")
    from scart_bench.generator.mavlink.proxy import run_proxy
    from scart_bench.generator.scart.scenario import load_scenarios
    from scart_bench.generator.sitl.endpoint import bind_udp
    from scart_bench.generator.sitl.session import run_sitl

    scenarios = load_scenarios(Path(__file__).parents[1] / "data" / "scenarios" / "gps_spoof.toml")
    stop, lines = threading.Event(), []
    done = _in_a_thread(lambda: run_proxy(("127.0.0.1", 0), ("127.0.0.1", 9), scenarios, stop=stop,
                                          log=lines.append), stop)
    assert done.wall_s > 0 and done.stats.frames == 0 and done.path is None
    assert any(line.startswith("proxy: listening on udp:127.0.0.1:") for line in lines)
    assert any(line.startswith("proxy: stopped after") for line in lines)

    sock, stop, lines = bind_udp(("127.0.0.1", 0)), threading.Event(), []
    try:
        done = _in_a_thread(lambda: run_sitl(sock.getsockname(), [], sock=sock, speed=None, stop=stop,
                                             log=lines.append), stop)
    finally:
        sock.close()
    assert done.flown_s == 0 and done.path is None  # lockstep: no client, no step
    assert any("lockstep" in line for line in lines) and any(line.startswith("sitl: stopped") for line in lines)


def test_report_prints_a_leaderboard_that_fits_and_wide_every_column(tmp_path, capsys):
    from scart_bench.reports.leaderboard import terminal_table

    rows = [{"rank": i + 1, "detector": name, "headline_mean": 1.0,
             **{f"{k}_{s}": 1.0 for k in ("tp_simulation", "tp_csv", "tn_no_attack", "roc_auc")
                for s in ("mean", "lo", "hi")}} for i, name in enumerate(BUILTINS)]
    lines = terminal_table(pd.DataFrame(rows), []).splitlines()
    assert len(lines[0].strip("|").split("|")) <= 10 and max(map(len, lines)) <= 120, max(lines, key=len)

    assert main(["report", str(FIXTURE), "--out", str(tmp_path / "r"), "--no-figures"]) == 0
    short = capsys.readouterr().out.splitlines()
    assert main(["report", str(FIXTURE), "--out", str(tmp_path / "r"), "--no-figures", "--wide"]) == 0
    wide = capsys.readouterr().out.splitlines()
    assert [c.strip() for c in short[0].strip("|").split("|")] == [
        "Rank", "Detector", "Headline", "TP Simulation", "TP CSV", "TN No Attack", "ROC-AUC"]
    assert "| statistical |" in short[2] and all(len(line) <= 120 for line in short)
    md = (tmp_path / "r" / "leaderboard.md").read_text().splitlines()
    head = next(line for line in md if line.startswith("| Rank |"))
    assert wide[0].count(" | ") == head.count(" | ") and "| Flagged anywhere CSV |" in wide[0]  # leaderboard.md's
    assert short[-1] == wide[-1] == str(tmp_path / "r" / "leaderboard.html")
