"""csv mode on a user's own data: attack a recorded flight file and write a labelled dataset."""

from __future__ import annotations

import json
from pathlib import Path

from scart_bench.generator.dataset import DatasetWriter, FlightRecord, check_output_dir
from scart_bench.generator.importers import load_flight_file
from scart_bench.generator.modes import csv_mode, scenario_manifest, with_labels
from scart_bench.generator.scart.grid import load_configurations


def attack_file(input_path: str | Path, scenario_path: str | Path, out: str | Path, fmt: str = "parquet",
                seed: int = 0, overwrite: bool = False, topics: list[str] | None = None) -> Path:
    """Replay ``input_path`` (CSV, ULog, Parquet or a dataset flight folder) through the scenario(s).

    A scenario file's scenarios are applied together to one attacked copy; a grid or sweep file
    gives one attacked copy per configuration. Everything is validated before anything is written.
    """
    input_path, out = Path(input_path), Path(out)
    check_output_dir(out, overwrite=overwrite)
    scenario_doc = Path(scenario_path)
    jobs = load_configurations(scenario_doc, check_topics=False)
    tables = load_flight_file(input_path, topics=topics)
    available = {t: tuple(c for c in df.columns if c not in ("Timestamp", "Is_Anomaly")) for t, df in tables.items()}
    for job in jobs:
        for sc in job:
            sc.validate_topics(available)
    results = csv_mode([tables] * len(jobs), jobs, [seed] * len(jobs))
    writer = DatasetWriter(out, fmt=fmt, overwrite=overwrite,
                           info={"mode": "csv", "input": str(input_path), "scenario_file": str(scenario_doc)})
    last = max(int(df["Timestamp"].iloc[-1]) for df in tables.values() if len(df))
    for job, (nav, windows, events) in zip(jobs, results):
        flight_id = "csv-" + "+".join(s.id for s in job)
        manifest = scenario_manifest(job, "csv", seed, source=str(input_path))
        manifest["duration_s"] = (last + 1) / 1e6
        config = {"mode": "csv", "input": str(input_path), "seed": seed, "scenarios": [s.to_dict() for s in job],
                  "input_origin_us": {t: df.attrs.get("origin_us") for t, df in tables.items()}}
        writer.write(FlightRecord(flight_id=flight_id, navigator=nav, simulator=with_labels(tables, windows),
                                  manifest=manifest, config=json.loads(json.dumps(config, default=str)),
                                  windows=windows, events=events))
    writer.close()
    return out
