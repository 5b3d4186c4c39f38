"""A plugin's first import and construction, tried in a child process before the run trusts it.

``--plugin file.py:Class`` is code the user named, but a plugin that hangs or crashes while it is
imported or constructed would otherwise hang or kill ``scart-bench run`` itself (that happens in the
parent, outside the jobs' isolation). The probe runs ``python -m scart_bench.benchmark.probe SPEC`` with
a time limit; only when it succeeds does the parent import the plugin.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from scart_bench.errors import RunError

#: Longest a plugin may take to import and construct, at most (the limit is the run's job timeout plus
#: the time a fresh Python needs to import scart-bench on a busy machine, capped at this).
PROBE_TIMEOUT_S = 120.0
STARTUP_S = 15.0


#: specs (with their file's mtime) that passed in this process: a session of runs probes each once
_PASSED: set[tuple[str, int]] = set()


def _key(spec: str) -> tuple[str, int]:
    target = spec.rpartition(":")[0]
    try:
        return spec, os.stat(target).st_mtime_ns if target.endswith(".py") else 0
    except OSError:
        return spec, -1


def probe_plugin(spec: str, timeout_s: float) -> None:
    """RunError naming ``spec`` when importing and constructing it hangs, crashes or fails."""
    key = _key(spec)
    if key in _PASSED:
        return
    limit = min(float(timeout_s) + STARTUP_S, PROBE_TIMEOUT_S)
    try:
        proc = subprocess.run([sys.executable, "-m", "scart_bench.benchmark.probe", spec], capture_output=True,
                              text=True, timeout=limit, stdin=subprocess.DEVNULL, start_new_session=True)
    except subprocess.TimeoutExpired as exc:
        _kill_group(exc)
        raise RunError(f"--plugin {spec}: importing and constructing it did not finish within {limit:g} s; "
                       "nothing was run") from None
    if proc.returncode < 0:
        name = signal.Signals(-proc.returncode).name if -proc.returncode in signal.valid_signals() else "?"
        raise RunError(f"--plugin {spec}: the process importing it died ({name}); nothing was run")
    if proc.returncode != 0:
        lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
        raise RunError(f"--plugin {spec}: {lines[-1] if lines else f'exit code {proc.returncode}'}")
    _PASSED.add(key)


def _kill_group(exc: subprocess.TimeoutExpired) -> None:
    # subprocess.run has killed the child; a grandchild it started would still hold the pipes
    pid = getattr(getattr(exc, "process", None), "pid", None)
    if pid:
        try:
            os.killpg(pid, signal.SIGKILL)
        except OSError:
            pass


def _main(argv: list[str]) -> int:
    from scart_bench.detectors import registry

    (spec,) = argv
    try:
        info = registry.load_plugin(spec)
        info.cls()
    except Exception as exc:  # reported by the parent as one line
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
