"""A store mid-run: the driver's writes retried for a bounded time while the store does not answer, and a store
that answers with an error (permission, a full disk, a refused login) named at once, in one line.
Not MLflow's own retries (``MLFLOW_HTTP_REQUEST_MAX_RETRIES``, ``..._BACKOFF_FACTOR``): they reach a tracking
server only, never an SQL store (SQLite, PostgreSQL, MySQL: MLflow retries its deadlocks alone). Not tenacity:
not installed (torch, Ray and MLflow do not pull it), and the loop is 25 lines.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

from ablate.launch.store import TrackingError, first_line

STORE_RETRY_S = 40.0
"""How long the driver retries a write whose store stopped answering (a database restarting, a network blip)
before it stops the launch: trials not recorded by then run again on the next launch."""
WRITE_TIMEOUT_S = 15
"""One request of the driver's to a tracking server, mid-run: this long, one try (``RetryingClient`` retries).
With ``STORE_RETRY_S`` and the launch's teardown, a store that stops answering ends the launch within
``STORE_BOUND_S`` of the first failed write."""
STORE_BOUND_S = 60
_LOST = ("operationalerror", "connection", "refused", "timed out", "timeout", "server closed", "max retries")
_ANSWERED_5XX = ("error code 5", "error code 429", "too many 5", "server error", "bad gateway", "unavailable")
_ANSWERED = {  # the login first: a 403's body says "Permission denied" too
    "auth": (
        ("error code 401", "error code 403", "unauthorized", "permission_denied"),
        "the login was refused mid-run (HTTP 401/403: a changed password or a revoked permission); check "
        "MLFLOW_TRACKING_USERNAME/PASSWORD and ask the server's admin for EDIT",
    ),
    "permission": (
        (
            "permission denied",
            "operation not permitted",
            "errno 13",
            "permissionerror",
            "read-only file system",
            "readonly database",
        ),
        "the server may not write its store or artifact folder (permission denied); fix the folder's owner or "
        "mode on the server",
    ),
    "disk": (
        ("no space left", "errno 28", "disk is full", "disk full", "quota exceeded"),
        "the server's disk is full; free space where it keeps its store and artifacts",
    ),
}


def store_fault(error: BaseException) -> tuple[str, str]:
    """What a failed write says of the store: ``("lost", "")`` for a store that does not answer, ``("5xx",
    "")`` for one that answers with a server error (a restart, a lock: retried like a lost one), ``(kind,
    advice)`` for one that answered with an error it will give again (``permission``, ``disk``, ``auth``),
    ``("", "")`` for anything else (not the store's: passed through)."""
    text = f"{type(error).__name__} {error}".lower()
    for kind, (words, advice) in _ANSWERED.items():
        if any(word in text for word in words):
            return kind, advice
    if any(word in text for word in _ANSWERED_5XX):
        return "5xx", ""
    if any(word in text for word in _LOST):
        return "lost", ""
    return "", ""


class RetryingClient:
    """The writer's MlflowClient, each call retried for up to ``STORE_RETRY_S`` while the store does not
    answer, then a one-line ``TrackingError``; after that every call fails at once (the store is gone: the
    launch stops without waiting again for each trial). A store that answers with an error it would give
    again (permission, a full disk, a refused login) is a one-line ``TrackingError`` at once, naming which.
    Other errors pass through unchanged."""

    def __init__(self, client: Any, shown_uri: str) -> None:
        self._client, self._shown_uri, self._lost = client, shown_uri, ""

    def __getattr__(self, name: str) -> Any:
        method = getattr(self._client, name)
        if not callable(method):
            return method

        def call(*args: Any, **kwargs: Any) -> Any:
            return self.retried(method, *args, **kwargs)

        return call

    def retried(self, method: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """``method(*args, **kwargs)``, a write to this client's store by other means than the client's own
        methods (``patches.mlflow_insert_metrics``), retried and told as the client's calls are."""
        deadline = None
        while True:
            if self._lost:
                raise TrackingError(self._lost)
            try:
                return method(*args, **kwargs)
            except Exception as error:  # noqa: BLE001 - SQLAlchemy's and requests' errors alike
                kind, advice = store_fault(error)
                if not kind:
                    raise
                if kind not in ("lost", "5xx"):
                    raise TrackingError(
                        f"MLflow store {self._shown_uri} refused a write: {advice} ({first_line(error)})"
                    ) from None
                now = time.monotonic()  # read once: the two outcomes below must see the same moment
                deadline = deadline or now + STORE_RETRY_S
                if now >= deadline and kind == "5xx":  # it answers: the launch can be closed
                    raise TrackingError(
                        f"MLflow store {self._shown_uri} answered every try of a write with a server error for "
                        f"{STORE_RETRY_S:.0f} s ({first_line(error)}); its log says why (an artifact "
                        "folder it may not write, a full disk, ...): fix it and run the same command again"
                    ) from None
                if now >= deadline:
                    self._lost = (
                        f"MLflow store {self._shown_uri} stopped answering ({first_line(error)}); "
                        f"retried for {STORE_RETRY_S:.0f} s, the launch stops: run the same command again "
                        "once it is back (trials not recorded run again)"
                    )
                    raise TrackingError(self._lost) from None
            time.sleep(min(2.0, max(0.0, deadline - time.monotonic())))


def fail_fast_writes() -> None:
    """Mid-run, each request to a tracking server is one try of ``WRITE_TIMEOUT_S`` (MLflow's own retries, 7
    with backoff over minutes, made a lost server take 250 s to end a launch); ``RetryingClient`` retries."""
    os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] = "0"
    os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] = str(WRITE_TIMEOUT_S)
