"""How a job uses its cores: its share of threads, passive OpenMP waiting, DeepOD's scoring batches."""

from __future__ import annotations

import shutil
import types

import numpy as np
import pandas as pd
import pytest
import torch

from scart_bench.benchmark import executors
from scart_bench.benchmark.jobs import JobSpec
from scart_bench.detectors.base import DetectorError
from scart_bench.detectors.deepod_models import DeepSVDD, isolated_global_state


def test_a_job_gets_its_share_of_threads_and_waits_passively(monkeypatch):
    seen: dict = {}

    class FakePopen:
        def __init__(self, *args, env=None, **kwargs):
            seen.update(env)

    monkeypatch.setattr(executors.subprocess, "Popen", FakePopen)
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    w = executors._launch(JobSpec("d", "s", {}, (), "ds", (), (), threads=3), 10.0)
    w.log.close()
    shutil.rmtree(w.folder)
    assert seen["OMP_NUM_THREADS"] == "3" and seen["MKL_NUM_THREADS"] == "3"
    assert seen["OMP_WAIT_POLICY"] == "PASSIVE"


def test_deepod_n_threads_zero_is_the_jobs_share(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    before = torch.get_num_threads()
    with isolated_global_state(0):
        assert torch.get_num_threads() == 3
    with isolated_global_state(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with pytest.raises(DetectorError, match="n_threads"):
        DeepSVDD(n_threads=-1)._check_params()
    with pytest.raises(DetectorError, match="score_batch_size"):
        DeepSVDD(score_batch_size=0)._check_params()


def _flight(rng: np.random.Generator, n: int) -> pd.DataFrame:
    t = np.arange(n) / 50.0
    return pd.DataFrame({"a.x": np.sin(t) + rng.normal(0, 0.05, n), "a.y": np.cos(0.5 * t) + rng.normal(0, 0.05, n)})


def test_deepod_scores_in_large_batches_without_depending_on_the_flight_length():
    rng = np.random.default_rng(0)
    det = DeepSVDD(epochs=1, max_train_windows=300, score_batch_size=256).fit([_flight(rng, 600)])
    flight = _flight(rng, 700)
    full = det.score(flight)
    assert det.model_.batch_size == 64  # the training batch size is back after scoring
    # a window's score is the same whatever follows it: the flight is padded to whole batches
    assert np.array_equal(det.score(flight.iloc[:300]), full[:300])
    assert det.get_params()["score_batch_size"] == 256


@pytest.mark.parametrize("name", ["deepsvdd", "rdp", "rca", "goad", "neutral"])
def test_deepod_scores_equal_deepods_own_decision_function(name):
    """The adapters score without DeepOD's data loader (and GOAD transforms with one matrix
    product and computes its distances in chunks of windows, without the unused head); the scores
    must stay exactly DeepOD's. 100-window batches: GOAD's last chunk is a partial one."""
    from scart_bench.detectors.registry import make

    rng = np.random.default_rng(1)
    extra = {"model_params": {"n_trans": 8}} if name == "goad" else {}
    det = make(name, epochs=1, max_train_windows=300, score_batch_size=100, **extra).fit([_flight(rng, 600)])
    flight = _flight(rng, 500)
    feats = det._features(det._transform(flight))
    if name == "goad":  # DeepOD's own transformation (float64, one product per affine map), to float32 rounding
        rots = det.model_.affine_weights
        theirs64 = np.stack([feats.dot(r) for r in rots], 2)
        ours = det.model_.transform(feats).numpy()
        assert ours.dtype == np.float32 and ours.shape == theirs64.shape
        assert np.abs(ours - theirs64).max() <= 1e-5 * np.abs(theirs64).max()
    padded = np.concatenate([feats, np.repeat(feats[-1:], (-len(feats)) % 100, axis=0)])
    det.model_.batch_size = 100
    if name == "goad":  # DeepOD's own scoring step, not the adapter's
        from deepod.models.tabular import GOAD as DeepODGOAD

        det.model_.inference_forward = types.MethodType(DeepODGOAD.inference_forward, det.model_)
    with isolated_global_state(1):
        theirs = det.model_.decision_function(padded)[: len(feats)]
    det.model_.__dict__.pop("inference_forward", None)
    det.model_.batch_size = 64
    ours = det.score(flight)
    assert np.array_equal(ours, theirs)
    if name == "goad":  # and one window at a time (streaming) gives the same bits
        assert det.score_last(flight.iloc[:40]) == ours[39]
