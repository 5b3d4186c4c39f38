"""Where detectors are found: the built-ins, entry-point plugins and ``--plugin`` specs.

Built-ins are imported lazily (torch is only loaded when a torch detector is used). Plugins are
discovered through the entry-point group ``scart_bench.detectors``; each entry point names a
Detector subclass. ``load_plugin("pkg.module:Class")`` or ``load_plugin("path/to/file.py:Class")``
adds one at run time.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import sys
import warnings
from importlib.metadata import entry_points
from pathlib import Path

from scart_bench.detectors.base import Detector, DetectorError

ENTRY_POINT_GROUP = "scart_bench.detectors"

#: name -> "module:Class" of the paper's eight detectors, in the paper's order (``--detectors all``).
PAPER: dict[str, str] = {
    "telemanom": "scart_bench.detectors.telemanom:Telemanom",
    "tsbitmaps": "scart_bench.detectors.tsbitmaps:TSBitmaps",
    "statistical": "scart_bench.detectors.statistical:Statistical",
    "deepsvdd": "scart_bench.detectors.deepod_models:DeepSVDD",
    "rdp": "scart_bench.detectors.deepod_models:RDP",
    "rca": "scart_bench.detectors.deepod_models:RCA",
    "goad": "scart_bench.detectors.deepod_models:GOAD",
    "neutral": "scart_bench.detectors.deepod_models:NeuTraL",
}

#: name -> "module:Class" of the zoo (issue 50): detectors the field uses beside the paper's eight,
#: each an adapter of scikit-learn, PyOD or DeepOD where one ships (``--detectors zoo``).
ZOO: dict[str, str] = {
    "iforest": "scart_bench.detectors.zoo_tabular:IForest",
    "pca": "scart_bench.detectors.zoo_tabular:PCAReconstruction",
    "kmeans": "scart_bench.detectors.zoo_tabular:KMeansDistance",
    "knn": "scart_bench.detectors.zoo_tabular:KNNDistance",
    "lof": "scart_bench.detectors.zoo_tabular:LOF",
    "ecod": "scart_bench.detectors.zoo_tabular:ECOD",
    "copod": "scart_bench.detectors.zoo_tabular:COPOD",
    "hbos": "scart_bench.detectors.zoo_tabular:HBOS",
    "lstm_ae": "scart_bench.detectors.zoo_torch:LSTMAutoencoder",
    "tcned": "scart_bench.detectors.zoo_deepod:TcnED",
    "usad": "scart_bench.detectors.zoo_deepod:USAD",
    "deepsvdd_ts": "scart_bench.detectors.zoo_deepod:DeepSVDDTS",
    "dif_ts": "scart_bench.detectors.zoo_deepod:DIFTS",
}

#: name -> "module:Class" of every built-in: the paper's eight, then the zoo.
BUILTINS: dict[str, str] = {**PAPER, **ZOO}

#: Names that stand for a set of built-ins in ``--detectors`` and a run file's ``detectors``
#: (``all`` is the paper's eight and every plugin: see scart_bench.benchmark.selection).
TAGS: dict[str, tuple[str, ...]] = {"paper": tuple(PAPER), "zoo": tuple(ZOO)}


def tag_of(name: str) -> str | None:
    """The tag of a built-in ("paper" or "zoo"), None for a plugin."""
    return next((tag for tag, names in TAGS.items() if name in names), None)


class DetectorInfo:
    """A detector and where it came from ("built-in" or the plugin's origin).

    The class is imported on first use of ``cls``, so listing detectors does not load torch.
    """

    def __init__(self, name: str, spec: str | type, source: str):
        self.name = name
        self.source = source
        self._spec = spec

    @property
    def cls(self) -> type:
        if isinstance(self._spec, str):
            self._spec = _import_spec(self._spec)
        return self._spec

    @property
    def description(self) -> str:
        return (self.cls.description or (self.cls.__doc__ or "").strip().split("\n")[0]).strip()

    def parameters(self) -> dict[str, object]:
        sig = inspect.signature(self.cls.__init__)
        return {
            p.name: (None if p.default is inspect.Parameter.empty else p.default)
            for p in sig.parameters.values()
            if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        }


_PLUGINS: dict[str, DetectorInfo] = {}


def _import_spec(spec: str) -> type:
    if ":" not in spec:
        raise DetectorError(f"plugin spec {spec!r}: expected 'module:Class' or 'path/to/file.py:Class'")
    target, _, clsname = spec.rpartition(":")
    if target.endswith(".py"):
        path = Path(target)
        if not path.is_file():
            raise DetectorError(f"plugin spec {spec!r}: file {path} does not exist")
        modname = f"scart_bench_plugin_{path.stem}"
        mod_spec = importlib.util.spec_from_file_location(modname, path)
        module = importlib.util.module_from_spec(mod_spec)
        sys.modules[modname] = module
        mod_spec.loader.exec_module(module)
    else:
        try:
            module = importlib.import_module(target)
        except ImportError as exc:
            raise DetectorError(f"plugin spec {spec!r}: cannot import module {target!r}: {exc}") from exc
    cls = getattr(module, clsname, None)
    if cls is None:
        raise DetectorError(f"plugin spec {spec!r}: module {target!r} has no attribute {clsname!r}")
    if not (inspect.isclass(cls) and issubclass(cls, Detector)):
        raise DetectorError(f"plugin spec {spec!r}: {clsname} is not a scart_bench.detectors.base.Detector subclass")
    return cls


def load_plugin(spec: str) -> DetectorInfo:
    """Import a detector class from ``module:Class`` or ``file.py:Class`` and register it."""
    cls = _import_spec(spec)
    name = cls.__dict__.get("name")
    if not isinstance(name, str) or not name:
        raise DetectorError(f"plugin spec {spec!r}: {cls.__name__} must set a class attribute `name`")
    if name in TAGS or name == "all":
        raise DetectorError(f"plugin spec {spec!r}: name {name!r} stands for a set of detectors in --detectors; "
                            "choose another")
    if name in BUILTINS:
        if _import_spec(BUILTINS[name]) is cls:  # the built-in itself, named by its module
            return DetectorInfo(name, cls, "built-in")
        raise DetectorError(f"plugin spec {spec!r}: name {name!r} is taken by a built-in detector")
    info = DetectorInfo(name, cls, f"plugin ({spec})")
    _PLUGINS[name] = info
    return info


def plugin_names() -> list[str]:
    """Names of the detectors loaded with ``load_plugin``."""
    return list(_PLUGINS)


def available() -> dict[str, DetectorInfo]:
    """Every known detector: built-ins, entry-point plugins, then ``load_plugin`` ones."""
    found: dict[str, DetectorInfo] = {name: DetectorInfo(name, spec, "built-in") for name, spec in BUILTINS.items()}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep, "dist", None)
        origin = f"plugin ({dist.name} {dist.version})" if dist is not None else f"plugin ({ep.value})"
        try:
            cls = ep.load()
        except Exception as exc:  # a broken plugin must not hide the others
            warnings.warn(f"detector plugin {ep.name} ({ep.value}) cannot be loaded: {exc}", stacklevel=2)
            continue
        name = getattr(cls, "name", ep.name)
        if name in BUILTINS:
            warnings.warn(f"detector plugin {ep.value} uses the built-in name {name!r}; skipped", stacklevel=2)
            continue
        found[name] = DetectorInfo(name, cls, origin)
    found.update(_PLUGINS)
    return found


def names() -> list[str]:
    """Names of every known detector, built-ins first."""
    return list(available())


def make(name: str, **params) -> Detector:
    """A new, unfitted detector by name."""
    if name in BUILTINS:
        return _import_spec(BUILTINS[name])(**params)
    if name in _PLUGINS:
        return _PLUGINS[name].cls(**params)
    known = available()
    if name not in known:
        raise DetectorError(f"unknown detector {name!r}; known: {', '.join(known)}")
    return known[name].cls(**params)
