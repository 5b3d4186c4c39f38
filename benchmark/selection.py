"""Which detectors a run uses: names, ``--plugin`` specs and the parameters given for them.

``--param NAME.KEY=VALUE`` (or a ``[params.NAME]`` table of ``--config``) sets a constructor parameter of
detector NAME; for the DeepOD adapters a key of the underlying model (e.g. ``goad.n_trans``) goes into
``model_params``. Unknown detectors, unknown keys and values of the wrong type are refused with a
:class:`~scart_bench.errors.RunError` naming the parameter, before anything runs.
"""

from __future__ import annotations

import inspect
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from scart_bench.benchmark.store import json_safe
from scart_bench.errors import RunError
from scart_bench.names import check_id


@dataclass(frozen=True)
class DetectorChoice:
    """A detector of the run: its name, class, how a worker loads the class, and its parameters."""

    name: str
    cls: type
    source: str
    params: dict = field(default_factory=dict)

    def overrides(self, seed: int) -> dict:
        """Constructor arguments set by the run: the seed (where the detector takes one) and the
        parameters given with ``--param`` / ``--config``."""
        accepted = inspect.signature(self.cls.__init__).parameters
        seeded = {"random_state": int(seed)} if "random_state" in accepted else {}
        return {**seeded, **self.params}

    def params_of(self, seed: int) -> dict:
        """Every constructor parameter of the detector as the job builds it."""
        return json_safe(self.cls(**self.overrides(seed)).get_params(deep=False))


def absolute_plugin(spec: str) -> str:
    """A plugin spec with its file path made absolute (module specs unchanged)."""
    target, sep, cls = spec.rpartition(":")
    if sep and target.endswith(".py"):
        return f"{Path(target).resolve()}:{cls}"
    return spec


def load_plugins(specs: list[str], probe_timeout_s: float | None = None) -> dict[str, DetectorChoice]:
    """Load ``--plugin`` specs (file paths made absolute so workers anywhere can load them).

    With ``probe_timeout_s``, each spec is first imported and constructed in a child process with that
    time limit (:mod:`scart_bench.benchmark.probe`), so a plugin that hangs or crashes there is refused
    instead of hanging or killing this process.
    """
    from scart_bench.benchmark.probe import probe_plugin
    from scart_bench.detectors import registry

    out = {}
    for spec in specs:
        absolute = absolute_plugin(spec)
        if probe_timeout_s is not None:
            probe_plugin(absolute, probe_timeout_s)
        info = registry.load_plugin(absolute)
        out[info.name] = DetectorChoice(info.name, info.cls, absolute)
    return out


def _parse_names(names: list[str]) -> list[str]:
    out: list[str] = []
    for item in names:
        for n in str(item).split(","):
            n = n.strip()
            if n and n not in out:
                out.append(n)
    if not out:
        raise RunError("--detectors: expected 'all' or a comma-separated list of names")
    return out


def resolve_detectors(names: list[str], plugins: dict[str, DetectorChoice]) -> list[DetectorChoice]:
    """The detectors to run, in order; ``["all"]`` means the paper's eight and every plugin.

    A tag of ``registry.TAGS`` (``zoo``, ``paper``) stands for its built-ins and mixes with names.
    """
    from scart_bench.detectors import registry

    names = _parse_names(names)
    names = list(dict.fromkeys(n for name in names for n in registry.TAGS.get(name, (name,))))

    def choice(info) -> DetectorChoice:
        if info.name in plugins:
            return plugins[info.name]
        if info.name in registry.BUILTINS:
            return DetectorChoice(info.name, info.cls, registry.BUILTINS[info.name])
        return DetectorChoice(info.name, info.cls, f"{info.cls.__module__}:{info.cls.__qualname__}")

    if names == ["all"]:
        chosen = [choice(info) for info in registry.available().values() if info.name not in registry.ZOO]
        for c in chosen:
            check_id(c.name, f"detector name (from {c.source})")
        return chosen
    if "all" in names:
        raise RunError("--detectors: 'all' cannot be combined with names")
    chosen = []
    for name in names:
        if name in plugins:
            chosen.append(plugins[name])
        elif name in registry.BUILTINS:
            cls = type(registry.make(name))
            chosen.append(DetectorChoice(name, cls, registry.BUILTINS[name]))
        else:
            try:
                known = registry.available()
            except ValueError:
                known = {}
            if name not in known:
                listed = ", ".join(dict.fromkeys([*registry.BUILTINS, *plugins, *known]))
                raise RunError(f"--detectors: unknown detector {name!r}; expected one of: {listed} "
                                 "(or load one with --plugin module:Class)")
            chosen.append(choice(known[name]))
    for c in chosen:
        check_id(c.name, f"detector name (from {c.source})")
    return chosen


# -- detector parameters ------------------------------------------------------------------------

def parse_value(text: str) -> object:
    """A parameter value from the command line: a TOML literal (``64``, ``0.5``, ``true``, ``[32, 32]``,
    ``"cpu"``), or the text itself when it is not one (``cpu``)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_params(items: list[str]) -> dict[str, dict]:
    """``["goad.n_trans=64", "telemanom.epochs=5"]`` -> ``{"goad": {"n_trans": 64}, "telemanom": {"epochs": 5}}``."""
    out: dict[str, dict] = {}
    for item in items:
        key, sep, value = str(item).partition("=")
        name, dot, param = key.strip().partition(".")
        if not sep or not dot or not name or not param:
            raise RunError(f"--param {item!r}: expected DETECTOR.PARAMETER=VALUE, e.g. goad.n_trans=64")
        out.setdefault(name, {})[param] = parse_value(value.strip())
    return out


def _model_signature(cls: type) -> dict[str, inspect.Parameter]:
    """Parameters of the model a DeepOD-style adapter builds (``_model_class``), if it has one."""
    model = getattr(cls, "_model_class", None)
    if model is None:
        return {}
    return {k: p for k, p in inspect.signature(model.__init__).parameters.items()
            if k != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}


def _type_ok(value: object, default: object) -> bool:
    """Whether ``value`` has a type the parameter takes, judged by its default (None: anything)."""
    if default is None or default is inspect.Parameter.empty:
        return True
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    if isinstance(default, tuple | list):
        return isinstance(value, tuple | list)
    if isinstance(default, dict):
        return isinstance(value, dict)
    return True


def _expected(default: object) -> str:
    if isinstance(default, bool):
        return "true or false"
    return {int: "an integer", float: "a number", str: "a string", tuple: "a list", list: "a list",
            dict: "a table"}.get(type(default), type(default).__name__)


def check_params(name: str, cls: type, params: dict) -> dict:
    """The constructor arguments for ``params`` given to detector ``name``: checked, with keys of the
    underlying model moved into ``model_params``. RunError naming the parameter when one is wrong."""
    own = {k: p for k, p in inspect.signature(cls.__init__).parameters.items()
           if k != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
    model = _model_signature(cls) if "model_params" in own else {}
    out: dict = {}
    for key, value in params.items():
        if key in ("random_state",):
            raise RunError(f"--param {name}.{key}: set by the run's --seed, not per detector")
        if key in own:
            default = own[key].default
            if isinstance(default, tuple) and isinstance(value, list):
                value = tuple(value)
        elif key in model:
            default = model[key].default
            out.setdefault("model_params", dict(params.get("model_params") or {}))[key] = value
        else:
            known = sorted([*own, *model])
            raise RunError(f"--param {name}.{key}: {name} has no parameter {key!r}; its parameters: "
                           f"{', '.join(k for k in known if k != 'random_state')}")
        if not _type_ok(value, default):
            raise RunError(f"--param {name}.{key}={value!r}: expected {_expected(default)} "
                           f"(default {default!r})")
        if key in own:
            out[key] = value
    try:
        detector = cls(**out)
    except (TypeError, ValueError) as exc:
        raise RunError(f"--param {name}: {exc}") from exc
    validate = getattr(detector, "_check_params", None)
    if callable(validate):
        try:
            validate()
        except ValueError as exc:
            raise RunError(f"--param {name}: {exc}") from exc
    return out


def with_params(chosen: list[DetectorChoice], params: dict[str, dict], device: str = "auto") -> list[DetectorChoice]:
    """``chosen`` with the given parameters attached; parameters for a detector not in the run are refused.

    ``device`` other than "auto" (``--device cpu|cuda``) becomes the ``device`` parameter of every
    detector that takes one and was not given one with ``--param``; "auto" leaves the detectors'
    own default (cuda when available, else cpu). "cuda" without a CUDA device is refused here.
    """
    names = [c.name for c in chosen]
    for name in params:
        if name not in names:
            raise RunError(f"--param {name}.*: {name!r} is not a detector of this run ({', '.join(names)})")
    params = {k: dict(v) for k, v in params.items()}
    if device != "auto":
        takes = [c.name for c in chosen if "device" in inspect.signature(c.cls.__init__).parameters]
        if device == "cuda" and takes:
            import torch

            if not torch.cuda.is_available():
                raise RunError(f"--device cuda: torch sees no CUDA device here (detectors {', '.join(takes)}); "
                               "use --device auto or cpu")
        for name in takes:
            params.setdefault(name, {}).setdefault("device", device)
    return [DetectorChoice(c.name, c.cls, c.source, check_params(c.name, c.cls, params[c.name]))
            if params.get(c.name) else c for c in chosen]
