"""Progress a person can follow: counts per part against their totals, bars on a terminal, plain
lines every few seconds elsewhere, a summary at the end; nothing from a quiet one."""

from __future__ import annotations

import io
import re
import threading

from scart_bench.progress import Progress, quiet


def test_plain_lines_count_every_part_and_end_with_a_summary():
    out = io.StringIO()
    with Progress("generate", "flights", every_s=0, stream=out, bars=False) as p:
        p.expect("normal", 4)
        p.expect("simulation", 2)
        p.add("normal", 2)
        p.add("normal", 2)
        p.add("simulation", 2)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("generate: normal 2/4, simulation 0/2 flights; ")
    assert re.search(r"flights/s, about .* left$", lines[0])
    assert lines[-1].startswith("generate: normal 4/4, simulation 2/2 flights in ")


def test_lines_wait_for_their_period_but_the_summary_always_comes():
    out = io.StringIO()
    with Progress("import", "logs", every_s=3600, stream=out, bars=False) as p:
        p.expect("read", 3)
        for _ in range(3):
            p.add("read")
    assert out.getvalue().splitlines() == [out.getvalue().splitlines()[-1]]
    assert out.getvalue().startswith("import: read 3/3 logs in ")


def test_bars_on_a_terminal_keep_notes_apart():
    out = io.StringIO()
    with Progress("attack", "flights", stream=out, bars=True) as p:
        p.expect("replayed", 5)
        p.note("attack: a note")
        p.add("replayed", 5)
    text = out.getvalue()
    assert "attack: replayed" in text and "5/5" in text and "attack: a note" in text


def test_counts_from_several_threads_add_up():
    p = Progress("generate", every_s=3600, stream=io.StringIO(), bars=False)
    p.expect("csv", 4000)
    threads = [threading.Thread(target=lambda: [p.add("csv") for _ in range(1000)]) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert p.done["csv"] == 4000


def test_a_quiet_progress_counts_and_says_nothing(capsys):
    p = quiet()
    p.expect("normal", 2)
    p.add("normal", 2)
    p.note("hidden")
    p.close()
    assert p.done == {"normal": 2}
    assert capsys.readouterr() == ("", "")


def test_work_that_fails_ends_with_its_error_alone():
    out = io.StringIO()
    try:
        with Progress("import", "logs", every_s=3600, stream=out, bars=False) as p:
            p.expect("read", 3)
            p.add("read")
            raise ValueError("bad log")
    except ValueError:
        pass
    assert out.getvalue() == ""
