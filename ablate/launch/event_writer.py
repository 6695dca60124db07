"""The launch's trial events told on a thread of the driver's own (``EventWriter``), so Tune's callbacks only queue
them: the scheduler (the one module that talks to Ray) hands each event here. Standard library only."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any


class EventWriter:
    """Trial events (``Recorder`` calls) told on a thread of their own, in the order they came. Tune holds a
    population's worker at each report until the driver's callbacks have returned, and telling a report's events
    is the launch's MLflow writes (tens of ms a member, more on a tracking server): told inline they held the
    workers for ~a quarter of their time (a 200-seed launch, populations of 50). A write that fails stops the
    telling; the next event queued, or ``close``, raises its error."""

    def __init__(self, events: Any) -> None:
        self.events = events
        self.error: BaseException | None = None
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="ablate-events")

    def _tell(self, event: Callable[..., None], args: tuple) -> None:
        if self.error is None:
            try:
                event(*args)
            except BaseException as error:  # noqa: BLE001 - raised on the driver's thread, by put or close
                self.error = error

    def put(self, event: Callable[..., None], *args: Any) -> None:
        """Tell ``event(*args)`` (a method of ``events``) after the events queued before it."""
        if self.error is not None:
            raise self.error
        self.pool.submit(self._tell, event, args)

    def close(self, drop: bool = False) -> None:
        """Wait until the queued events are told (``drop``: only the one being told), then raise a failed write's
        error. A second Ctrl-C does not cut the wait short: the caller then writes to the same store."""
        while True:
            with contextlib.suppress(KeyboardInterrupt):
                self.pool.shutdown(cancel_futures=drop)
                break
        if self.error is not None and not drop:
            raise self.error
