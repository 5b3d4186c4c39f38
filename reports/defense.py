"""The defense table in the report: ``scart-bench defend``'s table beside the leaderboard, and its figure.

A defense folder is what ``scart-bench defend --out DIR`` wrote: ``defense.csv`` (one row per detector x
response, benchmark.defense.defense_table), ``defense.md`` (its header says the run, grid and wall time) and
``defense_paths.csv`` (one example attacked flight's normal, undefended and defended paths). ``report`` finds
one inside a run folder (``RUN/defense.csv`` or ``RUN/defense/defense.csv``) or takes it with ``--defense DIR``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure

from scart_bench.benchmark.defense import table_markdown
from scart_bench.errors import ReportError
from scart_bench.reports import figures as fg
from scart_bench.reports.html import esc

#: The columns the report reads from defense.csv.
COLUMNS = (
    "detector", "response", "alarms", "missions_saved", "endangered", "saved_low", "saved_high",
    "undefended_max_dev_m", "undefended_max_dev_low", "undefended_max_dev_high", "defended_max_dev_m",
    "defended_max_dev_low", "defended_max_dev_high", "false_aborts", "normal", "false_abort_low",
    "false_abort_high", "response_delay_s", "response_delay_low", "response_delay_high",
)
DEFENDED_COLOUR = "#2ca02c"
UNDEFENDED_COLOUR = "#e6550d"


def find_defense(run_paths: list[str | Path], extra: list[str | Path] = ()) -> list[Path]:
    """Defense folders: each run folder's (``defense.csv`` in it or in ``defense/``), then ``extra``.

    ReportError when a folder given in ``extra`` holds no defense.csv."""
    found: list[Path] = []
    for run in run_paths:
        for folder in (Path(run), Path(run) / "defense"):
            if (folder / "defense.csv").is_file():
                found.append(folder)
                break
    for folder in extra:
        folder = Path(folder)
        if not (folder / "defense.csv").is_file():
            raise ReportError(f"--defense {folder}: no defense.csv (a folder scart-bench defend --out wrote)")
        if folder.resolve() not in {f.resolve() for f in found}:
            found.append(folder)
    return found


def read_table(folder: Path) -> pd.DataFrame:
    """defense.csv of ``folder``, checked for the columns the report shows."""
    path = folder / "defense.csv"
    table = pd.read_csv(path)
    missing = [c for c in COLUMNS if c not in table.columns]
    if missing:
        raise ReportError(f"{path}: column {missing[0]!r} missing; expected the table scart-bench defend writes")
    return table


def _header(folder: Path) -> str:
    """The line of defense.md that names the run, grid and wall time ('' when absent)."""
    md = folder / "defense.md"
    if not md.is_file():
        return ""
    lines = [ln for ln in md.read_text().splitlines() if ln.startswith("Run ")]
    return lines[0] if lines else ""


def markdown(folders: list[Path], figures: dict[Path, Path] | None = None, out: Path | None = None) -> str:
    """The report's "Defense in the loop" section (Markdown): each folder's table, its header and figure."""
    if not folders:
        return ""
    parts = ["\n## Defense in the loop\n"]
    for folder in folders:
        parts.append(f"\n{folder}: {_header(folder)}\n\n" + table_markdown(read_table(folder)))
        png = (figures or {}).get(folder)
        if png is not None:
            rel = png.relative_to(out).as_posix() if out is not None else png.as_posix()
            parts.append(f"\n![{_caption(folder)}]({rel})\n")
    return "".join(parts)


def html(folders: list[Path]) -> str:
    """The same section as an HTML fragment (tables; the figures go with the report's figures)."""
    if not folders:
        return ""
    out = ["<h2>Defense in the loop</h2>"]
    for folder in folders:
        table = read_table(folder)
        lines = [ln for ln in table_markdown(table).splitlines() if ln.startswith("|")]
        head = [c.strip() for c in lines[0].strip("|").split("|")]
        out.append(f'<p class="doc">{esc(folder)}: {esc(_header(folder))}</p>')
        out.append('<div class="scroll"><table class="leaderboard"><thead><tr>')
        out += [f"<th>{esc(h)}</th>" for h in head]
        out.append("</tr></thead><tbody>")
        for line in lines[2:]:
            out.append("<tr>" + "".join(f"<td>{esc(c.strip())}</td>" for c in line.strip("|").split("|")) + "</tr>")
        out.append("</tbody></table></div>")
        note = table_markdown(table).strip().splitlines()[-1]
        out.append(f'<p class="doc">{esc(note)}</p>')
    return "".join(out)


def _caption(folder: Path) -> str:
    paths = pd.read_csv(folder / "defense_paths.csv", nrows=1)
    r = paths.iloc[0]
    return (f"Defense in the loop: flight seed {int(r['seed'])}, {r['detector']} with {r['response']}: "
            "its normal twin, the attacked flight undefended and defended")


def path_figure(folder: Path, out_dir: Path, name: str = "defense") -> Path | None:
    """The example flight of ``folder`` (defense_paths.csv): normal twin, undefended and defended true paths."""
    src = folder / "defense_paths.csv"
    if not src.is_file():
        return None
    paths = pd.read_csv(src)
    if paths.empty:
        return None
    r = paths.iloc[0]
    fig = Figure(figsize=(6.5, 6.0), dpi=fg.DPI)
    ax = fig.add_subplot()
    style = {
        "normal": (fg.NORMAL_COLOUR, 3.0, 0.5, "normal: its twin, same seed, no attack"),
        "undefended": (UNDEFENDED_COLOUR, 1.4, 1.0, "attacked, undefended"),
        "defended": (DEFENDED_COLOUR, 1.8, 1.0, f"attacked, defended ({r['detector']}, {r['response']})"),
    }
    for path, (colour, lw, alpha, label) in style.items():
        p = paths[paths["path"] == path]
        if len(p):
            ax.plot(p["y"], p["x"], color=colour, lw=lw, alpha=alpha, label=fg.plain(label, 70), zorder=3 if path == "defended" else 2)
            ax.plot(p["y"].iloc[-1:], p["x"].iloc[-1:], "o", color=colour, ms=5)
    ax.plot([0.0], [0.0], marker="^", color="black", ms=7, ls="none", label="home")
    ax.set_xlabel("east, y (m)")
    ax.set_ylabel("north, x (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, color="#dddddd", lw=0.6)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(fg.plain(f"defense in the loop: flight seed {int(r['seed'])} (dots: where it ended)", 100),
                 fontsize=11)
    fig.tight_layout()
    return fg._save(fig, Path(out_dir) / f"{name}.png")


def figures(folders: list[Path], out_dir: Path) -> dict[Path, Path]:
    """The path figure of each folder that has an example flight."""
    out = {}
    for k, folder in enumerate(folders):
        png = path_figure(folder, out_dir, f"defense_{k + 1}_{fg.safe_name(folder.name)}")
        if png is not None:
            out[folder] = png
    return out

