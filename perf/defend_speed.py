"""Defense speed: how much longer a batch takes to fly with a detector and a response in the loop.

    python -m perf.defend_speed [--flights N] [--detector statistical] [--response return] [--repeat R]
                                [--profile standard] [--in-loop]

Fits the detector on 2 generated normal flights (no run needed), then flies ``N`` normal flights and ``N``
link GPS-spoofing flights (data/scenarios/gps_spoof.toml) with the profile's flight config, undefended and
defended as ``scart-bench defend`` defends them: the undefended batch, the notices its stream raises
(benchmark.defense.replay_notices: the detector's rows and blocks, scored per flight) and the alarmed flights
flown again with the response (generator.defense.DefenseHook with benchmark.defense.ScheduledAlarms). Prints
the times and the ratio defended / undefended, best of ``R`` (the issue's budget: at most 3x on 2 cores).
``--in-loop`` also times the detector inside the loop (benchmark.defense.BatchMonitor at every link step), the
reference the replay is tested against. The threshold is the largest score of the fitting flights, so the
detector alarms (on normal flights too) and the responses are flown.
"""

from __future__ import annotations

import argparse
import dataclasses
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
    p.add_argument("--profile", default="standard", help="flight config of this profile (default standard)")
    p.add_argument("--in-loop", action="store_true", help="also time the detector inside the loop")
    args = p.parse_args(argv)

    import numpy as np

    from scart_bench.benchmark.defense import BatchMonitor, DefendedDetector, ScheduledAlarms, replay_notices
    from scart_bench.dataset.labels import combine
    from scart_bench.detectors import registry
    from scart_bench.generator.attacks import grid_path
    from scart_bench.generator.defense import DefenseHook, Response
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.modes import _builtin_rates
    from scart_bench.generator.profiles import get_profile
    from scart_bench.generator.scart.layer import AttackLayer
    from scart_bench.generator.scart.scenario import load_scenarios
    from scart_bench.generator.telemetry.tables import flight_views

    cfg = dataclasses.replace(get_profile(args.profile).flight_config(), airframes=())  # a layer flies one vehicle
    fit = simulate([9001, 9002], cfg)
    tables = [combine(flight_views(fit, i)[0], [])["most_frequent"] for i in range(2)]
    det = registry.make(args.detector).fit(tables)
    threshold = max(float(det.score(t).max()) for t in tables)
    defended_det = DefendedDetector(args.detector, det, threshold, burn_in_s=5.0)
    seeds = list(range(100, 100 + args.flights))
    spoof = load_scenarios(grid_path("gps_spoof.toml"))
    response = Response(args.response)
    stats: dict[str, int] = {"attacked": 0}
    simulate(seeds[:1], cfg, layer=DefenseHook(BatchMonitor(det, threshold, 1), response, 1))  # compile
    simulate(seeds[:1], cfg)

    def layer(sds):
        return AttackLayer([list(spoof) for _ in sds], sds, rates=_builtin_rates()) if stats["attacked"] else None

    def undefended():
        return simulate(seeds, cfg, layer=layer(seeds))

    def replayed():
        und = undefended()
        notices = replay_notices(und, defended_det, response.alarms)
        hit = np.flatnonzero(notices.notice_us >= 0)
        if hit.size:
            sds = [seeds[i] for i in hit]
            hook = DefenseHook(ScheduledAlarms(notices.notice_us[hit], 1), response, len(sds), layer(sds))
            simulate(sds, cfg, layer=hook)
        stats["alarmed"] = int(hit.size)

    def in_loop():
        mon = BatchMonitor(det, threshold, len(seeds), burn_in_s=5.0)
        simulate(seeds, cfg, layer=DefenseHook(mon, response, len(seeds), layer(seeds)))

    print(
        f"{args.flights} flights per batch, profile {args.profile} ({cfg.timing} timing), {args.detector}, "
        f"response {args.response}, best of {args.repeat}"
    )
    total = {"und": 0.0, "replay": 0.0, "loop": 0.0}
    for name, attacked in (("normal", 0), ("gps_spoof", 1)):
        stats["attacked"] = attacked
        tu, tr = _best(undefended, args.repeat), _best(replayed, args.repeat)
        total["und"] += tu
        total["replay"] += tr
        line = (
            f"  {name:10s} undefended {tu:7.2f} s  defended {tr:7.2f} s  ratio {tr / tu:5.2f}"
            f"  ({stats['alarmed']}/{len(seeds)} flights alarmed)"
        )
        if args.in_loop:
            tl = _best(in_loop, args.repeat)
            total["loop"] += tl
            line += f"  [in the loop {tl:7.2f} s  ratio {tl / tu:5.2f}]"
        print(line)
    line = (
        f"  {'all':10s} undefended {total['und']:7.2f} s  defended {total['replay']:7.2f} s  "
        f"ratio {total['replay'] / total['und']:5.2f}"
    )
    if args.in_loop:
        line += f"  [in the loop ratio {total['loop'] / total['und']:5.2f}]"
    print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
