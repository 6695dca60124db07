"""One launch at a time per experiment and store: an exclusive lock on a file, naming its holder.

Standard library only. The lock is ``flock`` on a file beside the SQLite store (``Tracker.lock_path``): the
kernel releases it when the holder exits in any way, ``kill -9`` included, so a stale lock cannot outlive
its process and no lease has to expire. The file's text (pid, host, start, command) is only for the message.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path


class LaunchLocked(RuntimeError):
    """Another live launch holds the lock (the message names it), or the lock file cannot be opened: one line."""


def _holder_text(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError):
        info = {}
    if not info:
        return "a launch that is starting"
    alive = ""
    if info.get("host") == socket.gethostname() and not _pid_alive(int(info.get("pid", 0))):
        # flock says held but the recorded process is gone: a child it started without closing the file
        # still holds it. Naming the pid lets the user find it.
        alive = ", gone, but a process it started still holds the lock"
    return (
        f"pid {info.get('pid')} on {info.get('host')}{alive}, started {info.get('started')}"
        f" ({info.get('command') or 'ablate run'})"
    )


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def launch_lock(path: Path, what: str, command: str = "") -> Iterator[None]:
    """Hold the lock at ``path`` for the body, or raise ``LaunchLocked`` at once naming the launch that has it."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)  # the per-user folder for a tracking server's locks
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as error:
        raise LaunchLocked(f"cannot open the launch lock {path}: {error.strerror}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise LaunchLocked(
                f"{what} is already being run on this store by {_holder_text(fd)}; wait for it to end or stop it "
                f"(lock: {path})"
            ) from None
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
            "command": command,
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        yield
    finally:
        os.close(fd)
