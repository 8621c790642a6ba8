"""Python programs run as ``subprocess.run`` would, in a fork of a warm interpreter.

A fresh interpreter spends most of a short program's CPU importing the package (the CLI,
asyncio, the emulator). ``run(argv, ...)`` takes the same arguments as ``subprocess.run``
for ``[sys.executable, "-c", code, ...]``, ``[sys.executable, "-m", module, ...]`` and
``[sys.executable, script, ...]`` and gives the same ``CompletedProcess``: a server
process of this test process's interpreter and environment imports those modules once,
then forks a child per program, which runs it as ``__main__`` with its own stdin, stdout,
stderr, working directory, ``sys.argv`` and exit code, and ends as the interpreter would
(non-daemon threads joined, ``atexit`` run, streams flushed). The program is still a
process of its own, and nothing it does reaches the test process or the next program.

Anything else runs in a real subprocess: other interpreter options, an ``env`` other than
this process's environment at the server's start (``monkeypatch.setenv``; but for the
variables of ``_PER_CALL``), a platform
without ``os.fork``, or a server that failed to start. Tests about the process itself
(signals, Ctrl+C, start-up imports, the console script) keep ``subprocess``.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import tempfile
import threading
from collections.abc import Mapping, Sequence
from typing import Any

#: What the server imports before it forks (each one only if it imports).
PRELOAD = ("asyncio", "tango_aio", "tango_aio.cli", "tango_aio.sim", "tango_aio.sync",
           "tango_aio.testing", "bluesky", "ophyd_async.core", "tango_aio.bluesky")

#: Variables read only when used, not by an import: the child takes the caller's (``env``
#: or this process's), and the server serves any value of them.
_PER_CALL = ("PYTEST_CURRENT_TEST", "PYTEST_ADDOPTS", "TANGO_AIO_HISTORY")

_SERVER = r"""
import atexit, gc, json, os, runpy, sys, threading, traceback, types
control_in = os.fdopen(os.dup(0), "rb", 0)
control_out = os.fdopen(os.dup(1), "wb", 0)
null = os.open(os.devnull, os.O_RDWR)
os.dup2(null, 0)
os.dup2(null, 1)
for name in sys.argv[1:]:
    try:
        __import__(name)
    except Exception:
        pass
gc.collect()

def _exit_code(stop):
    if stop.code is None:
        return 0
    if isinstance(stop.code, int):
        return stop.code & 0xFF
    print(stop.code, file=sys.stderr)
    return 1

def _child(request):
    control_in.close()
    control_out.close()
    os.chdir(request["cwd"])
    for name, value in request["environment"].items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    for fd, path, flags in ((0, request["stdin"], os.O_RDONLY), (1, request["stdout"], os.O_WRONLY),
                            (2, request["stderr"], os.O_WRONLY)):
        opened = os.open(path, flags)
        os.dup2(opened, fd)
        os.close(opened)
    main = types.ModuleType("__main__")
    main.__dict__["__builtins__"] = __builtins__
    sys.modules["__main__"] = main
    mode, target, args = request["mode"], request["target"], request["args"]
    code = 0
    try:
        if mode == "-c":
            sys.argv = ["-c", *args]
            sys.path[0] = ""
            exec(compile(target, "<string>", "exec"), main.__dict__)
        elif mode == "-m":
            sys.argv = ["-m", *args]
            sys.path[0] = os.getcwd()
            runpy._run_module_as_main(target, alter_argv=True)
        else:
            sys.argv = [target, *args]
            sys.path[0] = os.path.dirname(os.path.abspath(target))
            runpy.run_path(target, run_name="__main__")
    except SystemExit as stop:
        code = _exit_code(stop)
    except BaseException as error:
        traceback.print_exception(type(error), error, error.__traceback__.tb_next)
        code = 1
    try:
        threading._shutdown()
        atexit._run_exitfuncs()
        gc.collect()
    except SystemExit as stop:
        code = _exit_code(stop)
    except BaseException:
        traceback.print_exc()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    os._exit(code)

control_out.write(b"ready\n")
for line in control_in:
    request = json.loads(line)
    pid = os.fork()
    if pid == 0:
        try:
            _child(request)
        finally:
            os._exit(70)
    control_out.write(b"%d\n" % pid)
    _, status = os.waitpid(pid, 0)
    control_out.write(b"%d\n" % os.waitstatus_to_exitcode(status))
"""


class _Server:
    def __init__(self) -> None:
        self.environment = _stable_environment(os.environ)
        self.process = subprocess.Popen(
            [sys.executable, "-c", _SERVER, *PRELOAD], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, bufsize=0)
        if self._line(120) != "ready":
            raise OSError("the fork server did not start")

    def _line(self, timeout: float) -> str | None:
        assert self.process.stdout is not None
        ready, _, _ = select.select([self.process.stdout], [], [], timeout)
        if not ready:
            return None
        return self.process.stdout.readline().decode().strip()

    def run(self, request: dict[str, Any], timeout: float | None) -> int:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps(request).encode() + b"\n")
        self.process.stdin.flush()
        pid = self._line(30)
        if pid is None or not pid.isdigit():
            raise OSError("the fork server did not answer")
        status = self._line(timeout if timeout is not None else 24 * 3600.0)
        if status is None:
            os.kill(int(pid), 9)
            self._line(30)
            raise subprocess.TimeoutExpired(request["argv"], timeout or 0.0)
        if not status.lstrip("-").isdigit():
            raise OSError("the fork server died")
        return int(status)

    def close(self) -> None:
        if self.process.stdin is not None:
            self.process.stdin.close()
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        if self.process.stdout is not None:
            self.process.stdout.close()


_lock = threading.Lock()
_server: _Server | None = None
_broken = False


def _warm_server(environment: Mapping[str, str]) -> _Server | None:
    global _server, _broken
    if _server is None and not _broken:
        try:
            _server = _Server()
        except OSError:
            _broken = True
            return None
        import atexit
        atexit.register(_server.close)
    if _server is not None and _server.environment != _stable_environment(environment):
        return None
    return _server


def _stable_environment(environment: Mapping[str, str]) -> dict[str, str]:
    return {name: value for name, value in environment.items() if name not in _PER_CALL}


def _parse(argv: Sequence[str]) -> tuple[str, str, list[str]] | None:
    if len(argv) < 2 or argv[0] != sys.executable:
        return None
    if argv[1] in ("-c", "-m"):
        if len(argv) < 3:
            return None
        return argv[1], argv[2], list(argv[3:])
    if argv[1].startswith("-"):
        return None
    return "script", argv[1], list(argv[2:])


def _decoded(data: bytes) -> str:
    import locale
    text = data.decode(locale.getpreferredencoding(False))
    return text.replace("\r\n", "\n").replace("\r", "\n")


def run(argv: Sequence[str], *, input: str | bytes | None = None, text: bool = False,
        timeout: float | None = None, cwd: str | os.PathLike[str] | None = None,
        env: Mapping[str, str] | None = None, capture_output: bool = True,
        check: bool = False) -> subprocess.CompletedProcess[Any]:
    """``subprocess.run(argv, capture_output=True, ...)`` of a Python program, forked from a
    warm interpreter where it can be (the module's docstring says when)."""
    assert capture_output and not check, "only captured, unchecked runs"
    parsed = _parse(argv) if hasattr(os, "fork") else None
    environment = os.environ if env is None else env
    if parsed is not None:
        with _lock:
            server = _warm_server(environment)
            if server is not None:
                return _forked(server, list(argv), parsed, input, text, timeout, cwd,
                               {name: environment.get(name) for name in _PER_CALL})
    return subprocess.run(list(argv), input=input, text=text, timeout=timeout, cwd=cwd,
                          env=env, capture_output=True, check=False)


def _forked(server: _Server, argv: list[str], parsed: tuple[str, str, list[str]],
            input: str | bytes | None, text: bool, timeout: float | None,
            cwd: str | os.PathLike[str] | None,
            environment: dict[str, str | None]) -> subprocess.CompletedProcess[Any]:
    with tempfile.TemporaryDirectory(prefix="forkrun-") as folder:
        paths = {name: os.path.join(folder, name) for name in ("stdin", "stdout", "stderr")}
        data = input.encode() if isinstance(input, str) else (input or b"")
        for name, content in (("stdin", data), ("stdout", b""), ("stderr", b"")):
            with open(paths[name], "wb") as file:
                file.write(content)
        mode, target, args = parsed
        request = {"argv": argv, "mode": mode, "target": target, "args": args,
                   "cwd": os.fspath(cwd) if cwd is not None else os.getcwd(),
                   "environment": environment, **paths}
        returncode = server.run(request, timeout)
        with open(paths["stdout"], "rb") as out, open(paths["stderr"], "rb") as err:
            stdout, stderr = out.read(), err.read()
    if text:
        return subprocess.CompletedProcess(argv, returncode, _decoded(stdout), _decoded(stderr))
    return subprocess.CompletedProcess(argv, returncode, stdout, stderr)
