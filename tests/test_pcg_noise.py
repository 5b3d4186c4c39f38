"""The compiled noise (generator.engine.pcg_noise) draws numpy's own normals, value for value."""

from __future__ import annotations

import numpy as np

from scart_bench.generator.engine.pcg_noise import fill_rows, pcg_states
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
