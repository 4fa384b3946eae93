"""Ctrl-C and SIGTERM end a command within two seconds, however busy it is, with one line on stderr.

Python runs a signal handler only in the main thread, between bytecodes: while that thread is inside XLA (a long
compiled call) the handler waits for the call to end, and an exception the handler raises inside a garbage-collection
callback (JAX runs one at every collection, so often while it traces) is printed and dropped. So :func:`install`
sets up three things:

* the handler raises ``KeyboardInterrupt`` for SIGINT and :class:`Terminated` (a ``KeyboardInterrupt`` too) for
  SIGTERM, once, so that the command unwinds like it does for Ctrl-C: files are closed, the finished work is kept,
  and the command may say what it kept; a further signal changes nothing;
* where Python drops that exception (``sys.unraisablehook`` sees it), the signal is delivered again a moment later;
* a watchdog thread, woken through ``signal.set_wakeup_fd`` as soon as the signal arrives whatever the main thread is
  doing, ends the process if it still runs :data:`GRACE_S` later: it writes ``PROGRAM: interrupted`` (or
  ``terminated``) unless the command has, flushes the output and calls ``os._exit``.

How the process ends (:func:`exit_process`, which ``driveopt`` calls once its command has returned, whatever the
outcome). Python's own exit is not safe from signals: after the exit handlers its finalisation gives the signals
their default action back (a signal there kills the process, with no line and status -2 / -15 seen by the caller),
and the exit handlers run in the reverse order of registration, so JAX's (registered when JAX is imported, after
:func:`install`) runs before driveopt's and can crash (a segmentation fault that pygame's parachute turns into an
abort, status 134) after a signal stopped XLA mid-compilation. So the process is ended with ``os._exit`` and never
reaches that teardown:

* from the moment the command has returned (:func:`stop_raising`) a stopping signal no longer raises: the watchdog
  writes the line and ends the process at once with 128 + its number, whatever the main thread is doing;
* without a signal, :func:`exit_process` does what Python's exit would do before its teardown, in the same order
  (the threads' exit hooks and a join of the non-daemon threads, then every exit handler: JAX's, Ray's, logging's,
  temporary files), with the handlers above still in force, then flushes the output and calls ``os._exit(status)``;
* after a signal, it runs no exit handler but Ray's shutdown (when Ray is initialised: a cluster is told that this
  driver has gone; a local instance is already stopped by the runner), since the others are what can crash or hang
  once a compilation was cut short, then flushes and calls ``os._exit(128 + signum)``, within the watchdog's
  :data:`GRACE_S` of the signal.

Other entry points (benchmark scripts calling :func:`install`, a Python caller of ``driveopt.cli.main``) leave by
Python's exit: the exit handler :func:`install` registers is moved to the front when the first signal arrives, so it
runs before JAX's and ends the process the same way (Ray's shutdown, the line, ``os._exit(128 + signum)``).

The one window not covered is the interpreter's start and the import of :mod:`driveopt.cli` (about 0.2 s), before
``main`` calls :func:`install`: a signal there meets Python's default handling.

For tests, ``DRIVEOPT_EXIT_PAUSE_S=SECONDS`` makes :func:`exit_process`, once the command has returned and its output
is flushed, write ``PROGRAM: pausing before exit (DRIVEOPT_EXIT_PAUSE_S)`` on stderr and wait that long as the first
exit handler, so that a test can aim a signal at the end of a command; unset (the default) it does nothing.

A reader of stdout that goes away (``driveopt plan | head -1``) ends a command quietly with status 141, the status
a shell reports for a process that SIGPIPE stopped (:func:`stdout_closed`).
"""

from __future__ import annotations

import _thread
import atexit
import os
import select
import signal
import sys
import threading
import time
from pathlib import Path
from typing import NoReturn

GRACE_S = 1.2  # [s] from the signal to the forced exit, when the process has not ended by then (2 s in all, loaded)
REDELIVER_S = 0.01  # [s] from a dropped exception to the signal's next delivery: the dropping callback has returned
FLUSH_S = 0.2  # [s] the most the forced exit waits for buffered output: a stalled reader must not hold it
STOPPING_SIGNALS = (signal.SIGINT, signal.SIGTERM)
BROKEN_PIPE_STATUS = 128 + signal.SIGPIPE
WAKE = b"\0"  # what wakes the watchdog to look at the state (signals write their own number)
WORDS = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}
NEVER = float("inf")
EXIT_PAUSE_ENV = "DRIVEOPT_EXIT_PAUSE_S"


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that a terminated command unwinds and keeps its work the same way."""


class _State:
    """What this process knows of the stopping signal; shared by the main thread and the watchdog."""

    def __init__(self) -> None:
        self.lock = threading.RLock()  # reentrant: the handler may run in the main thread while it holds the lock
        self.program = "driveopt"
        self.signum: int | None = None  # the first stopping signal
        self.deadline = NEVER  # time.monotonic() at which the watchdog ends the process
        self.redeliver_at = NEVER  # time.monotonic() at which the watchdog delivers the signal again
        self.raised = False  # the handler's exception is on its way (not dropped)
        self.announced = False  # the one line has been written
        self.ending = False  # the command has returned: a signal now ends the process at once (stop_raising)
        self.exit_handler_first = False  # _exit_with_signal_status has been moved to the front of the exit handlers
        self.end_lock = threading.Lock()  # taken by whoever ends the process, never released: one line, one exit
        self.wake_fd: int | None = None  # the write end of the watchdog's pipe (also the wakeup descriptor)
        self.unraisable_hook = sys.unraisablehook  # the hook :func:`install` replaced


_state = _State()


def install(program: str) -> None:
    """Make SIGINT and SIGTERM stop this process cleanly and promptly, reporting as ``program``.

    Only in the main thread (Python sets handlers nowhere else; elsewhere nothing happens). Calling it again only
    changes the name.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    _state.program = program
    if _state.wake_fd is None:
        _state.wake_fd = _start_watchdog()
        _state.unraisable_hook = sys.unraisablehook
        sys.unraisablehook = _redeliver_dropped_interrupt
        atexit.register(_exit_with_signal_status)
        if hasattr(os, "register_at_fork"):
            os.register_at_fork(after_in_child=_uninstall_in_forked_child)
    # Last, so that the first signal raises only once everything above is in place (the caller's ``try`` catches it).
    # Also where the shell that started us ignored SIGINT (a background job of a script): Ctrl-C stops it too.
    for signum in STOPPING_SIGNALS:
        signal.signal(signum, _raise_in_main_thread)


def _uninstall_in_forked_child() -> None:
    """A forked child has no watchdog, and would write its signals into the parent's pipe: it gets Python's default
    handling back (until it calls :func:`install` itself)."""
    global _state
    if _state.wake_fd is None:
        return
    signal.set_wakeup_fd(-1)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    sys.unraisablehook = _state.unraisable_hook
    _state = _State()


def stop_raising() -> None:
    """The command has returned: from now on a stopping signal raises nothing, and the watchdog ends the process at
    once (the line, status 128 + its number). A signal already received keeps its course (its deadline)."""
    with _state.lock:  # against the watchdog's _note: the deadline follows from the state it finds
        _state.ending = True


def exit_process(status: int) -> NoReturn:
    """End this process with ``status`` (or 128 + the stopping signal received), never through Python's teardown.

    Without a signal: the threads' exit hooks, the join of non-daemon threads and every exit handler, as Python's
    exit runs them, then the output flushed and ``os._exit``. After a signal: Ray's shutdown only (when Ray is
    initialised), the line unless written, the output flushed and ``os._exit``. Signals are handled throughout: one
    arriving now ends the process at once with its status (see the module docstring). Call it from the main thread
    once the command has returned, after :func:`stop_raising` (which it calls too).
    """
    stop_raising()
    if stop_status() is None:
        pause = os.environ.get(EXIT_PAUSE_ENV)
        if pause:
            atexit.register(_pause_before_exit, float(pause))  # the last registered runs first
        _flush_streams()
        threading._shutdown()  # what Python's exit does first: threading's exit hooks, the non-daemon threads joined
        atexit._run_exitfuncs()  # then the exit handlers (it empties their list)
    if stop_status() is not None:
        _shutdown_ray()
    _end_process(status)


def stop_status() -> int | None:
    """128 + the stopping signal received, or None when none has arrived."""
    return None if _state.signum is None else 128 + _state.signum


def announce(detail: str = "") -> None:
    """Write the line for the signal received (``PROGRAM: interrupted[: detail]``), once; nothing without a signal.

    The watchdog writes the plain line itself when the command has not announced in time.
    """
    line = _claim_line(detail)
    if line is not None:
        print(line, file=sys.stderr, flush=True)


def stdout_closed(exc: BaseException) -> bool:
    """Whether ``exc`` is a write to a standard output whose reader has gone; if so stdout now goes to /dev/null, so
    that flushing it at exit raises nothing more."""
    if not isinstance(exc, BrokenPipeError) or not _reader_gone(sys.stdout):
        return False
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return True


def default_program() -> str:
    """The running script's name without its suffix (``faithful_ablation``)."""
    return Path(sys.argv[0]).stem if sys.argv and sys.argv[0] else "python"


def _reader_gone(stream) -> bool:
    """Whether ``stream`` is a pipe with no reader left (poll reports an error on its descriptor)."""
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):  # replaced by an object without a descriptor
        return False
    poller = select.poll()
    poller.register(fd, select.POLLOUT)
    return any(events & select.POLLERR for _, events in poller.poll(0))


def _claim_line(detail: str) -> str | None:
    """The line for the signal received, to the first caller only; None without a signal or after the first."""
    with _state.lock:
        if _state.signum is None or _state.announced:
            return None
        _state.announced = True
        word = WORDS.get(_state.signum, f"stopped by signal {_state.signum}")
        return f"{_state.program}: {word}: {detail}" if detail else f"{_state.program}: {word}"


def _note(signum: int) -> None:
    """Keep ``signum`` when it is the first stopping signal, and start the count to the forced exit: GRACE_S, or none
    once the command has returned (nothing is left to unwind)."""
    with _state.lock:
        if _state.signum is None:
            _state.signum = signum
            _state.deadline = time.monotonic() + (0.0 if _state.ending else GRACE_S)


def _importing(frame) -> bool:
    """Whether ``frame`` or a frame that called it runs Python's import machinery."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _raise_in_main_thread(signum: int, frame) -> None:
    _note(signum)
    _wake_watchdog()  # it has heard already, unless another library took the wakeup descriptor
    if _state.raised or _state.announced or _state.ending:
        return  # the first is unwinding, or the command has ended; the watchdog bounds how long either takes
    if _importing(frame):
        # An exception raised into a module's import can land inside a compiled extension's initialisation, which
        # does not survive it (a segmentation fault while jax imported its extensions, in 6 of 16 signals sent just
        # after the handlers were installed); no work is in flight while a module imports, so the process ends here.
        _end_process(1)
    _state.raised = True
    if not _state.exit_handler_first:  # here, in the main thread, never while the exit handlers run (ending)
        _state.exit_handler_first = True
        atexit.unregister(_exit_with_signal_status)
        atexit.register(_exit_with_signal_status)  # the last registered runs first: before JAX's clean-up
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _redeliver_dropped_interrupt(unraisable) -> None:
    """``sys.unraisablehook``: the signal's exception raised where Python can only drop it (a garbage-collection
    callback, a finaliser) is delivered again once that code has returned; anything else goes to the previous hook."""
    if not (issubclass(unraisable.exc_type, KeyboardInterrupt) and _state.signum is not None):
        _state.unraisable_hook(unraisable)
        return
    with _state.lock:
        _state.raised = False
        _state.redeliver_at = time.monotonic() + REDELIVER_S
    _wake_watchdog()


def _start_watchdog() -> int:
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)  # the C-level signal handler must never block
    signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    threading.Thread(target=_watch, args=(read_fd,), name="driveopt-signal-watchdog", daemon=True).start()
    return write_fd


def _wake_watchdog() -> None:
    try:
        os.write(_state.wake_fd, WAKE)
    except (OSError, TypeError):  # the pipe is full (the watchdog is awake), or not installed
        pass


def _watch(read_fd: int) -> None:
    """The watchdog: sleep until a signal or a request, deliver dropped signals again, end the process at the deadline."""
    while True:
        wake_at = min(_state.deadline, _state.redeliver_at)
        timeout = None if wake_at == NEVER else max(wake_at - time.monotonic(), 0.0)
        if select.select([read_fd], [], [], timeout)[0]:
            for number in os.read(read_fd, 4096):  # signal numbers (the wakeup descriptor's) and wake bytes
                if number in STOPPING_SIGNALS:
                    _note(number)
        now = time.monotonic()
        if now >= _state.deadline:
            _force_exit()
        if now >= _state.redeliver_at:
            _state.redeliver_at = NEVER
            if not _state.announced:
                _thread.interrupt_main(_state.signum)


def _force_exit() -> None:
    """From the watchdog: the line (unless written) and buffered output, then exit with the signal's status."""
    _end_process(1)


def _end_process(status: int) -> NoReturn:
    """The line for the signal (unless written), the buffered output, then ``os._exit`` with the signal's status, or
    ``status`` without a signal. The first caller (main thread or watchdog) ends the process; a second waits for it."""
    _state.end_lock.acquire()
    line = _claim_line("")
    if line is not None and os.isatty(2):
        line = "\n" + line  # a progress bar may have left the cursor at the end of its line
    _finish_output(line)
    os._exit(stop_status() or status)


def _exit_with_signal_status() -> None:
    """Exit handler, for entry points that leave by Python's exit: after a stopping signal, Ray's shutdown (when Ray
    is initialised), the line unless written, the output flushed and ``os._exit`` with the signal's status, before
    the other exit handlers and the interpreter's teardown can run."""
    if stop_status() is not None:
        _shutdown_ray()
        _end_process(1)


def _shutdown_ray() -> None:
    """Disconnect from Ray (stopping a local instance) when this process initialised it; the watchdog bounds it."""
    ray = sys.modules.get("ray")
    try:
        if ray is not None and ray.is_initialized():
            ray.shutdown()
    except Exception:  # noqa: BLE001 - a half-imported or failing Ray: the process ends all the same
        pass


def _pause_before_exit(seconds: float) -> None:
    """The test hook of :data:`EXIT_PAUSE_ENV` (see the module docstring)."""
    print(f"{_state.program}: pausing before exit ({EXIT_PAUSE_ENV})", file=sys.stderr, flush=True)
    time.sleep(seconds)


def _finish_output(line: str | None) -> None:
    """Flush stdout and stderr, then write ``line`` (if any) to descriptor 2, waiting at most FLUSH_S: a reader
    that stopped reading must not keep the process alive."""
    writer = threading.Thread(target=_flush_and_write, args=(line,), name="driveopt-flush", daemon=True)
    writer.start()
    writer.join(FLUSH_S)


def _flush_and_write(line: str | None) -> None:
    _flush_streams()
    if line is not None:
        try:
            os.write(2, (line + "\n").encode())
        except OSError:  # no stderr: the status still says it
            pass


def _flush_streams() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):  # closed, a broken pipe, or no stream at all
            pass
