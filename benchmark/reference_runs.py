"""The reference runs: the benchmark over several seeds of a profile and its factor experiments, run or
resumed here; ``scart_bench.reports.reference`` renders them as one page beside the paper's numbers.

Per seed it runs (or resumes) the benchmark with the paper's eight detectors on the profile's dataset
(generated when missing). The factor experiments that need no new training are rescorings of the same
saved scores under another protocol (a copy of each run folder with its protocol changed, scored again):
the operating point (alpha 1 % and 10 % beside 5 %) and the burn-in after arming (none, as protocol v1).
Retrained configurations (``TRAINED``: Telemanom on TensorFlow, when it is installed; Telemanom under
its own alarm rule) run one detector again on each seed's dataset.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import pandas as pd

from scart_bench.benchmark.protocol import Protocol
from scart_bench.benchmark.store import RunStore

#: The SCART paper's table, in percent: TP simulation mode, TP csv mode, TN (normal flights).
PAPER: dict[str, tuple[float, float, float]] = {
    "telemanom": (58.2, 89.6, 90.0),
    "tsbitmaps": (42.0, 86.2, 100.0),
    "statistical": (59.7, 86.2, 100.0),
    "deepsvdd": (100.0, 100.0, 90.0),
    "rdp": (100.0, 100.0, 100.0),
    "rca": (100.0, 100.0, 100.0),
    "goad": (100.0, 100.0, 100.0),
    "neutral": (100.0, 100.0, 100.0),
}

#: Rescorings of every run: name -> (what changes, protocol changes).
VARIANTS: dict[str, tuple[str, dict]] = {
    "alpha-0.01": ("alpha = 1 %", {"alpha": 0.01}),
    "alpha-0.10": ("alpha = 10 %", {"alpha": 0.10}),
    "no-burn-in": ("no burn-in, no end transient (protocol v1's counting)", {"burn_in_s": 0.0,
                                                                             "end_transient_s": 0.0}),
}


@dataclasses.dataclass(frozen=True)
class Retrained:
    """A configuration trained again on every seed's dataset, beside the default run's detector of the
    same name: other detector parameters and/or another protocol (e.g. the detector's own alarm rule)."""

    what: str
    detector: str
    params: dict = dataclasses.field(default_factory=dict)
    needs: str | None = None  # the module it needs; left out (with a line) when it is not installed
    protocol: dict = dataclasses.field(default_factory=dict)
    short: str = ""  # a few words for the pages that only name it

    def label(self) -> str:
        return "; ".join(f"{k} = {v!r}" for k, v in {**self.params, **self.protocol}.items())


#: Retrained configurations: name -> Retrained.
TRAINED: dict[str, Retrained] = {
    "telemanom-tensorflow": Retrained(
        "Telemanom on Keras 3 / TensorFlow (the paper's stack), the same model and training as our torch default",
        "telemanom", {"backend": "tensorflow"}, needs="tensorflow", short="Telemanom on TensorFlow"),
    "telemanom-own-threshold": Retrained(
        "Telemanom with its own nonparametric dynamic threshold (Hundman et al. 2018; the paper's Telemanom "
        "alarms this way) instead of the calibrated one, the same model and training as our default",
        "telemanom", protocol={"alarm_rule": "own"}, short="Telemanom with its own dynamic threshold"),
}


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def finished(run: Path, detectors=None) -> bool:
    """The run folder has metrics for every one of ``detectors`` (default: the paper's eight), each job
    finished (OK or failed with its message): an interrupted run lists its unstarted jobs as UNFINISHED,
    and is resumed rather than reused."""
    need = set(PAPER if detectors is None else detectors)
    if not (run / "metrics.csv").is_file():
        return False
    m = pd.read_csv(run / "metrics.csv")
    done = m["detector"] if "status" not in m.columns else m.loc[m["status"] != "UNFINISHED", "detector"]
    return set(done) >= need


def run_seeds(profile: str, seeds: list[int], jobs: int, runs_root: Path, data_root: Path,
              detectors: list[str] | None = None, timeout: float | None = None) -> list[Path]:
    """Run (or resume) the benchmark of ``detectors`` (default: the paper's eight) once per seed, in
    ``runs_root/<profile>-seed<N>`` on the profile's dataset (generated when missing); the run folders.
    A folder that already has every detector is reused as it is; ``wall_s.json`` adds up the wall time
    of the invocations that ran something in it. ``timeout``: each job's limit in seconds (default: the
    profile's)."""
    from scart_bench.benchmark.config import RunConfig
    from scart_bench.benchmark.runner import run_benchmark

    names = list(PAPER) if detectors is None else list(detectors)
    paths = []
    for seed in seeds:
        out = runs_root / f"{profile}-seed{seed}"
        if finished(out, names):
            _log(f"reference: {out} is complete, reused")
        else:
            t0 = time.perf_counter()
            run_benchmark(RunConfig(detectors=names, profile=profile, seed=seed, out=out, resume=out.exists(),
                                    jobs=jobs, data_root=data_root, timeout=timeout))
            _add_wall_s(out, time.perf_counter() - t0)
        paths.append(out)
    return paths


def _add_wall_s(run: Path, seconds: float) -> None:
    """Add ``seconds`` to the run's wall_s.json (a resumed run's earlier invocations count too; an
    unreadable file counts as 0, with a line)."""
    from scart_bench.errors import ScartBenchError
    from scart_bench.jsonfile import read_json

    path = run / "wall_s.json"
    before = 0.0
    if path.is_file():
        try:
            value = read_json(path).get("wall_s", 0.0)  # type: ignore[union-attr]
        except (ScartBenchError, AttributeError) as exc:
            _log(f"reference: {path} unreadable ({exc}); its earlier wall time is not counted")
            value = 0.0
        ok = isinstance(value, int | float) and not isinstance(value, bool) and value >= 0
        before = float(value) if ok else 0.0
    path.write_text(json.dumps({"wall_s": before + seconds}))


def protocol_variant(protocol: Protocol, alpha: float | None = None, **changes) -> Protocol:
    """``protocol`` with another alpha for both thresholds and/or other counting windows."""
    if alpha is not None:
        changes["flight_rule"] = dataclasses.replace(protocol.flight_rule, alpha=alpha)
        changes["row_rule"] = dataclasses.replace(protocol.row_rule, alpha=alpha)
    return dataclasses.replace(protocol, **changes)


def _newer(variant: Path, run: Path) -> bool:
    """The variant folder was scored after its run (so it is still that run's variant)."""
    done = variant / "metrics.csv"
    return done.is_file() and done.stat().st_mtime >= (run / "metrics.csv").stat().st_mtime


def rescored(run: Path, name: str, changes: dict) -> Path:
    """A copy of ``run`` (scores, truth, flights; not its flight cache) scored under the changed protocol."""
    from scart_bench.benchmark.results import score_run

    out = run.parent / "variants" / f"{run.name}.{name}"
    config = RunStore(run).read_config()
    protocol = protocol_variant(Protocol.from_dict(config["identity"]["protocol"]), **changes)
    if _newer(out, run):
        return out
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(run, out, ignore=shutil.ignore_patterns("cache"))
    config["identity"]["protocol"] = protocol.rules()
    config["protocol"] = protocol.to_dict()
    config["name"] = f"{config.get('name') or run.name} ({name})"
    (out / "config.json").write_text(json.dumps(config, indent=2, sort_keys=True))
    score_run(out)
    return out


def retrained(run: Path, name: str, jobs: int, conf: Retrained | None = None) -> Path | None:
    """``run``'s dataset and seed with one detector retrained under other parameters (``conf``, default
    TRAINED[name]): the variant's run folder, or None when the module it needs is not installed."""
    import importlib.util

    from scart_bench.benchmark.config import RunConfig
    from scart_bench.benchmark.runner import run_benchmark

    conf = TRAINED[name] if conf is None else conf
    if conf.needs is not None and importlib.util.find_spec(conf.needs) is None:
        _log(f"reference: {name} left out: {conf.needs} is not installed")
        return None
    out = run.parent / "variants" / f"{run.name}.{name}"
    if _newer(out, run):
        return out
    config = RunStore(run).read_config()
    t0 = time.perf_counter()
    protocol = dataclasses.replace(Protocol.from_dict(config["protocol"]), **conf.protocol)
    run_benchmark(RunConfig(detectors=[conf.detector], params={conf.detector: dict(conf.params)},
                            seed=int(config["seed"]), dataset=Path(config["dataset"]["path"]), out=out,
                            resume=out.exists(), jobs=jobs, protocol=protocol))
    (out / "wall_s.json").write_text(json.dumps({"wall_s": time.perf_counter() - t0}))
    return out


@dataclasses.dataclass
class ReferenceRuns:
    """What :func:`reference_runs` ran or found: the run folder of each seed, and per variant (rescored or
    retrained) its folders, seed by seed."""

    runs: list[Path]
    variants: dict[str, list[Path]]
    trained: dict[str, list[Path]]


def reference_runs(profile: str, seeds: list[int], jobs: int, runs_root: Path, data_root: Path,
                   trained: dict[str, Retrained] | None = None) -> ReferenceRuns:
    """Run (or resume) every seed, rescore each under :data:`VARIANTS` and retrain ``trained`` (default
    :data:`TRAINED`; a configuration whose module is missing is left out, with a line)."""
    paths = run_seeds(profile, seeds, jobs, runs_root, data_root)
    variants = {name: [rescored(path, name, changes) for path in paths] for name, (_, changes) in VARIANTS.items()}
    done: dict[str, list[Path]] = {}
    for name, conf in (TRAINED if trained is None else trained).items():
        folders = [retrained(path, name, jobs, conf) for path in paths]
        if all(f is not None for f in folders):
            done[name] = folders  # type: ignore[assignment]
    return ReferenceRuns(paths, variants, done)
