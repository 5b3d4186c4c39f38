"""Defense speed: how much longer a batch takes to fly with a detector and a response in the loop.

    python -m perf.defend_speed [--flights N] [--detector statistical] [--response return] [--repeat R]

Fits the detector on 2 generated normal flights (no run needed), then flies ``N`` normal flights and ``N``
link GPS-spoofing flights (data/scenarios/gps_spoof.toml) undefended and defended (benchmark.defense.
BatchMonitor in generator.defense.DefenseHook), best of ``R``, and prints the fly times and their ratio
(the issue's budget: at most 3x on 2 cores). The threshold is the largest score of the fitting flights, so
the detector alarms and the responses are flown too. ``reject_gps*`` responses add the ``sensor`` point
(Python at every 250 Hz step), the others only the ``link`` and ``command`` points.
"""

from __future__ import annotations

import argparse
import time


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--flights", type=int, default=16)
    p.add_argument("--detector", default="statistical")
    p.add_argument("--response", default="return")
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args(argv)

    from scart_bench.benchmark.defense import BatchMonitor
    from scart_bench.dataset.labels import combine
    from scart_bench.detectors import registry
    from scart_bench.generator.attacks import grid_path
    from scart_bench.generator.defense import DefenseHook, Response
    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.modes import _builtin_rates
    from scart_bench.generator.scart.layer import AttackLayer
    from scart_bench.generator.scart.scenario import load_scenarios
    from scart_bench.generator.telemetry.tables import flight_views

    cfg = FlightConfig(timing="ideal")
    fit = simulate([9001, 9002], cfg)
    tables = [combine(flight_views(fit, i)[0], [])["most_frequent"] for i in range(2)]
    det = registry.make(args.detector).fit(tables)
    threshold = max(float(det.score(t).max()) for t in tables)
    seeds = list(range(100, 100 + args.flights))
    spoof = load_scenarios(grid_path("gps_spoof.toml"))
    response = Response(args.response)
    simulate(seeds[:1], cfg, layer=DefenseHook(BatchMonitor(det, threshold, 1), response, 1))  # compile

    def layer():
        return AttackLayer([list(spoof) for _ in seeds], seeds, rates=_builtin_rates())

    def defended(inner):
        return DefenseHook(
            BatchMonitor(det, threshold, len(seeds), burn_in_s=5.0), response, len(seeds), inner
        )

    rows = [
        ("normal", lambda: simulate(seeds, cfg), lambda: simulate(seeds, cfg, layer=defended(None))),
        (
            "gps_spoof",
            lambda: simulate(seeds, cfg, layer=layer()),
            lambda: simulate(seeds, cfg, layer=defended(layer())),
        ),
    ]
    total_u = total_d = 0.0
    print(
        f"{args.flights} flights per batch, {args.detector}, response {args.response}, best of {args.repeat}"
    )
    for name, und, dfd in rows:
        tu, td = _best(und, args.repeat), _best(dfd, args.repeat)
        total_u, total_d = total_u + tu, total_d + td
        print(f"  {name:10s} undefended {tu:7.2f} s  defended {td:7.2f} s  ratio {td / tu:5.2f}")
    print(
        f"  {'all':10s} undefended {total_u:7.2f} s  defended {total_d:7.2f} s  ratio {total_d / total_u:5.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
