"""What the paper's Telemanom (``data/runs/telemanom_paper.toml``: one LSTM per channel, l_s 250, 80-80
units, 35 epochs, patience 10, its own dynamic threshold) costs: per channel, the fit on a dataset's
training flights and the score of one test flight, timed for a few channels, and the whole run
extrapolated to every channel and every scored flight.

    python -m perf.telemanom_paper_speed --dataset DIR [--channels a.b,c.d] [--device cpu|cuda]
                                         [--scored N] [--param NAME=VALUE ...]

``--scored``: how many flights the run scores (default: the dataset's validation and test flights;
the quick profile's run scores 222). Each is forecast once: its alarms under the own rule reuse the
forecast of its scores.
"""

from __future__ import annotations

import argparse
import ast
import time
from pathlib import Path

import numpy as np

RUN_FILE = Path(__file__).resolve().parents[1] / "data" / "runs" / "telemanom_paper.toml"


def _sync(device: str) -> None:
    import torch

    if device.startswith("cuda"):
        torch.cuda.synchronize()


def main(argv: list[str] | None = None) -> int:
    from scart_bench.benchmark.config import read_run_file
    from scart_bench.dataset.read import Dataset
    from scart_bench.detectors.telemanom import Telemanom

    p = argparse.ArgumentParser(prog="python -m perf.telemanom_paper_speed", description=__doc__.split("\n")[0])
    p.add_argument("--dataset", type=Path, required=True)
    p.add_argument("--channels", default="attitude.roll,local_position_ned.z",
                   help="comma-separated channels (topic.field) to time; the rest are extrapolated")
    p.add_argument("--device", default="auto")
    p.add_argument("--scored", type=int, default=None, help="flights the run scores (default: validation + test)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="override one of the run file's parameters (a smoke test: epochs=1 l_s=20)")
    args = p.parse_args(argv)
    run = read_run_file(RUN_FILE)
    params = dict(run["params"]["telemanom"], device=args.device)
    for item in args.param:
        name, _, value = item.partition("=")
        try:
            params[name] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            params[name] = value
    channels = [c for c in args.channels.split(",") if c]
    if not channels:
        p.error("--channels: name at least one channel")
    ds = Dataset(args.dataset)
    split = ds.manifest["split"]
    if not (split == "train").any() or not (split == "test").any():
        p.error(f"{args.dataset}/manifest: split: expected training and test flights, found "
                f"{sorted(set(split.astype(str)))}")
    train = [ds.flight(f) for f in ds.manifest.loc[split == "train", "flight_id"]]
    test = ds.flight(ds.manifest.loc[split == "test", "flight_id"].iloc[0])
    scored = args.scored if args.scored is not None else int(split.isin(("validation", "test")).sum())
    fits, scores, n_channels = [], [], 0
    for channel in channels:
        det = Telemanom(**params, target_columns=[channel])
        t0 = time.perf_counter()
        det.fit(train)
        _sync(str(det._torch_device()))
        fit_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        det.score(test)
        _sync(str(det._torch_device()))
        score_s = time.perf_counter() - t0
        n_channels = det.n_features_in_
        fits.append(fit_s)
        scores.append(score_s)
        print(f"{channel}: fit {fit_s:.1f} s ({det.epochs_run_[0]} epochs, {len(train)} training flights), "
              f"score {1e3 * score_s:.0f} ms for {len(test)} rows, on {det._torch_device()}", flush=True)
    fit_all = n_channels * float(np.mean(fits))
    score_all = n_channels * scored * float(np.mean(scores))
    print(f"the whole run, extrapolated: {n_channels} channels x {np.mean(fits):.1f} s of fit = "
          f"{fit_all / 60:.1f} min; {scored} scored flights x {n_channels} channels x {1e3 * np.mean(scores):.0f} ms = "
          f"{score_all / 60:.1f} min; about {(fit_all + score_all) / 60:.0f} min in all", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
