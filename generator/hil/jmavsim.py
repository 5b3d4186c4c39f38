"""Start and stop jMAVSim (PX4's Java multirotor simulator) for the bridge: headless, lockstep, a free port.

The project does not ship jMAVSim. A user builds it from its own repository (docs/jmavsim.md) and
names the result with ``--jmavsim PATH`` or the environment variable ``SCART_JMAVSIM``: the jar
``jmavsim_run.jar`` or the checkout it was built in (``out/production/jmavsim_run.jar``).
What is missing is said in one line (:class:`HilError`): Java, the jar, or a simulator that never
sends its first message.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from scart_bench.generator.hil.errors import HilError

ENV_VAR = "SCART_JMAVSIM"
JAR_NAME = "jmavsim_run.jar"
#: lockstep speed-up asked of jMAVSim (PX4_SIM_SPEED_FACTOR): its loop ticks this much faster than
#: 250 Hz; the flight then runs as fast as the bridge answers, up to this multiple of real time
DEFAULT_SPEED = 20.0


def find_java() -> str:
    """The ``java`` executable on PATH, or a one-line HilError."""
    java = shutil.which("java")
    if java is None:
        raise HilError("jMAVSim needs Java and none is on PATH: install a Java runtime "
                       "(Debian: apt-get install default-jdk-headless)")
    return java


def find_jar(path: str | os.PathLike | None = None) -> Path:
    """jMAVSim's ``jmavsim_run.jar`` from ``path`` (a jar or a build folder) or ``$SCART_JMAVSIM``."""
    given = path if path is not None else os.environ.get(ENV_VAR)
    if not given:
        raise HilError(f"no jMAVSim given: pass --jmavsim PATH or set {ENV_VAR} to its {JAR_NAME} or build "
                       "folder (docs/jmavsim.md says how to build it)")
    p = Path(given).expanduser()
    for cand in (p, p / JAR_NAME, p / "out" / "production" / JAR_NAME):
        if cand.is_file() and cand.suffix == ".jar":
            return cand.resolve()
    raise HilError(f"jMAVSim: no {JAR_NAME} at {str(p)!r} (build it with `ant create_run_jar copy_res` "
                   "in a jMAVSim checkout, see docs/jmavsim.md)")


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port free on ``host`` now (the OS's pick)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now (the OS's pick)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def build(source: str | os.PathLike, dest: str | os.PathLike) -> Path:
    """Copy a jMAVSim checkout ``source`` into ``dest`` and build it with ant; returns the jar.

    The build happens in the copy, so ``source`` may be read-only (``../shared/sim/jmavsim``).
    """
    ant = shutil.which("ant")
    if ant is None:
        raise HilError("building jMAVSim needs ant and none is on PATH (Debian: apt-get install ant)")
    find_java()
    work = Path(dest) / "jmavsim"
    shutil.copytree(source, work, dirs_exist_ok=True)
    proc = subprocess.run([ant, "-q", "create_run_jar", "copy_res"], cwd=work, capture_output=True, text=True,
                          timeout=600)
    if proc.returncode != 0:
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-1:] or ["no output"]
        raise HilError(f"building jMAVSim in {work} failed: {tail[0]}")
    return find_jar(work)


class JMavSim:
    """A jMAVSim process, headless, waiting for its flight controller on ``port`` (lockstep by default).

    ``transport``: ``udp`` (jMAVSim's ``-udp PORT``: it answers whoever sends first) or ``tcp``
    (``-tcp 127.0.0.1:PORT``: it serves the port and the flight controller connects).
    ``lockstep`` False: jMAVSim runs on its own clock, in real time, and the bridge follows it.
    Use as a context manager; :meth:`stop` ends it (and only it). Its output goes to ``log_path``.
    """

    def __init__(self, jar: str | os.PathLike | None = None, port: int | None = None, lockstep: bool = True,
                 speed: float = DEFAULT_SPEED, rate_hz: int = 250, transport: str = "udp"):
        if transport not in ("udp", "tcp"):
            raise HilError(f"jMAVSim transport {transport!r}: expected udp or tcp")
        self.java = find_java()
        self.jar = find_jar(jar)
        self.transport = transport
        self.port = int(port) if port else (free_udp_port() if transport == "udp" else free_tcp_port())
        self.lockstep = lockstep
        self.speed = float(speed)
        self.rate_hz = int(rate_hz)
        self.proc: subprocess.Popen | None = None
        self.log_path: Path | None = None

    @property
    def address(self) -> tuple[str, int]:
        return ("127.0.0.1", self.port)

    @property
    def link_address(self) -> str:
        """Where the bridge reaches this simulator (:func:`scart_bench.generator.hil.link.open_link`)."""
        return f"{self.transport}:127.0.0.1:{self.port}"

    def command(self) -> list[str]:
        where = ["-udp", str(self.port)] if self.transport == "udp" else ["-tcp", f"127.0.0.1:{self.port}"]
        cmd = [self.java, "-Djava.awt.headless=true", "-jar", str(self.jar), "-no-gui", *where,
               "-r", str(self.rate_hz)]
        return cmd + (["-lockstep"] if self.lockstep else [])

    def start(self) -> JMavSim:
        """Start the process; it waits for the first datagram on its port."""
        fd, name = tempfile.mkstemp(prefix="jmavsim-", suffix=".log")
        self.log_path = Path(name)
        env = dict(os.environ)
        if self.lockstep:
            env["PX4_SIM_SPEED_FACTOR"] = f"{self.speed:g}"
        with os.fdopen(fd, "wb") as log:
            self.proc = subprocess.Popen(self.command(), cwd=self.jar.parent, stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, env=env)
        time.sleep(0.05)
        if self.proc.poll() is not None:
            raise HilError(f"jMAVSim exited at start (code {self.proc.returncode}): {self.last_line()}")
        return self

    def last_line(self) -> str:
        """The last line jMAVSim printed (for error messages)."""
        try:
            lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        except (OSError, AttributeError):
            return "no output"
        return lines[-1].strip() if lines else "no output"

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        """End the process (terminate, then kill after 3 s) and remove its log."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=3)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=3)
        if self.log_path is not None:
            self.log_path.unlink(missing_ok=True)

    def __enter__(self) -> JMavSim:
        return self.start() if self.proc is None else self

    def __exit__(self, *exc) -> None:
        self.stop()
