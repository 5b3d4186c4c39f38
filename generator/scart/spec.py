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


#: Largest scenario/grid file read (bytes): a scenario is a few kilobytes; a grid a few hundred.
MAX_FILE_BYTES = 4 * 1024 * 1024
#: Largest magnitude of any number in a scenario unless a parameter says otherwise: far beyond any
#: physical value in the field's units (m, m/s, rad, s), far below what overflows a float computation.
MAX_MAGNITUDE = 1e7


def read_toml(path: str | Path, what: str = "scenario file") -> dict:
    """Parse a TOML file, turning a missing, unreadable, oversized or invalid file into a ScenarioError."""
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{path}: no such {what}")
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ScenarioError(f"{path}: {size} bytes; a {what} is at most {MAX_FILE_BYTES} bytes")
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from exc
    except RecursionError:
        raise ScenarioError(f"{path}: nested too deeply to be a {what}") from None


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
    allow_inf: bool = False  # +inf is a meaningful value (e.g. "no end"); otherwise numbers must be finite
    item: type | None = None  # the type of a list's items (str for targets, float for coordinates)
    min_items: int = 0
    max_items: int | None = None

    def check(self, value: Any, where: str) -> Any:
        """Validate and normalise one value (ints accepted for floats)."""
        if self.kind is float:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ScenarioError(f"{where}.{self.name}: expected a number, got {value!r}")
            value = float(value)
            if math.isnan(value):
                raise ScenarioError(f"{where}.{self.name}: expected a number, got NaN")
            if math.isinf(value) and not (self.allow_inf and value > 0):
                raise ScenarioError(f"{where}.{self.name}: expected a finite number, got {value!r}")
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
            if len(value) < self.min_items or (self.max_items is not None and len(value) > self.max_items):
                n = (f"{self.min_items}" if self.max_items == self.min_items
                     else f"{self.min_items}-{self.max_items}" if self.max_items is not None
                     else f"at least {self.min_items}")
                raise ScenarioError(f"{where}.{self.name}: expected {n} item(s), got {len(value)}")
            if self.item is str:
                bad = [v for v in value if not isinstance(v, str) or not v]
                if bad:
                    raise ScenarioError(f"{where}.{self.name}: expected names (strings), got {bad[0]!r}")
            elif self.item is float:
                for v in value:
                    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                            or abs(v) > MAX_MAGNITUDE:
                        raise ScenarioError(f"{where}.{self.name}: expected finite numbers, got {v!r}")
                value = [float(v) for v in value]
        if self.kind in (int, float):
            lo = self.minimum
            if lo is not None and (value < lo or (self.exclusive_min and value == lo)):
                rel = ">" if self.exclusive_min else ">="
                raise ScenarioError(f"{where}.{self.name}: must be {rel} {lo:g}, got {value!r}")
            if self.maximum is not None and value > self.maximum:
                raise ScenarioError(f"{where}.{self.name}: must be <= {self.maximum:g}, got {value!r}")
            if abs(value) > MAX_MAGNITUDE and not (self.allow_inf and math.isinf(value)) and self.maximum is None:
                raise ScenarioError(f"{where}.{self.name}: {value!r} is out of range (|value| <= {MAX_MAGNITUDE:g})")
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
