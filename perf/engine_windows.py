"""The window classifier between two engines: can it tell the built-in engine's flights from jMAVSim's?

    python -m perf.engine_windows --builtin DIR --jmavsim DIR [--phases ground,hover,cruise,all] [--top N]

Both datasets are ``generate --physics jmavsim`` datasets of the same seeds (``--physics`` jmavsim,
and :func:`scart_bench.generator.hil.dataset.generate_jmavsim` with ``physics="builtin"`` for the
built-in engine, one flight at a time, ideal timing): the same missions flown by the project's flight
software, once over the built-in physics and sensors, once over jMAVSim's. Their normal flights'
simulator views (the flight controller's telemetry) go through the realism check of
:mod:`perf.realism_windows` (10 s windows, per phase, cross-validated by flight), the built-in side in
the place of the generated flights and jMAVSim's in the place of the real ones. A flight AUC near 0.5
says the detectors see the same kind of flight from either physics; near 1.0, which features differ.
"""

from __future__ import annotations

import argparse

from perf.realism_windows import PHASES, compare, read_dataset


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.engine_windows", description=__doc__.splitlines()[0])
    p.add_argument("--builtin", required=True, help="dataset of the built-in engine's flights")
    p.add_argument("--jmavsim", required=True, help="dataset of jMAVSim's flights (the same seeds)")
    p.add_argument("--phases", default=",".join(PHASES), help="phases to compare (default: all)")
    p.add_argument("--top", type=int, default=8, help="most separating features shown per phase (default 8)")
    p.add_argument("--folds", type=int, default=4, help="cross-validation folds by flight (default 4)")
    args = p.parse_args(argv)
    builtin, jms = read_dataset(args.builtin), read_dataset(args.jmavsim)
    result = compare(builtin, jms, phases=tuple(args.phases.split(",")), folds=args.folds, log_set="jMAVSim",
                     groups=False)
    print(f"built-in engine: {len(builtin)} flights ({args.builtin}); jMAVSim: {len(jms)} flights ({args.jmavsim})")
    print(result.report(top=args.top))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
