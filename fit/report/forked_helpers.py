"""Figure helpers forked from an idle copy of the command, made before it starts a thread.

A helper of :class:`fit.report.figure_queue.FigureQueue` started as a fresh interpreter
spends about a second of a core importing what the command has long imported. A fork of
the command has it all at once, but the command cannot fork once it is at work: a child of
a process whose thread pools or BLAS run can inherit a lock that nobody will release. So,
once the command's imports are done and before anything starts a thread,
:func:`start_fork_server` forks a *server*: an idle copy of the process that forks a helper
whenever the process asks for one (:func:`forked_helper`). The server starts no thread, so
its forks are safe; the only other threads at its own fork are OpenBLAS's, which OpenBLAS
stops before a fork and starts again when next used.

A helper is the server's child, not the caller's: the caller names it by a pidfd (to see
it end and to kill it) and asks the server for its exit code. Linux only (pidfds, file
descriptors passed over a socket); elsewhere, and in any process but the one that started
the server (a forked worker, say), helpers are fresh interpreters.
"""

from __future__ import annotations

import os
import pickle
import select
import signal
import socket
import subprocess
import sys
import threading
import warnings

__all__ = ["start_fork_server", "forked_helper", "fork_server_pid", "ForkedProcess"]

#: Requests to the server: fork a helper; the exit code of a helper that ended.
_FORK, _EXIT_CODE = b"f", b"w"
#: Bytes of a pid or an exit code on the server's socket.
_WORD = 8
#: The server's answer for an exit code it cannot tell (not a helper of its own).
_UNKNOWN = -(1 << 63)


class _Server:
    """The caller's end of the server: its pid, socket, and the process that started it."""

    def __init__(self, pid: int, channel: socket.socket):
        self.pid, self.channel, self.owner = pid, channel, os.getpid()
        self.lock = threading.Lock()            # one request and its answer at a time

    def ask(self, request: bytes, fds: int = 0) -> tuple[int, list]:
        """Send `request`; return the server's answer (a word) and the `fds` it passed.

        Raises ChildProcessError when it could not fork a helper, another OSError when
        it is gone."""
        with self.lock:
            self.channel.sendall(request)
            word, passed, _, _ = socket.recv_fds(self.channel, _WORD, fds)
        answer = int.from_bytes(word, "little", signed=True) if len(word) == _WORD else None
        if len(passed) != fds:
            for fd in passed:
                os.close(fd)
            if answer == _UNKNOWN:
                raise ChildProcessError("the figure helpers' fork server could not fork")
            raise ConnectionError("the figure helpers' fork server ended")
        return answer, passed


def _received(channel: socket.socket, size: int) -> bytes:
    """The next `size` bytes of `channel`; fewer when it closes first."""
    data = b""
    while len(data) < size and (part := channel.recv(size - len(data))):
        data += part
    return data


_server: _Server | None = None


def fork_server_pid() -> int | None:
    """Pid of this process's fork server, None when it has none."""
    return _server.pid if _server is not None and _server.owner == os.getpid() else None


def start_fork_server() -> bool:
    """Fork the server of this process's figure helpers, unless it has one; True when it
    has one after the call.

    Call it once the imports the figures need are done and before any thread starts (a
    command's start): with another Python thread running, or off Linux, it starts nothing
    and returns False (helpers are then fresh interpreters).
    """
    global _server
    if fork_server_pid() is not None:
        return True
    if not (sys.platform.startswith("linux") and hasattr(os, "pidfd_open")
            and hasattr(socket, "send_fds")) or threading.active_count() > 1:
        return False
    for stream in (sys.stdout, sys.stderr):         # nothing buffered is written twice
        if stream is not None:
            stream.flush()
    try:
        caller_end, server_end = socket.socketpair()
    except OSError:                                 # out of file descriptors: fresh helpers
        return False
    try:
        with warnings.catch_warnings():
            # Python 3.12+ warns of any other OS thread: here only OpenBLAS's (see above)
            warnings.filterwarnings("ignore", category=DeprecationWarning,
                                    message=".*multi-threaded.*fork")
            pid = os.fork()
    except OSError:                                 # no process to spare: fresh helpers
        caller_end.close()
        server_end.close()
        return False
    if pid == 0:
        try:
            caller_end.close()
            _serve(server_end)
        finally:
            os._exit(1)
    server_end.close()
    _server = _Server(pid, caller_end)
    return True


def _serve(channel: socket.socket) -> None:
    """The server's loop: a helper forked for each request, until the caller's end closes."""
    # the caller stops the helpers: an interrupt of the terminal's group is the caller's
    # alone (the helpers keep ignoring it)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    nothing = os.open(os.devnull, os.O_RDONLY)      # the terminal's input is the caller's
    os.dup2(nothing, 0)
    os.close(nothing)
    while True:
        try:
            request = _received(channel, 1)
            if request == _EXIT_CODE:
                request += _received(channel, _WORD)
        except OSError:
            request = b""
        if request == _FORK:
            _fork_helper(channel)
        elif len(request) == 1 + _WORD:
            _send_exit_code(channel, int.from_bytes(request[1:], "little"))
        else:                                       # the caller's end closed
            os._exit(0)


def _fork_helper(channel: socket.socket) -> None:
    """Fork a helper; pass the caller its pid, its two pipes' other ends and its pidfd
    (:data:`_UNKNOWN` and no descriptor when the system refuses a process or a pipe)."""
    opened = []
    try:
        from_caller, to_helper = os.pipe()
        opened += [from_caller, to_helper]
        from_helper, to_caller = os.pipe()
        opened += [from_helper, to_caller]
        pid = os.fork()
        if pid == 0:
            channel.close()
            os.close(to_helper)
            os.close(from_helper)
            _run_helper(from_caller, to_caller)
        pidfd = os.pidfd_open(pid)
    except OSError:
        for fd in opened:
            os.close(fd)
        channel.sendall(_UNKNOWN.to_bytes(_WORD, "little", signed=True))
        return
    os.close(from_caller)
    os.close(to_caller)
    socket.send_fds(channel, [pid.to_bytes(_WORD, "little", signed=True)],
                    [to_helper, from_helper, pidfd])
    for fd in (to_helper, from_helper, pidfd):
        os.close(fd)


def _send_exit_code(channel: socket.socket, pid: int) -> None:
    """Reap helper `pid` (it has ended: the caller saw its pidfd) and send its exit code."""
    try:
        code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    except ChildProcessError:
        code = _UNKNOWN
    channel.sendall(code.to_bytes(_WORD, "little", signed=True))


def _run_helper(inbox: int, outbox: int) -> None:
    """A forked helper: one BLAS thread (the caller's process has the others), the
    caller's import path read first from the pipe `inbox`, then the helper's loop on
    `inbox` and `outbox`; never returns."""
    try:
        import threadpoolctl

        from fit.report._figure_helper import serve
        threadpoolctl.threadpool_limits(1)
        inbox = os.fdopen(inbox, "rb")
        sys.path[:] = pickle.load(inbox)        # the caller's, first (see figure_queue)
        serve(inbox, os.fdopen(outbox, "wb"))
    finally:
        os._exit(1)


def forked_helper() -> ForkedProcess | None:
    """A new helper forked by this process's server, its protocol's pipes open; None
    without a server (or when it has ended: helpers are then fresh interpreters)."""
    global _server
    server = _server
    if server is None or server.owner != os.getpid():
        return None
    try:
        pid, (to_helper, from_helper, pidfd) = server.ask(_FORK, fds=3)
    except ChildProcessError:                       # this time: a fresh interpreter
        return None
    except OSError:                                 # the server is gone: from now on
        _server = None
        return None
    return ForkedProcess(server, pid, pidfd, os.fdopen(to_helper, "wb"),
                         os.fdopen(from_helper, "rb"))


class ForkedProcess:
    """A helper forked by the server, as much of :class:`subprocess.Popen` as the
    figure queue uses: ``pid``, ``stdin`` and ``stdout`` (the protocol's pipes),
    :meth:`poll`, :meth:`wait` and :meth:`kill`; safe to wait for from several threads.
    Its pidfd is closed with it."""

    def __init__(self, server: _Server, pid: int, pidfd: int, stdin, stdout):
        self.pid, self.stdin, self.stdout = pid, stdin, stdout
        self.returncode = None
        self._server, self._pidfd = server, pidfd
        self._reaped = False
        self._reaping = threading.Lock()        # the server reaps a helper once

    def poll(self) -> int | None:
        """The exit code, None while the helper runs (or when the server cannot tell)."""
        return self._exit_code()

    def wait(self, timeout: float | None = None) -> int | None:
        """The exit code once the helper ends (None: the server could not tell it).

        Raises subprocess.TimeoutExpired when it has not ended within `timeout` s."""
        if not self._reaped and not select.select([self._pidfd], [], [], timeout)[0]:
            raise subprocess.TimeoutExpired(f"figure helper {self.pid}", timeout)
        return self._exit_code()

    def kill(self) -> None:
        if not self._reaped:
            try:
                signal.pidfd_send_signal(self._pidfd, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def _exit_code(self) -> int | None:
        """The exit code, asked of the server once the pidfd shows the helper ended."""
        if not self._reaped and select.select([self._pidfd], [], [], 0.0)[0]:
            with self._reaping:
                if not self._reaped:
                    try:
                        code = self._server.ask(_EXIT_CODE
                                                + self.pid.to_bytes(_WORD, "little"))[0]
                    except OSError:
                        code = _UNKNOWN
                    self.returncode = None if code == _UNKNOWN else code
                    self._reaped = True
        return self.returncode

    def __del__(self):
        pidfd, self._pidfd = getattr(self, "_pidfd", None), None
        if pidfd is not None:
            os.close(pidfd)


def _forget_server() -> None:
    """In a forked child: the caller's server is not its own (nor is its lock)."""
    global _server
    if _server is not None:
        _server.channel.close()
        _server = None


os.register_at_fork(after_in_child=_forget_server)
