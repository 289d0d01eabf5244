"""Run one command on one input in a forked child and classify how it ended.

The child is forked from a forkserver (:mod:`multiprocessing`) that imported wtml, torch and
lightning once and never ran a torch operation: imports are paid once, state is isolated, and
no thread pool is inherited. (A fork of the test process itself deadlocks in its first
parallel torch operation once an earlier test ran one with more than one thread: OpenMP is
not fork-safe.) The child redirects file descriptors 1 and 2 to files, caps its address space
(a runaway allocation ends in a ``MemoryError`` there, not in the machine's swap), starts
:mod:`tracemalloc` (numpy registers its allocations there) and an alarm, runs
``wtml.cli.main`` or ``wtml.training.cli_main`` in-process, and writes its report to a file.
The parent kills a child that outlives its limit.

Outcomes (:data:`GOOD` satisfy the contract, the rest are failures):

- ``ok``: exit 0, nothing wrong seen;
- ``flagged``: exit 0 with the answer flagged (a warning, ``in_domain`` 0, flags);
- ``clear``: exit 2 with exactly one line on stderr naming the file;
- ``unnamed``: exit 2, one line, but it names neither the file nor its folder;
- ``multiline``: exit 2 (or another code) with several lines: a usage dump, log lines;
- ``traceback``: an exception escaped (or a traceback was printed);
- ``exit``: another exit code, or exit 0 with an error printed;
- ``memory``: a ``MemoryError``, or a traced peak over ``wtml.files.MEMORY_CEILING``;
- ``hang``: over the time limit;
- ``silent``: exit 0 with an answer that differs from the untampered file's, not flagged
  (kinds whose files must be refused when edited: exports).
"""

from __future__ import annotations

import io
import json
import multiprocessing
import os
import resource
import signal
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from wtml.files import MEMORY_CEILING

GOOD = ("ok", "flagged", "clear")
BAD = ("unnamed", "multiline", "exit", "traceback", "memory", "hang", "silent")
OUTCOMES = GOOD + BAD


class Hang(BaseException):
    """Raised by the child's alarm: not an Exception, so no ``except Exception`` swallows it."""


@dataclass
class Result:
    """What one run did."""

    outcome: str
    rc: int | None
    stdout: str = ""
    stderr: str = ""
    error: str = ""
    """The escaped exception's last traceback lines, if any."""
    peak: int = 0
    """tracemalloc's peak, bytes."""
    seconds: float = 0.0
    names: tuple[str, ...] = field(default_factory=tuple)

    def summary(self) -> str:
        tail = self.error or self.stderr.strip()[-600:]
        return (f"{self.outcome} (rc {self.rc}, {self.seconds:.1f} s, peak "
                f"{self.peak / 2**20:.0f} MiB): {tail}")


def _vm_bytes() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


def _child(entry: str, argv: list[str], cwd: Path, limit_s: float, out_dir: Path) -> None:
    import tracemalloc
    import warnings

    report: dict = {"rc": None, "error": "", "exc": "", "peak": 0}
    try:
        os.chdir(cwd)
        for fd, name in ((1, "stdout"), (2, "stderr")):
            f = os.open(out_dir / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(f, fd)
            os.close(f)
        sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", closefd=False), line_buffering=True)
        sys.stderr = io.TextIOWrapper(os.fdopen(2, "wb", closefd=False), line_buffering=True)
        sys.stdin = open(os.devnull)
        # what a user's interpreter does with warnings, not pytest's "error"
        warnings.resetwarnings()
        for cat in (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                    ResourceWarning):
            warnings.filterwarnings("ignore", category=cat)
        os.environ["CI"] = "1"
        cap = _vm_bytes() + MEMORY_CEILING + 2 * 2**30
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

        def alarm(signum, frame):
            raise Hang

        signal.signal(signal.SIGALRM, alarm)
        tracemalloc.start()
        signal.setitimer(signal.ITIMER_REAL, limit_s)
        try:
            if entry == "wtml":
                from wtml.cli import main

                rc = main(argv)
            else:
                from wtml.training import cli_main

                cli_main(argv)
                rc = 0
        except SystemExit as err:
            code = err.code
            rc = code if isinstance(code, int) else (0 if code is None else 1)
            if not isinstance(code, int | None):
                print(code, file=sys.stderr)
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            report["peak"] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        report["rc"] = rc
    except Hang:
        report["exc"] = "Hang"
    except MemoryError:
        report["exc"] = "MemoryError"
        report["error"] = "".join(traceback.format_exc(limit=-3))[-1500:]
    except BaseException as err:  # noqa: B036 - everything that escaped is the finding
        report["exc"] = type(err).__name__
        report["error"] = "".join(traceback.format_exc(limit=-3))[-1500:]
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except BaseException:  # noqa: B036
        pass
    (out_dir / "report.json").write_text(json.dumps(report))
    os._exit(0)


_CONTEXT: multiprocessing.context.BaseContext | None = None


def _context() -> multiprocessing.context.BaseContext:
    """The forkserver context, its server preloading what every command imports."""
    global _CONTEXT
    if _CONTEXT is None:
        _CONTEXT = multiprocessing.get_context("forkserver")
        _CONTEXT.set_forkserver_preload(["wtml.cli", "wtml.training", __name__])
    return _CONTEXT


def _read(path: Path) -> str:
    return path.read_text(errors="replace") if path.exists() else ""


def run(entry: str, argv: list[str], *, cwd: Path, limit_s: float = 30.0,
        names: tuple[str, ...] = ()) -> Result:
    """Run ``argv`` through ``entry`` (``"wtml"``: :func:`wtml.cli.main`; ``"train"``:
    :func:`wtml.training.cli_main`) in a forked child in ``cwd``, at most ``limit_s`` seconds;
    ``names`` are the strings one of which a clear error must contain (the file's path, its
    name, its folder)."""
    out_dir = Path(cwd) / ".fuzz_io"
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "report.json").unlink(missing_ok=True)
    start = time.perf_counter()
    child = _context().Process(target=_child, args=(entry, list(argv), Path(cwd), limit_s,
                                                    out_dir), daemon=True)
    child.start()
    child.join(limit_s + 20.0)
    killed = child.is_alive()
    if killed:
        child.kill()
        child.join()
    seconds = time.perf_counter() - start
    stdout, stderr = _read(out_dir / "stdout"), _read(out_dir / "stderr")
    if killed:
        return Result("hang", None, stdout, stderr, "killed after the time limit", 0, seconds,
                      names)
    try:
        report = json.loads(_read(out_dir / "report.json"))
    except ValueError:
        return Result("traceback", None, stdout, stderr,
                      f"the child died (exit code {child.exitcode})", 0, seconds, names)
    return classify(report, stdout, stderr, seconds, names)


FLAG_WORDS = ("warning", "outside the trained", "impossible", "in_domain = 0")


def classify(report: dict, stdout: str, stderr: str, seconds: float,
             names: tuple[str, ...]) -> Result:
    rc, exc, peak = report["rc"], report["exc"], report["peak"]

    def result(outcome: str) -> Result:
        return Result(outcome, rc, stdout, stderr, report["error"], peak, seconds, names)

    if exc == "Hang":
        return result("hang")
    if exc == "MemoryError" or peak > MEMORY_CEILING:
        return result("memory")
    if exc:
        return result("traceback")
    if "Traceback (most recent call last)" in stderr:
        return result("traceback")
    lines = [line for line in stderr.splitlines() if line.strip()]
    if rc == 0:
        if any(w in (stdout + stderr).lower() for w in FLAG_WORDS):
            return result("flagged")
        if any("error" in line.lower() for line in lines):
            return result("exit")
        return result("ok")
    if rc == 2:
        if len(lines) != 1:
            return result("multiline")
        if names and not any(n in lines[0] for n in names):
            return result("unnamed")
        return result("clear")
    return result("multiline" if len(lines) > 1 else "exit")
