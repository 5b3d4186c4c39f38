"""The compiled noise (generator.engine.pcg_noise) draws numpy's own normals, value for value."""

from __future__ import annotations

import numpy as np

from scart_bench.generator.engine.pcg_noise import fill_rows, fill_rows_parallel, pcg_states
from scart_bench.generator.physics.noise import NOISE_DIM, fill_block


def _generators(n: int) -> list[np.random.Generator]:
    rngs = [np.random.default_rng(np.random.SeedSequence([s, 0x5CA7])) for s in range(n)]
    for g in rngs:
        g.uniform(size=7)  # the initial conditions draw first
    return rngs


def test_compiled_noise_equals_numpy_standard_normal_block_after_block():
    """Blocks of uneven length, a subset of the flights, many draws (the ziggurat's rare tail included)."""
    n = 16
    ours, theirs = pcg_states(_generators(n)), _generators(n)
    rows = np.arange(n, dtype=np.int64)
    for steps, subset in ((500, rows), (137, rows[::3]), (2000, rows[1:])):
        a = np.empty((len(subset), steps, NOISE_DIM))
        b = np.empty_like(a)
        fill_rows(ours, subset, a)
        fill_block(theirs, subset, b)
        np.testing.assert_array_equal(a, b)
    tail = np.empty((1, 40000, NOISE_DIM))  # 1.2 M normals: thousands take the ziggurat's slow paths
    ref = np.empty_like(tail)
    fill_rows(ours, rows[:1], tail)
    fill_block(theirs, rows[:1], ref)
    np.testing.assert_array_equal(tail, ref)


def test_a_generator_other_than_pcg64_is_left_to_numpy():
    assert pcg_states([np.random.Generator(np.random.MT19937(1))]) is None
    assert pcg_states(_generators(2)).shape == (2, 4)


def test_the_parallel_draw_gives_each_flight_the_same_values_as_the_serial_one():
    n = 12
    serial, parallel = pcg_states(_generators(n)), pcg_states(_generators(n))
    rows = np.arange(1, n, dtype=np.int64)
    for steps in (300, 77):
        a = np.empty((len(rows), steps, NOISE_DIM))
        b = np.empty_like(a)
        fill_rows(serial, rows, a)
        fill_rows_parallel(parallel, rows, b)
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(serial, parallel)  # each generator advanced by as much


def test_flights_do_not_depend_on_the_kernel_thread_count():
    """Each flight's noise is drawn by the thread that flies it: 1 or 2 threads, the same flight."""
    import numba

    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.params import MissionParams

    cfg = FlightConfig(mission=MissionParams(max_duration_s=6.0))
    before = numba.get_num_threads()
    try:
        runs = []
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            runs.append(simulate(list(range(9)), cfg))
    finally:
        numba.set_num_threads(before)
    for topic, (_, values, _) in runs[0].simulator.items():
        np.testing.assert_array_equal(values, runs[1].simulator[topic][1], err_msg=topic)
