"""Parameter specifications: how scenario files are validated, with errors that name the key."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from scart_bench.errors import ScartBenchError


class ScenarioError(ScartBenchError):
    """A scenario or grid file is invalid; the message names the file, the key and what is allowed."""


def read_toml(path: str | Path, what: str = "scenario file") -> dict:
    """Parse a TOML file, turning a missing file or a syntax error into a ScenarioError."""
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{path}: no such {what}")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from exc


@dataclass(frozen=True)
class Param:
    """One parameter of a condition or action."""

    name: str
    kind: type  # float, int, str, bool, list
    default: Any = None
    required: bool = False
    minimum: float | None = None
    maximum: float | None = None
    exclusive_min: bool = False
    help: str = ""
    choices: tuple | None = None

    def check(self, value: Any, where: str) -> Any:
        """Validate and normalise one value (ints accepted for floats)."""
        if self.kind is float:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ScenarioError(f"{where}.{self.name}: expected a number, got {value!r}")
            value = float(value)
            if math.isnan(value):
                raise ScenarioError(f"{where}.{self.name}: expected a number, got NaN")
        elif self.kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise ScenarioError(f"{where}.{self.name}: expected an integer, got {value!r}")
        elif self.kind is bool:
            if not isinstance(value, bool):
                raise ScenarioError(f"{where}.{self.name}: expected true or false, got {value!r}")
        elif self.kind is str:
            if not isinstance(value, str):
                raise ScenarioError(f"{where}.{self.name}: expected a string, got {value!r}")
            if self.choices is not None and value not in self.choices:
                raise ScenarioError(f"{where}.{self.name}: {value!r} is not one of {', '.join(self.choices)}")
        elif self.kind is list:
            if isinstance(value, str):
                value = [value]
            if not isinstance(value, list):
                raise ScenarioError(f"{where}.{self.name}: expected a list, got {value!r}")
        if self.kind in (int, float):
            lo = self.minimum
            if lo is not None and (value < lo or (self.exclusive_min and value == lo)):
                rel = ">" if self.exclusive_min else ">="
                raise ScenarioError(f"{where}.{self.name}: must be {rel} {lo:g}, got {value!r}")
            if self.maximum is not None and value > self.maximum:
                raise ScenarioError(f"{where}.{self.name}: must be <= {self.maximum:g}, got {value!r}")
        return value


def validate_params(params: dict, spec: tuple[Param, ...], where: str, kind_key: str) -> dict:
    """Check a table against a spec: unknown keys, missing required keys, types and ranges."""
    known = {p.name: p for p in spec}
    unknown = [k for k in params if k not in known and k != kind_key]
    if unknown:
        allowed = ", ".join(sorted(known)) or "(none)"
        raise ScenarioError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: {allowed}")
    out = {}
    for p in spec:
        if p.name in params:
            out[p.name] = p.check(params[p.name], where)
        elif p.required:
            raise ScenarioError(f"{where}: missing required key {p.name!r} ({p.help or p.kind.__name__})")
        else:
            out[p.name] = p.default
    return out
