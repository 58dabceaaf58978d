"""Signals, atomic output files and the final ``result.json``: how a run ends, whatever happens.

One place turns SIGINT/SIGTERM, bad input and ``OSError`` into a final status:

========================  =================  =========
what ended the run        ``status``         exit code
========================  =================  =========
SIGINT (Ctrl-C)           ``interrupted``    130
SIGTERM (``timeout``,     ``interrupted``    143
SLURM pre-emption)
bad input                 ``input_error``    2
an output not written     ``output_error``   6
========================  =================  =========

HiGHS runs in C++, where a Python signal handler cannot run: Python runs it only when
the main thread executes Python code again, which during a HiGHS solve can take many
seconds. :func:`signals_handled` therefore also gives Python a wake-up pipe
(``signal.set_wakeup_fd``): the interpreter's C-level handler writes the signal number
into it at once. HiGHS's interrupt callbacks (see :mod:`spidermatch.solve.highs`), which
may run on HiGHS's own threads, poll it through :func:`stop_requested` and stop the
solve; after the solve :func:`raise_if_stopped` turns the request into
:class:`RunInterrupted`. Outside a solve the Python handler raises it at once.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import tempfile
import threading
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: run folders are not locked
    fcntl = None

logger = logging.getLogger(__name__)

EXIT_BAD_INPUT = 2
EXIT_OUTPUT_ERROR = 6
SIGNAL_EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
_NATIVE_LOCK = threading.Lock()  # native_call's counter, entered by the threads that watch solver processes


def _fresh_native_lock() -> None:
    """In a forked child: a lock of its own (another thread of the parent may have held it at the fork)."""
    global _NATIVE_LOCK
    _NATIVE_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_fresh_native_lock)


class RunInterrupted(BaseException):
    """SIGINT or SIGTERM ended the run (a BaseException, like KeyboardInterrupt).

    Attributes
    ----------
    signum : int
    known : dict
        What was known when the run stopped (e.g. incumbent objective and a certified bound).

    """

    def __init__(self, signum: int, known: dict | None = None) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum = signum
        self.known = dict(known or {})

    @property
    def exit_code(self) -> int:
        """130 for SIGINT, 143 for SIGTERM (128 + signal number)."""
        return 128 + int(self.signum)


class OutputError(OSError):
    """An output file could not be written; the message names the path."""


class FolderInUse(RuntimeError):
    """Another live process is writing into the run folder; the message names it."""


LOCK_NAME = ".spidermatch.lock"


@contextlib.contextmanager
def folder_lock(folder: Path):
    """Hold ``folder`` (created if missing) for this process: a second run into it is refused.

    The lock is an ``flock`` on ``folder/.spidermatch.lock``, released by the kernel when the
    process ends however it ends, so no stale lock survives a killed run.

    Raises
    ------
    FolderInUse
        Another process holds the folder.
    OutputError
        The folder or its lock file cannot be created.

    """
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle = open(folder / LOCK_NAME, "a+")  # noqa: SIM115 (held for the whole block)
    except OSError as error:
        raise OutputError(
            f"{folder}: the run folder cannot be created ({error.strerror or error})"
        ) from error
    _STATE.lock_handle = handle
    try:
        if fcntl is not None:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.seek(0)
                holder = handle.read().strip() or "another process"
                raise FolderInUse(
                    f"{folder}: another spidermatch run ({holder}) is writing into this folder; wait for it "
                    "to end or give another hydra.run.dir"
                ) from None
            handle.seek(0)
            handle.truncate()
            handle.write(f"process {os.getpid()}\n")
            handle.flush()
        yield
    finally:
        _STATE.lock_handle = None
        handle.close()


def release_folder_lock() -> None:
    """Close this process's copy of the run folder's lock descriptor (in a forked child)."""
    if _STATE.lock_handle is not None:
        _STATE.lock_handle.close()
        _STATE.lock_handle = None


class _State:
    signum: int | None = None  # the first signal received
    raised: bool = False  # RunInterrupted has been raised for it
    native: int = 0  # > 0 while control is in C++ (HiGHS), where raising is not possible
    installed: int = 0  # nesting depth of signals_handled()
    wakeup: int | None = None  # read end of the pipe that Python's C-level handler writes to
    abandoned: bool = False  # a HiGHS solve was left running on its thread after a signal
    held: int = 0  # > 0 while final files are written (signals_held)
    graceful: str | None = None  # inside graceful_stops: what the first signal asks for (logged)
    lock_handle = None  # the open lock file of folder_lock, closed in forked children


_STATE = _State()


def stop_requested() -> bool:
    """True once SIGINT or SIGTERM was received in a :func:`signals_handled` block.

    Safe to call from any thread, also while the main thread is inside C++: the signal's
    number reaches the wake-up pipe at once, before the Python-level handler can run.
    """
    if _STATE.signum is None and _STATE.wakeup is not None:
        try:
            received = os.read(_STATE.wakeup, 64)
        except (BlockingIOError, OSError):
            received = b""
        stops = [sig for sig in received if sig in SIGNAL_EXIT_CODES]
        if stops:
            _STATE.signum = stops[0]
    return _STATE.signum is not None


def received_signal() -> int | None:
    """The number of the first SIGINT/SIGTERM received, or None (call :func:`stop_requested` first)."""
    return _STATE.signum


def raise_if_stopped(known: dict | None = None) -> None:
    """Raise :class:`RunInterrupted` (once) if a signal asked the run to stop."""
    if _STATE.signum is not None and not _STATE.raised and not _STATE.held:
        _STATE.raised = True
        raise RunInterrupted(_STATE.signum, known)


def abandon_native_work() -> None:
    """Record that a C++ solve was left running after a signal (see :func:`native_work_abandoned`)."""
    _STATE.abandoned = True


def native_work_abandoned() -> bool:
    """True if a solve was left running: the process should end with ``os._exit`` once its files are written.

    A normal interpreter exit could wait for the abandoned solver thread.
    """
    return _STATE.abandoned


@contextlib.contextmanager
def signals_held():
    """Inside the block a signal is only recorded, not raised (a run's final files are written there).

    A signal that came meanwhile is raised by the next :func:`raise_if_stopped`.
    """
    _STATE.held += 1
    try:
        yield
    finally:
        _STATE.held -= 1


@contextlib.contextmanager
def native_call():
    """Mark a call into C++ (HiGHS): the signal handler only records the signal meanwhile.

    Safe to enter from several threads at once (two solver processes watched side by side).
    """
    with _NATIVE_LOCK:
        _STATE.native += 1
    try:
        yield
    finally:
        with _NATIVE_LOCK:
            _STATE.native -= 1


def _handler(signum, frame) -> None:
    if _STATE.graceful is not None and _STATE.signum is not None:
        raise KeyboardInterrupt  # a second signal in graceful_stops: at once
    if _STATE.signum is None:
        _STATE.signum = signum
        logger.warning("%s received: %s", signal.Signals(signum).name, _STATE.graceful or "stopping")
    if _STATE.native == 0 and _STATE.graceful is None:
        raise_if_stopped()


@contextlib.contextmanager
def signals_handled():
    """Turn SIGINT/SIGTERM into :class:`RunInterrupted` inside the block (main thread only).

    Nested blocks share the outer one's handler; the outermost restores the previous
    handlers and forgets the signal.
    """
    if _STATE.installed or threading.current_thread() is not threading.main_thread():
        _STATE.installed += 1
        try:
            yield
        finally:
            _STATE.installed -= 1
        return
    previous = {sig: signal.signal(sig, _handler) for sig in SIGNAL_EXIT_CODES}
    read_end, write_end = os.pipe()
    os.set_blocking(read_end, False)
    os.set_blocking(write_end, False)
    previous_wakeup = signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    _STATE.installed, _STATE.signum, _STATE.raised, _STATE.wakeup = 1, None, False, read_end
    try:
        yield
    finally:
        signal.set_wakeup_fd(previous_wakeup)
        _STATE.installed, _STATE.signum, _STATE.raised, _STATE.wakeup = 0, None, False, None
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        os.close(read_end)
        os.close(write_end)


@contextlib.contextmanager
def graceful_stops(what_happens: str):
    """Inside the block the first SIGINT/SIGTERM only asks to stop; a second one stops at once.

    For loops that can end cleanly between steps (training): they poll :func:`stop_requested`
    and read :func:`received_signal` before the block ends (it forgets the signal). The second
    signal raises ``KeyboardInterrupt``, for a user who will not wait for the step to end.

    Parameters
    ----------
    what_happens : str
        Logged with the first signal's name, e.g. "stopping after this step".

    """
    with signals_handled():
        previous, _STATE.graceful = _STATE.graceful, what_happens
        try:
            yield
        finally:
            _STATE.graceful = previous


def fresh_in_child() -> None:
    """In a forked child: no share in the run folder's lock, and a wake-up pipe of its own.

    Inside :func:`signals_handled` the child also gets signal state of its own.

    A child that kept its copy of the lock's descriptor would hold the folder after its
    parent died (a killed run could not be resumed while the orphaned solve went on).

    The child inherits the parent's pipe; reading it would take signals meant for the parent
    (and the parent's for the child). The handlers stay installed, so a signal stops the
    child's solve as it would the parent's.
    """
    release_folder_lock()
    if not _STATE.installed:
        return
    read_end, write_end = os.pipe()
    os.set_blocking(read_end, False)
    os.set_blocking(write_end, False)
    signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    _STATE.signum, _STATE.raised, _STATE.wakeup = None, False, read_end
    _STATE.native, _STATE.abandoned = 0, False


def _file_mode() -> int:
    """The mode a new file gets from the process umask (0644 with the usual umask 022)."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path`` (same suffix); on success it replaces ``path``.

    The file gets the normal umask-derived mode. An ``OSError`` (disk full, unwritable
    folder) becomes :class:`OutputError` naming ``path``; no half-written file is left.
    """
    path = Path(path)
    try:
        handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
        os.close(handle)
    except OSError as error:
        raise OutputError(f"{path}: cannot be written ({error.strerror or error})") from error
    try:
        yield Path(name)
        os.chmod(name, _file_mode())
        os.replace(name, path)
    except OSError as error:
        raise OutputError(f"{path}: cannot be written ({error.strerror or error})") from error
    finally:
        with contextlib.suppress(OSError):
            os.unlink(name)


def write_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file, so that no half file is ever left."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def final_status(error: BaseException, input_errors: tuple) -> tuple[str, int, str, dict]:
    """Status, exit code, message and known figures for the exception that ended a run.

    Parameters
    ----------
    error : BaseException
        :class:`RunInterrupted`, one of ``input_errors`` or an ``OSError``.
    input_errors : tuple of exception types
        Exceptions that mean bad input (exit 2).

    Raises
    ------
    BaseException
        ``error`` itself when it is none of these (a bug: let it show).

    """
    if isinstance(error, RunInterrupted):
        name = signal.Signals(error.signum).name
        return "interrupted", error.exit_code, f"interrupted by {name}", error.known
    if isinstance(error, OutputError):
        return "output_error", EXIT_OUTPUT_ERROR, str(error), {}
    if isinstance(error, input_errors):
        return "input_error", EXIT_BAD_INPUT, str(error), {}
    if isinstance(error, OSError):
        where = f"{error.filename}: " if error.filename else ""
        return "output_error", EXIT_OUTPUT_ERROR, f"{where}{error.strerror or error}", {}
    raise error


def write_result(path: Path, report: dict) -> bool:
    """Write ``report`` as ``path`` (atomically); log and return False if that is impossible."""
    try:
        write_atomic(path, json.dumps(report, indent=2) + "\n")
    except OutputError as error:
        logger.error("%s; no result file was written", error)
        return False
    return True


def quiet_file_logs() -> None:
    """Let the root logger's file handlers drop a record they cannot write (a full disk) quietly.

    Python's default prints '--- Logging error ---' and a traceback to the console for every
    such record; the run's own error already says what failed. Console handlers keep the default.
    """
    for handler in _file_handlers():
        handler.handleError = _drop_record


def log_to_files(logger: logging.Logger, level: int, message: str) -> None:
    """``message`` to the root logger's file handlers only (the console has it already)."""
    record = logger.makeRecord(logger.name, level, "(unknown file)", 0, message, (), None)
    for handler in _file_handlers():
        handler.handle(record)


def detach_file_logs(folder: Path, remove_empty: bool) -> None:
    """Close the root logger's file handlers that write into ``folder`` (Hydra's run log there).

    For a run refused before it held its folder: the log file there belongs to the run that
    holds it (or to the user), so the refusal goes to the console only. ``remove_empty``: an
    empty log file is removed too (not in a folder a live run holds: its log may be empty yet).
    """
    for handler in _file_handlers():
        path = Path(handler.baseFilename)
        if path.parent != Path(folder).absolute():
            continue
        logging.getLogger().removeHandler(handler)
        handler.close()
        with contextlib.suppress(OSError):
            if remove_empty and path.stat().st_size == 0:
                path.unlink()


def _file_handlers() -> list[logging.FileHandler]:
    """The root logger's handlers that write a file (Hydra's run log)."""
    return [handler for handler in logging.getLogger().handlers if isinstance(handler, logging.FileHandler)]


def _drop_record(record: logging.LogRecord) -> None:
    """A log record a file handler could not write: dropped (see :func:`quiet_file_logs`)."""
