"""The paper's figures as PNG files (matplotlib's object API with the Agg renderer; no pyplot state).

One flight (from the public dataset reader, :func:`scart_bench.dataset.open_dataset`):

- :func:`flight_path`: path (east, north) of the attacked flight as flown (simulator view: the
  ``truth`` topic when the flight has it, else ``local_position_ned``), as the navigator perceived
  it, and the normal flight it came from, i.e. the path before the attack (simulation mode: its
  normal twin, the same seed flown without the attack, from the ``twin_truth`` topic; else the
  normal flight with the same seed, when there is one; csv mode: its source flight). The part flown during the attack window
  is drawn in :data:`ATTACK_COLOUR`.
- :func:`sensor_trace`: one field in the navigator view (received) and the simulator view
  (truth), with the attack window shaded.
- :func:`score_trace`: a detector's per-row score (from a run's saved scores), its row
  threshold from metrics.csv, its alarms (score strictly above the threshold) and the window.

One run: :func:`roc_curves` (flight-level ROC per detector, from flight_scores.csv) and
:func:`tp_heatmap` (TP rate by action x target per detector); many runs: :func:`headline_bars`.

Time figures shade every attack window, taken from the labels (contiguous rows with
``Is_Anomaly`` = 1, from the first labelled row's timestamp to the next row's), in the opaque
colour :data:`ATTACK_WINDOW_COLOUR` over the grid and under the data. Their axes sit at a fixed place
(:data:`AXES_RECT`) and each PNG records in its text chunk ``scart-bench axes`` the data x-range
and the pixel box of its axes, so a test (or a user) can map times to pixel columns
(:func:`axes_extent`, :func:`column_of`).
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from scart_bench.benchmark.store import ChecksumError, RunStore
from scart_bench.dataset import Dataset, is_dataset, open_dataset
from scart_bench.errors import ReportError, ScartBenchError
from scart_bench.reports.results import RunResults, load_run

#: Shaded attack window (light orange, opaque, drawn over the grid and below the data).
ATTACK_WINDOW_COLOUR = "#fdd0a2"
#: The attacked part of a flight path.
ATTACK_COLOUR = "#e6550d"
NAVIGATOR_COLOUR = "#1f77b4"
SIMULATOR_COLOUR = "#2ca02c"
NORMAL_COLOUR = "#7f7f7f"
SCORE_COLOUR = "#1f77b4"
THRESHOLD_COLOUR = "#000000"
ALARM_COLOUR = "#d62728"
DPI = 100
TIME_FIGSIZE = (9.0, 4.0)
#: [left, bottom, width, height] of the axes of time figures, in figure fractions.
AXES_RECT = (0.1, 0.12, 0.87, 0.66)
METADATA_KEY = "scart-bench axes"
TEST_ROLES = ("test_normal", "test_attacked")


# -- helpers ----------------------------------------------------------------------------------

def safe_name(text: str) -> str:
    """A file-name-safe form of a name (a short hash is added when characters were replaced)."""
    clean = re.sub(r"[^A-Za-z0-9._-]+", "_", str(text)).strip("._") or "x"
    if clean != str(text):
        clean = f"{clean[:60]}-{hashlib.sha1(str(text).encode()).hexdigest()[:8]}"
    return clean


def plain(text: str, limit: int = 60) -> str:
    """Text shown literally by matplotlib (no mathtext, not hidden from legends), shortened."""
    s = str(text)
    s = s if len(s) <= limit else s[: limit - 1] + "…"
    s = s.replace("$", r"\$")
    return " " + s if s.startswith("_") else s


def label_windows(timestamps_us: np.ndarray, labels: np.ndarray) -> list[tuple[int, int]]:
    """Attack windows ``[start, end)`` in microseconds from row labels: each run of labelled rows
    starts at its first row's timestamp and ends at the next row's (the last row's at the end)."""
    ts = np.asarray(timestamps_us, dtype=np.int64)
    lab = np.asarray(labels).astype(bool).astype(np.int8)
    d = np.diff(np.concatenate(([0], lab, [0])))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return [(int(ts[s]), int(ts[e] if e < ts.size else ts[-1])) for s, e in zip(starts, ends)]


def _time_axes(title: str) -> tuple[Figure, Axes]:
    fig = Figure(figsize=TIME_FIGSIZE, dpi=DPI)
    ax = fig.add_axes(AXES_RECT)
    fig.suptitle(plain(title, 100), y=0.98, fontsize=11)
    ax.set_xlabel("time (s)")
    ax.ticklabel_format(axis="y", useOffset=False)  # latitudes as themselves, no "+4.7e1" offset
    ax.grid(True, color="#dddddd", lw=0.6)
    ax.set_axisbelow(True)
    return fig, ax


def _shade(ax: Axes, windows_us: list[tuple[int, int]]) -> None:
    for start, end in windows_us:
        ax.axvspan(start / 1e6, end / 1e6, facecolor=ATTACK_WINDOW_COLOUR, edgecolor="none", lw=0, zorder=1)


def _legend_above(fig: Figure, ax: Axes, shaded: bool) -> None:
    handles, labels = ax.get_legend_handles_labels()
    if shaded:
        handles.append(Patch(facecolor=ATTACK_WINDOW_COLOUR, label="attack window (labels)"))
        labels.append("attack window (labels)")
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.93), ncol=min(4, len(labels)),
               fontsize=8, frameon=False)


def _save_time_figure(fig: Figure, ax: Axes, path: Path) -> Path:
    """Save at :data:`DPI`, recording the axes' data x-range and pixel box in the PNG."""
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    (px0, py0), (px1, py1) = ax.transData.transform([(x0, y0), (x1, y1)])
    height = fig.bbox.height
    extent = {"x_data": [x0, x1], "x_pixels": [float(px0), float(px1)],
              "y_pixels": [float(height - py1), float(height - py0)]}
    return _save(fig, path, {METADATA_KEY: json.dumps(extent)})


def _save(fig: Figure, path: Path, metadata: dict | None = None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png", metadata=metadata or {})
    return path


def axes_extent(png: str | Path) -> dict:
    """The axes box recorded in a time figure: ``x_data`` [x0, x1], ``x_pixels`` [col0, col1],
    ``y_pixels`` [top row, bottom row]."""
    from PIL import Image

    with Image.open(png) as im:
        return json.loads(im.text[METADATA_KEY])


def column_of(extent: dict, x: float) -> float:
    """Pixel column of data x in a time figure (see :func:`axes_extent`)."""
    (x0, x1), (p0, p1) = extent["x_data"], extent["x_pixels"]
    return p0 + (x - x0) * (p1 - p0) / (x1 - x0)


# -- one flight -------------------------------------------------------------------------------

def open_flight(flight_dir: str | Path) -> tuple[Dataset, str]:
    """The dataset and flight id of ``<dataset>/flights/<id>`` (ReportError naming the path otherwise)."""
    path = Path(flight_dir)
    root = path.resolve().parent.parent
    if not path.is_dir() or path.resolve().parent.name != "flights" or not is_dataset(root):
        raise ReportError(f"{flight_dir}: not a flight folder; expected <dataset>/flights/<id> inside a "
                         "dataset with a manifest")
    ds = open_dataset(root)
    fid = path.resolve().name
    if fid not in set(ds.manifest["flight_id"].astype(str)):
        raise ReportError(f"{flight_dir}: flight {fid!r} is not in the manifest of {root}")
    return ds, fid


def _manifest_row(ds: Dataset, fid: str) -> pd.Series:
    m = ds.manifest
    return m[m["flight_id"].astype(str) == fid].iloc[0]


def _table(ds: Dataset, fid: str, view: str) -> pd.DataFrame:
    try:
        return ds.flight(fid, view)
    except (OSError, ValueError) as exc:
        raise ReportError(f"{ds.flight_dir(fid)}: cannot read the {view} view ({exc})") from exc


def _path_xy(ds: Dataset, fid: str, view: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(timestamps us, north m, east m) of a flight: the ``truth`` topic in the simulator view when
    there is one, else a local x/y position, else lat/lon around the first fix (any topic of the
    quantity ``position``: generated flights and PX4 logs alike)."""
    try:
        has_truth = view == "simulator" and "truth" in ds.topics(fid, "simulator")
    except OSError:
        has_truth = False
    if has_truth:
        t = ds.topic(fid, "truth", "simulator")
        return t["Timestamp"].to_numpy(np.int64), t["x"].to_numpy(float), t["y"].to_numpy(float)
    df = _table(ds, fid, view)
    ts = df["Timestamp"].to_numpy(np.int64)
    from scart_bench.generator.geo import ne_from_latlon
    from scart_bench.generator.scart.meanings import QUANTITIES

    pos = QUANTITIES["position"]  # local x/y first, then lat/lon (MAVLink or PX4 uORB names)
    for a, b in (("x", "y"), ("lat", "lon")):
        for ca, cb in zip(pos[a], pos[b]):
            if {ca, cb} <= set(df.columns) and ca.split(".")[0] == cb.split(".")[0]:
                u, v = df[ca].to_numpy(float), df[cb].to_numpy(float)
                if a == "x":
                    return ts, u, v
                ok = np.flatnonzero(np.isfinite(u) & np.isfinite(v))
                if ok.size:
                    n, e = ne_from_latlon(u, v, u[ok[0]], v[ok[0]])
                    return ts, n, e
    raise ReportError(f"{ds.flight_dir(fid)}: no position columns (the quantity 'position': "
                     f"{', '.join(pos['x'] + pos['lat'])}) in the {view} view")


def reference_flight(ds: Dataset, fid: str) -> str | None:
    """The normal flight an attacked flight is compared with: its csv-mode source, else the normal
    flight with the same seed (None when there is neither)."""
    row, m = _manifest_row(ds, fid), ds.manifest
    ids = m["flight_id"].astype(str)
    if row.get("mode") == "normal":
        return None
    src = row.get("source_flight")
    if isinstance(src, str) and src and src != fid and src in set(ids):
        return src
    if "seed" in m.columns and pd.notna(row.get("seed")):
        same = m[(m["mode"] == "normal") & (m["seed"] == row["seed"]) & (ids != fid)]
        if len(same):
            return str(same["flight_id"].iloc[0])
    return None


def _twin_xy(ds: Dataset, fid: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(north m, east m) of a simulation-mode attacked flight's normal twin (its ``twin_truth``
    topic, :mod:`scart_bench.generator.impact`); None when the flight has none."""
    from scart_bench.generator.impact import TWIN_TOPIC

    try:
        if TWIN_TOPIC not in ds.topics(fid, "simulator"):
            return None
    except OSError:
        return None
    t = ds.topic(fid, TWIN_TOPIC, "simulator")
    return t["x"].to_numpy(float), t["y"].to_numpy(float)


def _windows(ds: Dataset, fid: str) -> list[tuple[int, int]]:
    nav = _table(ds, fid, "navigator")
    return label_windows(nav["Timestamp"].to_numpy(np.int64), nav["Is_Anomaly"].to_numpy())


def flight_path(ds: Dataset, fid: str, out_dir: str | Path) -> Path:
    """Path figure of one flight: flown, perceived and the normal reference (see module doc)."""
    fig = Figure(figsize=(6.5, 6.0), dpi=DPI)
    ax = fig.add_subplot()
    twin = _twin_xy(ds, fid)
    ref = reference_flight(ds, fid) if twin is None else None
    if twin is not None:
        ax.plot(twin[1], twin[0], color=NORMAL_COLOUR, lw=3.0, alpha=0.5,
                label="before: its normal twin (same seed, no attack)")
    elif ref is not None:
        _, n, e = _path_xy(ds, ref, "simulator")
        ax.plot(e, n, color=NORMAL_COLOUR, lw=3.0, alpha=0.5, label=plain(f"normal flight {ref}"))
    ts, n, e = _path_xy(ds, fid, "simulator")
    ax.plot(e, n, color=SIMULATOR_COLOUR, lw=1.4, label="after: attacked flight, as flown (simulator view)")
    inside = np.zeros(ts.size, bool)
    for start, end in _windows(ds, fid):
        inside |= (ts >= start) & (ts < end)
    if inside.any():
        ax.plot(np.where(inside, e, np.nan), np.where(inside, n, np.nan), color=ATTACK_COLOUR, lw=2.6,
                label="during the attack window")
    _, pn, pe = _path_xy(ds, fid, "navigator")
    ax.plot(pe, pn, color=NAVIGATOR_COLOUR, lw=1.0, ls="--", label="as perceived (navigator view)")
    ax.set_xlabel("east, y (m)")
    ax.set_ylabel("north, x (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, color="#dddddd", lw=0.6)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(plain(f"flight path: {fid}", 100), fontsize=11)
    fig.tight_layout()
    return _save(fig, Path(out_dir) / f"path_{safe_name(fid)}.png")


def _target_columns(columns: list[str], target: object) -> list[str]:
    """Columns named by a manifest target (``topic.field`` or a whole topic; joined by , or +)."""
    out: list[str] = []
    for token in re.split(r"[,+]", target) if isinstance(target, str) else []:
        token = token.strip()
        out += [c for c in columns if c == token or c.startswith(token + ".")] if token else []
    return list(dict.fromkeys(out))


def choose_field(nav: pd.DataFrame, sim: pd.DataFrame, target: object = None, field: str | None = None) -> str:
    """The field to trace: ``field`` when given; else, among the attacked target's columns (all sensor
    columns when the target names none), the one whose navigator view departs most from the
    simulator view inside the attack window (mean absolute difference over the field's spread)."""
    cols = [c for c in nav.columns if "." in c]
    if field is not None:
        if field not in nav.columns:
            raise ReportError(f"--field {field!r}: not a column of the flight; expected one of {', '.join(cols)}")
        return field
    if not cols:
        raise ReportError("the flight has no sensor column (topic.field) to trace")
    cands = [c for c in _target_columns(cols, target) if c in sim.columns] or [c for c in cols if c in sim.columns]
    if len(cands) <= 1:
        return cands[0] if cands else cols[0]
    both = nav[["Timestamp", "Is_Anomaly", *cands]].merge(sim[["Timestamp", *cands]], on="Timestamp",
                                                           suffixes=("", "@sim"))
    rows = both[both["Is_Anomaly"] == 1] if (both["Is_Anomaly"] == 1).any() else both
    a, b = rows[cands].to_numpy(float), rows[[f"{c}@sim" for c in cands]].to_numpy(float)
    spread = np.nanstd(both[[f"{c}@sim" for c in cands]].to_numpy(float), axis=0) + 1e-12
    with np.errstate(all="ignore"):
        gap = np.nanmean(np.abs(a - b), axis=0) / spread if len(rows) else np.zeros(len(cands))
    return cands[int(np.argmax(np.nan_to_num(gap, nan=-1.0)))]


def sensor_trace(ds: Dataset, fid: str, out_dir: str | Path, field: str | None = None) -> Path:
    """One field in the navigator and simulator views with the attack window shaded."""
    nav, sim = _table(ds, fid, "navigator"), _table(ds, fid, "simulator")
    name = choose_field(nav, sim, _manifest_row(ds, fid).get("target"), field)
    windows = label_windows(nav["Timestamp"].to_numpy(np.int64), nav["Is_Anomaly"].to_numpy())
    fig, ax = _time_axes(f"{fid}: {name}")
    _shade(ax, windows)
    ax.plot(nav["Timestamp"] / 1e6, nav[name], color=NAVIGATOR_COLOUR, lw=1.0, label="navigator view (received)")
    if name in sim.columns:
        ax.plot(sim["Timestamp"] / 1e6, sim[name], color=SIMULATOR_COLOUR, lw=1.0, ls="--",
                label="simulator view (truth)")
    t = np.concatenate([nav["Timestamp"].to_numpy(), sim["Timestamp"].to_numpy()]) / 1e6
    ax.set_xlim(float(t.min()), float(t.max()))
    ax.set_ylabel(plain(name))
    _legend_above(fig, ax, bool(windows))
    return _save_time_figure(fig, ax, Path(out_dir) / f"trace_{safe_name(fid)}_{safe_name(name)}.png")


def _run(run: RunResults | str | Path) -> RunResults:
    return run if isinstance(run, RunResults) else load_run(run)


def scored_detectors(run: RunResults | str | Path, fid: str) -> list[str]:
    """Detectors of a run that finished OK and scored the flight."""
    run = _run(run)
    ok = [str(d) for d in run.metrics.loc[run.metrics["status"] == "OK", "detector"]]
    out = []
    for det in ok:
        try:
            if fid in run.store.read_scores(det):
                out.append(det)
        except ChecksumError:  # scores that changed since the run wrote them are refused, not skipped
            raise
        except (OSError, ScartBenchError):  # no readable scores (or a name that cannot be a job folder)
            continue
    return out


def score_trace(run: RunResults | str | Path, detector: str, fid: str, out_dir: str | Path) -> Path:
    """A detector's per-row score over one flight with its row threshold, alarms and the attack window."""
    run = _run(run)
    row = run.metrics[run.metrics["detector"] == detector]
    if row.empty:
        raise ReportError(f"--detector {detector!r}: not in run {run.path}; expected one of "
                         f"{', '.join(map(str, run.metrics['detector']))}")
    if row["status"].iloc[0] != "OK":
        raise ReportError(f"--detector {detector!r}: its job in {run.path} did not finish OK "
                         f"({row['status'].iloc[0]}), so it has no scores")
    try:
        scores = run.store.read_scores(detector)
    except (OSError, ScartBenchError) as exc:
        raise ReportError(f"{run.path}: cannot read the scores of {detector!r} ({exc})") from exc
    truth = RunStore(run.path).read_truth()
    if fid not in scores or fid not in truth:
        raise ReportError(f"flight {fid!r} was not scored in run {run.path} (only validation and test flights are)")
    ts, labels = truth[fid]
    s = scores[fid]
    thr = float(row["row_threshold"].iloc[0]) if "row_threshold" in row.columns else float("nan")
    windows = label_windows(ts, labels)
    fig, ax = _time_axes(f"{detector} on {fid}")
    _shade(ax, windows)
    t = ts / 1e6
    ax.plot(t, s, color=SCORE_COLOUR, lw=1.0, label="score")
    if np.isfinite(thr):
        ax.axhline(thr, color=THRESHOLD_COLOUR, lw=1.0, ls="--", label=f"row threshold {thr:.3g}")
        alarm = s > thr
        ax.plot(t[alarm], s[alarm], ls="none", marker="o", ms=2.5, color=ALARM_COLOUR,
                label=f"alarms ({int(alarm.sum())} rows)")
    ax.set_xlim(float(t.min()), float(t.max()))
    ax.set_ylabel("anomaly score")
    _legend_above(fig, ax, bool(windows))
    return _save_time_figure(fig, ax, Path(out_dir) / f"score_{safe_name(detector)}_{safe_name(fid)}.png")


def flight_figures(flight_dir: str | Path, out_dir: str | Path, run: str | Path | None = None,
                   detectors: list[str] | None = None, field: str | None = None) -> list[Path]:
    """Every figure of one flight: path and sensor trace, plus score traces when a run is given
    (``detectors`` default: every detector of the run that scored the flight)."""
    ds, fid = open_flight(flight_dir)
    paths = [flight_path(ds, fid, out_dir), sensor_trace(ds, fid, out_dir, field)]
    if run is not None:
        res = load_run(run)
        for det in detectors or scored_detectors(res, fid):
            paths.append(score_trace(res, det, fid, out_dir))
    return paths


# -- one run / many runs ----------------------------------------------------------------------

def roc_curves(run: RunResults, out_dir: str | Path) -> Path:
    """Flight-level ROC curves (held-out normal vs attacked test flights), one per OK detector."""
    from sklearn.metrics import auc, roc_curve

    fs = run.table("flight_scores.csv")
    fs = fs[fs["role"].isin(TEST_ROLES)]
    fig = Figure(figsize=(6.0, 5.5), dpi=DPI)
    ax = fig.add_subplot()
    ax.plot([0, 1], [0, 1], color="#bbbbbb", lw=1, ls=":", label="chance")
    for det, group in fs.groupby("detector", sort=False):
        y = (group["role"] == "test_attacked").astype(int).to_numpy()
        if y.min() == y.max():
            continue
        fpr, tpr, _ = roc_curve(y, group["score"].to_numpy(float))
        ax.plot(fpr, tpr, lw=1.4, label=plain(f"{det} (AUC {auc(fpr, tpr):.3f})"))
    ax.set_xlim(-0.01, 1.01)
    ax.set_ylim(-0.01, 1.01)
    ax.set_xlabel("false positive rate (normal test flights flagged)")
    ax.set_ylabel("true positive rate (attacked flights flagged)")
    ax.set_title(plain(f"flight-level ROC: {run.label}", 100), fontsize=11)
    ax.grid(True, color="#eeeeee")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return _save(fig, Path(out_dir) / f"roc_{safe_name(run.label)}.png")


def tp_rates(run: RunResults) -> pd.DataFrame:
    """TP rate (detected inside the attack window; the paper's lenient rule for runs scored before
    that rule existed) and count of attacked test flights per detector, action and target."""
    fs = run.table("flight_scores.csv")
    flights = run.table("flights.csv")[["flight_id", "action", "target"]].astype({"flight_id": str})
    att = fs[fs["role"] == "test_attacked"].merge(flights, on="flight_id", how="left")
    for col in ("action", "target"):
        att[col] = att[col].astype(object).where(att[col].notna(), "(none)").astype(str)
    hit = att["outcome"] == "detected" if "outcome" in att.columns else att["flagged"].astype(bool)
    att = att.assign(hit=hit.astype(float))
    return (att.groupby(["detector", "action", "target"], sort=True)["hit"]
            .agg(tp_rate="mean", n="size").reset_index())


def tp_heatmap(run: RunResults, out_dir: str | Path) -> Path:
    """TP rate by action (rows) x target (columns), one panel per detector that finished OK."""
    rates = tp_rates(run)
    order = [d for d in run.metrics["detector"].astype(str) if d in set(rates["detector"])]
    dets = list(dict.fromkeys([*order, *rates["detector"]]))
    actions, targets = sorted(set(rates["action"])), sorted(set(rates["target"]))
    ncols = max(1, min(3, len(dets)))
    nrows = max(1, -(-len(dets) // ncols))
    fig = Figure(figsize=(1.2 + ncols * max(3.0, 0.9 * len(targets) + 1.5), 1.4 + nrows * (0.45 * len(actions) + 1.6)),
                 dpi=DPI, layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    image = None
    for ax, det in zip(axes.flat, dets):
        grid = (rates[rates["detector"] == det].pivot(index="action", columns="target", values="tp_rate")
                .reindex(index=actions, columns=targets))
        image = ax.imshow(grid.to_numpy(float), vmin=0, vmax=1, aspect="auto",
                          cmap=colormaps["viridis"].with_extremes(bad="#eeeeee"))  # grey: no such flight
        for (i, j), v in np.ndenumerate(grid.to_numpy(float)):
            if np.isfinite(v):
                ax.text(j, i, f"{100 * v:.0f}%", ha="center", va="center", fontsize=7,
                        color="white" if v < 0.6 else "black")
        ax.set_xticks(range(len(targets)), [plain(t, 24) for t in targets], rotation=30, ha="right", fontsize=7)
        ax.set_yticks(range(len(actions)), [plain(a, 24) for a in actions], fontsize=7)
        ax.set_title(plain(det, 40), fontsize=9)
    for ax in list(axes.flat)[len(dets):]:
        ax.set_axis_off()
    if image is not None:
        fig.colorbar(image, ax=axes, shrink=0.8, label="TP rate")
    else:
        axes[0, 0].text(0.5, 0.5, "no attacked test flight scored", ha="center", va="center")
    fig.suptitle(plain(f"TP rate by action x target: {run.label}", 100), fontsize=11)
    return _save(fig, Path(out_dir) / f"tp_heatmap_{safe_name(run.label)}.png")


def headline_bars(board: pd.DataFrame, out_dir: str | Path) -> Path:
    """Headline score per ranked detector (mean, with the standard deviation across runs as error bar)."""
    ranked = board[board["headline_mean"].notna()]
    fig = Figure(figsize=(7.0, 1.2 + 0.4 * max(1, len(ranked))), dpi=DPI)
    ax = fig.add_subplot()
    y = np.arange(len(ranked))
    ax.barh(y, 100 * ranked["headline_mean"].to_numpy(float), xerr=100 * ranked["headline_std"].fillna(0).to_numpy(float),
            color=NAVIGATOR_COLOUR, capsize=3)
    ax.set_yticks(y, [plain(d, 40) for d in ranked["detector"]], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 105)
    ax.set_xlabel("headline score (%): mean of TP Simulation, TP CSV, TN No Attack")
    ax.grid(True, axis="x", color="#eeeeee")
    fig.tight_layout()
    return _save(fig, Path(out_dir) / "headline.png")


#: Markers of the operating characteristic: simulation and csv mode, the paper's reported point.
OC_MODES = (("simulation", "o", NAVIGATOR_COLOUR), ("csv", "s", SIMULATOR_COLOUR))
PAPER_COLOUR = "#d62728"


def operating_characteristic(oc: pd.DataFrame, detector: str, run_label: str, out_dir: str | Path,
                             run_alpha: float | None = None,
                             paper: tuple[float, float, float] | None = None) -> Path:
    """One detector's flight-level operating characteristic (:func:`benchmark.results.operating_characteristics`'s
    rows of ``detector``): TP in window per mode against the false-alarm rate measured on the held-out
    normal flights, one point per target alpha (labelled), the run's own alpha circled; a horizontal bar at
    each simulation-mode point spans the 95 % spread of the false-alarm rate a threshold calibrated on the
    run's number of validation flights realises (Beta(n + 1 - k, k)); ``paper``: the paper's (TP simulation,
    TP csv, TN) in percent, marked at its false-alarm rate 100 - TN."""
    d = oc[oc["detector"] == detector].sort_values("alpha")
    if d.empty:
        raise ReportError(f"no operating characteristic for detector {detector!r} in run {run_label}")
    fig = Figure(figsize=(6.4, 5.0), dpi=DPI)
    ax = fig.add_subplot()
    far = 100 * d["far_no_attack"].to_numpy(float)
    lo, hi = 100 * d["far_lo"].to_numpy(float), 100 * d["far_hi"].to_numpy(float)
    for mode, marker, colour in OC_MODES:
        tp = 100 * d[f"tp_{mode}"].to_numpy(float)
        if not np.isfinite(tp).any():
            continue
        n = int(d[f"n_{mode}"].iloc[0])
        ax.plot(far, tp, marker=marker, color=colour, lw=1.2, ms=5, label=f"TP in window, {mode} ({n} flights)")
        if mode == "simulation":
            ax.hlines(tp, lo, hi, color=colour, alpha=0.3, lw=3,
                      label=f"spread of the realised rate ({int(d['n_validation'].iloc[0])} validation flights)")
            same: dict[tuple[float, float], list[float]] = {}  # one label per point: alphas that share it
            for x, y, a in zip(far, tp, d["alpha"].to_numpy(float)):
                same.setdefault((float(x), float(y)), []).append(100 * a)
            for (x, y), a in same.items():
                text = f"{a[0]:g}%" if len(a) == 1 else f"{a[0]:g}-{a[-1]:g}%"
                ax.annotate(text, (x, y), textcoords="offset points", xytext=(4, -10), fontsize=7)
        if run_alpha is not None and np.isclose(d["alpha"], run_alpha).any():
            i = int(np.flatnonzero(np.isclose(d["alpha"].to_numpy(float), run_alpha))[0])
            ax.plot(far[i], tp[i], marker="o", ms=12, mfc="none", mec=THRESHOLD_COLOUR, lw=0)
    if paper is not None:
        for (mode, _, colour), value in zip(OC_MODES, paper[:2]):
            ax.plot(100 - paper[2], value, marker="*", ms=14, color=colour, mec=PAPER_COLOUR, mew=1.2, lw=0,
                    label=f"the paper, {mode}")
    ax.set_xlim(-1, max(35.0, float(np.nanmax(hi)) + 2 if np.isfinite(hi).any() else 35.0))
    ax.set_ylim(-2, 102)
    ax.set_xlabel(f"false alarms on held-out normal flights (%, {int(d['n_no_attack'].iloc[0])} flights)")
    ax.set_ylabel("attacked flights detected in the attack window (%)")
    ax.set_title(plain(f"operating characteristic: {detector} ({run_label})", 100), fontsize=10)
    ax.grid(True, color="#eeeeee")
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return _save(fig, Path(out_dir) / f"oc_{safe_name(run_label)}_{safe_name(detector)}.png")
