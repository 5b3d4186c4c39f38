"""``scart-bench run --device auto|cpu|cuda``: the torch device of the detectors that take one."""

from __future__ import annotations

import pytest

from scart_bench.benchmark.config import RunConfig, read_run_file
from scart_bench.benchmark.selection import resolve_detectors, with_params
from scart_bench.errors import RunError

NAMES = ["statistical", "goad", "telemanom"]


def _params(device: str, params: dict | None = None) -> dict[str, dict]:
    return {c.name: c.params for c in with_params(resolve_detectors(NAMES, {}), params or {}, device)}


def test_auto_leaves_the_detectors_defaults_unchanged():
    assert _params("auto") == {name: {} for name in NAMES}


def test_cpu_goes_to_every_detector_that_takes_a_device_and_param_wins():
    params = _params("cpu", {"telemanom": {"device": "auto"}})
    assert params["goad"] == {"device": "cpu"}
    assert params["telemanom"] == {"device": "auto"}  # an explicit --param is kept
    assert params["statistical"] == {}


def test_cuda_without_a_cuda_device_is_refused_up_front():
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present")
    with pytest.raises(RunError, match="--device cuda: torch sees no CUDA device"):
        _params("cuda")


def test_unknown_device_is_refused_and_the_run_config_records_it(tmp_path):
    with pytest.raises(RunError, match="--device 'gpu': expected one of auto, cpu, cuda"):
        RunConfig(device="gpu")
    assert RunConfig().to_dict()["device"] == "auto"
    run_file = tmp_path / "run.toml"
    run_file.write_text('device = "cpu"\n')
    assert RunConfig(**read_run_file(run_file)).to_dict()["device"] == "cpu"
    run_file.write_text("device = 1\n")
    with pytest.raises(RunError, match="device"):
        read_run_file(run_file)


def test_the_cli_option_reaches_the_run_config():
    from scart_bench.cli.main import build_parser

    args = build_parser().parse_args(["run", "--device", "cpu", "--detectors", "statistical"])
    from scart_bench.cli.run import run_config

    assert run_config(args).device == "cpu"
