"""Stopping cleanly: signals, output locks and temporary files.

Signals
    Inside :func:`stop_on_signals`, SIGINT, SIGTERM and SIGHUP are only
    recorded by their handler; every loop and wait of a run checks the
    record (:func:`check_stop`: between kernel calls, member chunks, sweep
    points, chunk reads, and while waiting for Dask tasks or another
    process) and raises :class:`Interrupted` there, in the main thread.  A
    handler that raised would drop its exception wherever it lands in code
    that ignores exceptions (a garbage-collector callback, a library's
    compiled code); a record cannot be lost.  The current member chunk is
    abandoned within one kernel call (~0.1 s).  Code that must not be cut in
    half (writing a chunk, renaming a file) runs inside :func:`critical`: a
    stop is not raised there, and is raised when the section ends.  Once
    raised, further signals are ignored while the program cleans up; a third
    one ends the process at once.

Temporaries
    Every file is written to a temporary ``.<name>.<pid>.tmp`` next to its
    destination and renamed onto it when complete.  :func:`create_temp`
    creates it and holds a POSIX record lock on it for as long as the writer
    lives, so another process can tell a live writer's temporary from one
    left by a process that died (killed, out of memory, lost node): the lock
    is released by the kernel when its owner dies, also across machines on a
    filesystem with network locks.  :func:`leftovers` lists the temporaries
    of a destination whose owner is gone; a live writer's are never listed.

Output locks
    :class:`OutputLock` is held by the one process that writes a given
    output (a run's netCDF file, a study's folder): a second process for the
    same output is refused instead of clobbering the first, and whoever holds
    the lock knows that every other temporary of that output is stale.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import signal
import socket
import threading
import time
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no locks, liveness by pid
    fcntl = None

#: The signals that stop a run or a study cleanly.
SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None)


class Interrupted(BaseException):
    """A stop signal arrived.  A BaseException, like KeyboardInterrupt, so
    that ``except Exception`` clauses on the way up do not swallow it.

    ``kept`` collects what the interrupted work left for a rerun (one phrase
    per output), for the one line the command prints.
    """

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.kept: list[str] = []
        super().__init__(self.name)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """128 + the signal number: 130 (SIGINT), 143 (SIGTERM), 129 (SIGHUP)."""
        return 128 + self.signum


class _State:
    active = False
    depth = 0  # nesting of critical sections
    signum: int | None = None  # the first stop signal received
    raised = False  # Interrupted was raised for it at least once
    count = 0


_state = _State()


def _handler(signum, frame):
    """Record the signal; the next :func:`check_stop` raises it."""
    st = _state
    st.count += 1
    if st.count >= 3:  # the user insists: leave now, whatever is left behind
        os._exit(128 + signum)
    if st.signum is None:
        st.signum = signum


@contextlib.contextmanager
def stop_on_signals():
    """Record SIGINT, SIGTERM and SIGHUP within the block, for :func:`check_stop`
    to raise as :class:`Interrupted`.

    Only in the main thread (signal handlers live there); elsewhere a no-op.
    The previous handlers are restored on exit.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in SIGNALS}
    _state.active, _state.depth, _state.raised, _state.count, _state.signum = True, 0, False, 0, None
    for s in SIGNALS:
        signal.signal(s, _handler)
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        _state.active = False


class critical:
    """A section that a stop signal does not cut: it is raised at the end."""

    def __enter__(self):
        _state.depth += 1
        return self

    def __exit__(self, exc_type, exc, tb):
        _state.depth -= 1
        if exc_type is None and not _state.raised:
            check_stop()
        return False


def stopping() -> bool:
    """True once a stop signal was raised (clean-up in progress)."""
    return _state.raised


def stop_received() -> int | None:
    """The stop signal received within :func:`stop_on_signals` (None: none),
    raised or not yet."""
    return _state.signum if _state.active else None


def check_stop() -> None:
    """Raise :class:`Interrupted` if a stop signal was received (outside a
    critical section, in the main thread).  The signal handler only records
    the signal, so every loop of a run and every wait calls this between
    units of work (kernel calls, member chunks, sweep points, chunk reads,
    polls of Dask tasks); after the first raise it raises again, so work
    that goes on regardless (an exception swallowed on the way up) still
    stops at its next check."""
    st = _state
    if (st.active and st.signum is not None and st.depth == 0
            and threading.current_thread() is threading.main_thread()):
        st.raised = True
        raise Interrupted(st.signum)


#: seconds between checks of a stop signal while waiting for other work
POLL_SECONDS = 0.05


def wait_checking(done, poll: float = POLL_SECONDS) -> None:
    """Wait until ``done(timeout)`` returns true, calling it with ``poll``
    seconds at a time and checking for a stop signal between the calls
    (``done`` waits at most its timeout: e.g. ``lambda t: not p.join(t) and
    not p.is_alive()`` for a process)."""
    while True:
        check_stop()
        if done(poll):
            return


def join_checking(process) -> None:
    """``process.join()`` (a thread or a process) with stop checks."""
    def done(t):
        process.join(t)
        return not process.is_alive()
    wait_checking(done)


# ---------------------------------------------------------------- temporaries
def temp_name(path: Path, pid: int | None = None, n: int = 0) -> Path:
    """``.<name>.<pid>.tmp`` next to ``path`` (``.<name>.<pid>.<n>.tmp`` if taken)."""
    pid = os.getpid() if pid is None else pid
    return path.with_name(f".{path.name}.{pid}{'.' + str(n) if n else ''}.tmp")


def _temp_re(name: str) -> re.Pattern:
    return re.compile(rf"^\.{re.escape(name)}\.(?P<pid>\d+)(?:\.\d+)?\.tmp(?P<side>\.json(?:\.new)?)?$")


def create_temp(path: str | os.PathLike) -> tuple[Path, int | None]:
    """Create and lock a fresh temporary for ``path``: ``(temp path, fd)``.

    The fd holds the lock; :func:`release_temp` closes it.  Raises OSError if
    the folder does not take a new file.
    """
    path = Path(path)
    for n in range(100):
        tmp = temp_name(path, n=n)
        try:
            fd = os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
        except FileExistsError:
            continue
        try:
            if fcntl is not None:
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            pass  # no record locks here: liveness falls back to the pid
        return tmp, fd
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(path))


def release_temp(fd: int | None) -> None:
    if fd is not None:
        try:
            os.close(fd)
        except OSError:
            pass


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _owner_alive(tmp: Path, pid: int) -> bool:
    """Is the process that writes ``tmp`` alive?  Its record lock says so; where
    the filesystem has no locks, whether ``pid`` runs on this machine."""
    if pid == os.getpid():
        return True
    if fcntl is None:  # pragma: no cover
        return _pid_alive(pid)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        return False
    except OSError:
        return _pid_alive(pid)
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except (BlockingIOError, PermissionError):
        return True  # locked: its writer lives
    except OSError:
        return _pid_alive(pid)
    finally:
        os.close(fd)  # also drops the test lock
    return False


def leftovers(path: str | os.PathLike) -> list[Path]:
    """Temporaries of ``path`` (and their side files) whose writer is gone."""
    path = Path(path)
    pat = _temp_re(path.name)
    try:
        names = os.listdir(path.parent)
    except OSError:
        return []
    found = []
    for name in sorted(names):
        m = pat.match(name)
        if not m:
            continue
        p = path.parent / name
        data = p.with_name(name[:-len(m["side"])]) if m["side"] else p
        if data.exists():
            if _owner_alive(data, int(m["pid"])):
                continue
        elif int(m["pid"]) == os.getpid() or _pid_alive(int(m["pid"])):
            continue
        found.append(p)
    return found


def folder_leftovers(folder: str | os.PathLike) -> list[Path]:
    """Stale temporaries of every file in ``folder`` (not recursive)."""
    folder = Path(folder)
    pat = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)(?:\.\d+)?\.tmp(?P<side>\.json(?:\.new)?)?$")
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    targets = {pat.match(n)["name"] for n in names if pat.match(n)}
    out: list[Path] = []
    for t in sorted(targets):
        out += leftovers(folder / t)
    return out


def figure_drafts(folder: str | os.PathLike, stem: str) -> list[Path]:
    """Folders ``.<stem>_figures.<pid>.*`` in which a process that is gone was
    drawing figures (a run draws into such a folder, then renames the files)."""
    folder = Path(folder)
    pat = re.compile(r"^\." + re.escape(stem) + r"_figures\.(?P<pid>\d+)\.")
    try:
        names = sorted(os.listdir(folder))
    except OSError:
        return []
    out = []
    for n in names:
        m = pat.match(n)
        if m and (folder / n).is_dir() and int(m["pid"]) != os.getpid() and not _pid_alive(int(m["pid"])):
            out.append(folder / n)
    return out


def remove_files(paths) -> tuple[int, int]:
    """Remove files; ``(count, bytes)`` of those removed."""
    n = size = 0
    for p in paths:
        try:
            s = p.stat().st_size
            p.unlink()
        except FileNotFoundError:
            continue
        n += 1
        size += s
    return n, size


def one_line(text) -> str:
    """``text`` on one printable line: control characters (a newline in a key
    name, say) and undecodable bytes are shown escaped."""
    text = str(text)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape", "backslashreplace").decode("ascii")
                   for c in text)


def human_bytes(n: float) -> str:
    n = float(n)
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"  # pragma: no cover


# ---------------------------------------------------------------- output locks
class Busy(Exception):
    """Another live process holds the lock of this output."""

    def __init__(self, path: Path, holder: str):
        self.path, self.holder = path, holder
        super().__init__(f"{path}: another liethermo process ({holder}) is writing it; "
                         "wait for it to finish or write elsewhere")


#: file descriptors of the output locks this process holds
_HELD_LOCKS: set = set()


def _close_inherited_locks() -> None:
    """In a forked child: close its copies of the parent's lock descriptors.
    An flock belongs to the open file, which a fork shares; a child that
    kept its copy (the kernel-warming process, a worker) would hold the
    output locked after its parent was killed, and the rerun that should
    take over would be refused as if the dead run were still writing."""
    for fd in list(_HELD_LOCKS):
        try:
            os.close(fd)
        except OSError:
            pass
    _HELD_LOCKS.clear()


#: seconds a lock held only through a dead holder's forked child is waited for
DEAD_HOLDER_WAIT = 2.0


def _holder_is_dead(holder: str) -> bool:
    """Whether a lock file's ``pid N on HOST`` names a process of this host that no longer runs."""
    parts = holder.split()
    if len(parts) != 4 or parts[0] != "pid" or parts[2] != "on" or parts[3] != socket.gethostname():
        return False
    try:
        os.kill(int(parts[1]), 0)
    except ProcessLookupError:
        return True
    except (OSError, ValueError):
        return False
    return False


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_inherited_locks)


class OutputLock:
    """Exclusive lock of one output (a file, or a study folder), held by this
    process until :meth:`release`: ``.<name>.lock`` next to it (inside it for a
    folder), with the holder's pid and host as its content.  Forked children
    do not inherit it.

    Where the filesystem has no locks, acquiring always succeeds (and the
    temporaries' liveness falls back to pids).
    """

    def __init__(self, target: str | os.PathLike, *, folder: bool = False):
        target = Path(target)
        self.target = target
        self.path = target / ".liethermo.lock" if folder else target.with_name(f".{target.name}.lock")
        self.fd: int | None = None

    def acquire(self) -> "OutputLock":
        if fcntl is None:  # pragma: no cover
            return self
        deadline = None
        for _ in range(10_000):
            fd = os.open(self.path, os.O_CREAT | os.O_RDWR, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                try:
                    holder = os.read(fd, 200).decode(errors="replace").strip() or "unknown"
                finally:
                    os.close(fd)
                # a holder on this host that has died: a child forked just before its death
                # still shares the lock until it has run its fork handler (closing it), which
                # a loaded machine may delay; wait for that briefly, not for a live holder
                deadline = deadline or time.monotonic() + DEAD_HOLDER_WAIT
                if _holder_is_dead(holder) and time.monotonic() < deadline:
                    time.sleep(0.02)
                    continue
                raise Busy(self.target, holder) from None
            except OSError:
                os.close(fd)  # no locks on this filesystem
                return self
            # the previous holder may have removed the file between our open and
            # our lock: then we locked an unlinked inode, and must start over
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            try:  # who holds it, for the message of a refused second process
                os.ftruncate(fd, 0)
                os.write(fd, f"pid {os.getpid()} on {socket.gethostname()}\n".encode())
            except OSError:
                pass  # a full disk: the lock holds all the same
            self.fd = fd
            _HELD_LOCKS.add(fd)
            return self
        raise Busy(self.target, "lock file keeps changing")  # pragma: no cover

    def release(self) -> None:
        if self.fd is None:
            return
        try:
            self.path.unlink()
        except OSError:
            pass
        _HELD_LOCKS.discard(self.fd)
        os.close(self.fd)
        self.fd = None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
        return False
