"""One launch at a time per experiment and store, wherever its drivers run: filelock's ``FileLock`` on a file
(``store.lock_file``; the kernel frees it however its holder exits, ``kill -9`` included) serialises one machine's
launches, and for a server or a database a lease kept in the store itself (``StoreLease``) other machines'.
Each refusal names the holder (host, pid, start, its command without secrets).
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from filelock import FileLock, Timeout

from ablate.launch.secrets import shown
from ablate.launch.store import first_line


class LaunchLocked(RuntimeError):
    """Another live launch holds the lock (the message names it), or the lock file cannot be opened: one line."""


def _holder_text(path: Path) -> str:
    try:
        info = json.loads(path.read_text() or "{}")
    except (OSError, ValueError):
        info = {}
    return _holder_line(info) if info else "a launch that is starting"


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
    lock = FileLock(path, mode=0o600)  # its holder's command: this user's only
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)  # the per-user folder of a server's locks
        lock.acquire(timeout=0)
    except Timeout:
        raise LaunchLocked(
            f"{what} is already being run on this store by {_holder_text(path)}; wait for it to end or stop it "
            f"(lock: {path})"
        ) from None
    except OSError as error:
        raise LaunchLocked(f"cannot open the launch lock {path}: {error.strerror}") from None
    try:
        info = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%d %H:%M:%S")}
        path.write_text(json.dumps({**info, "command": shown(command)}))  # flock is the file's, not this open's
        yield
    finally:
        lock.release()


LEASE_EXPIRY_S = 120.0
"""A store lease whose holder has not renewed it for this long has lapsed (its driver died on another machine,
or lost the store): the next launch takes it. The holder renews it every ``LEASE_EXPIRY_S / 4``."""
LEASE_PREFIX = "ablate-lease-"
"""The lease of experiment ``x`` is the MLflow experiment ``ablate-lease-x`` (no runs; its tags name the
holder): MLflow refuses a second experiment of one name, in any store, which makes taking it atomic."""
_HOLDER = ("host", "pid", "started", "heartbeat", "command")


def _holder_line(info: dict[str, Any]) -> str:
    command = shown(info.get("command") or "ablate run")
    return f"pid {info.get('pid')} on {info.get('host')}, started {info.get('started')} ({command})"


def lapsed(info: dict[str, str], now: float | None = None) -> str:
    """Why the lease ``info`` (its tags) has lapsed, or "" while its holder holds it: its heartbeat is older
    than ``LEASE_EXPIRY_S``, or its holder is a process of this machine that is gone."""
    now = time.time() if now is None else now
    try:
        heartbeat = float(info.get("ablate.lease.heartbeat", "0"))
    except ValueError:
        heartbeat = 0.0
    if now - heartbeat > LEASE_EXPIRY_S:
        return f"not renewed for {now - heartbeat:.0f} s (the bound: {LEASE_EXPIRY_S:.0f} s)"
    pid = info.get("ablate.lease.pid", "")
    if info.get("ablate.lease.host") == socket.gethostname() and pid.isdigit() and not _pid_alive(int(pid)):
        return f"its process {pid} on this machine is gone"
    return ""


class StoreLease:
    """The launch lease of one experiment, kept in the store itself (an MLflow experiment of its own; see
    ``LEASE_PREFIX``), so that drivers on any machines, and any spelling of the store's URI, exclude each other.
    ``client``: an ``MlflowClient`` (this module does not import MLflow; its errors are told by their code)."""

    def __init__(self, client: Any, experiment_name: str, what: str, command: str) -> None:
        self.client, self.name, self.what = client, LEASE_PREFIX + experiment_name, what
        self.command = shown(command)
        self.experiment_id: str | None = None
        self.lost = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _tags(self) -> dict[str, str]:
        return {
            "ablate.role": "lease",
            "ablate.lease.host": socket.gethostname(),
            "ablate.lease.pid": str(os.getpid()),
            "ablate.lease.started": time.strftime("%Y-%m-%d %H:%M:%S"),
            "ablate.lease.heartbeat": f"{time.time():.3f}",
            "ablate.lease.command": self.command,
        }

    def acquire(self) -> None:
        """Take the lease, or raise ``LaunchLocked`` naming its live holder; a lapsed one is moved aside first."""
        for _ in range(5):
            try:
                self.experiment_id = self.client.create_experiment(self.name, tags=self._tags())
                break
            except Exception as error:  # noqa: BLE001 - MlflowException: told by its error code
                if "RESOURCE_ALREADY_EXISTS" not in f"{getattr(error, 'error_code', '')} {error}":
                    raise LaunchLocked(f"cannot take the launch lease {self.name!r}: {first_line(error)}") from None
            holder = self.client.get_experiment_by_name(self.name)
            if holder is None:
                continue  # moved aside between the two calls: try again
            info = dict(holder.tags)
            why = "it was deleted" if holder.lifecycle_stage == "deleted" else lapsed(info)
            if not why:
                holder_info = {k: info.get(f"ablate.lease.{k}", "?") for k in _HOLDER}
                raise LaunchLocked(
                    f"{self.what} is already being run on this store by {_holder_line(holder_info)}; wait for it "
                    f"to end or stop it (its lease: MLflow experiment {self.name!r}, renewed every "
                    f"{LEASE_EXPIRY_S / 4:.0f} s, lapses {LEASE_EXPIRY_S:.0f} s after its holder stops)"
                )
            sys.stderr.write(
                f"the launch lease of pid {info.get('ablate.lease.pid')} on "
                f"{info.get('ablate.lease.host')} lapsed ({why}); taking it\n"
            )
            self._move_aside(holder.experiment_id, holder.lifecycle_stage == "deleted")
        else:
            raise LaunchLocked(f"cannot take the launch lease {self.name!r}: it changed hands 5 times in a row")
        self._thread = threading.Thread(target=self._renew, name="ablate-lease", daemon=True)
        self._thread.start()

    def _move_aside(self, experiment_id: str, deleted: bool) -> None:
        """Rename the experiment (by id: a newer lease of the same name is not touched) and delete it, so its
        name is free for ``create_experiment``; another launch doing the same at once is harmless."""
        try:
            if deleted:
                self.client.restore_experiment(experiment_id)
            self.client.rename_experiment(experiment_id, f"{self.name}.ended-{uuid.uuid4().hex[:12]}")
        except Exception as error:  # noqa: BLE001 - MlflowException; another launch may have moved it first
            current = self.client.get_experiment_by_name(self.name)
            if current is not None and current.experiment_id == experiment_id:
                raise LaunchLocked(
                    f"the launch lease {self.name!r} has lapsed, but this login may not clear it "
                    f"({first_line(error)}); ask the server's admin for EDIT on that experiment, or to delete it"
                ) from None
            return
        with contextlib.suppress(Exception):  # renamed: its name is free; deleting it only tidies the UI
            self.client.delete_experiment(experiment_id)

    def _renew(self) -> None:
        while not self._stop.wait(LEASE_EXPIRY_S / 4):
            try:
                current = self.client.get_experiment(self.experiment_id)
                if current.name != self.name:
                    self.lost = f"the launch lease {self.name!r} was taken over by another launch"
                    sys.stderr.write(f"warning: {self.lost}\n")
                    return
                self.client.set_experiment_tag(self.experiment_id, "ablate.lease.heartbeat", f"{time.time():.3f}")
            except Exception:  # noqa: BLE001, S112 - the store's absence is the writer's to report; try again
                continue

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
        if self.experiment_id is not None and not self.lost:
            with contextlib.suppress(Exception):  # else it lapses: at once for the next launch of this machine
                self._move_aside(self.experiment_id, False)


@contextlib.contextmanager
def held_launch(
    path: Path, what: str, command: str = "", client: Any = None, experiment_name: str = ""
) -> Iterator[None]:
    """This machine's lock at ``path`` (the fast path; an SQLite store needs nothing else), then, with an
    ``client`` (a store other machines reach), the store's own lease for ``experiment_name``."""
    with launch_lock(path, what, command):
        if client is None:
            yield
            return
        lease = StoreLease(client, experiment_name, what, command)
        lease.acquire()
        try:
            yield
        finally:
            lease.release()
