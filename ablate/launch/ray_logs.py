"""Ray's and Tune's own messages (a dead worker's traceback, a failed callback's) into the launch's log file,
and the one line the terminal gets instead. Standard library only: the scheduler hands Ray's parts in.
"""

from __future__ import annotations

import contextlib
import logging
import re
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from ablate.launch.secrets import shown

_launch_log: Path | None = None
"""The log file of the launch running now, or of the last one: where Ray's raylet errors go (a worker's death
is published after the fact, and may arrive once the launch's trials have ended)."""


class SchedulerFailed(RuntimeError):
    """Ray or Tune ended the run with an error: its last line, and the log that holds the rest."""


@contextlib.contextmanager
def tune_logs_to(path: Path) -> Iterator[None]:
    """Ray's and Tune's log records (a dead worker's or a failed callback's traceback: 16-25 lines) go to
    ``path`` instead of the terminal, where the progress view and one line of what happened stay."""
    loggers = [logging.getLogger(name) for name in ("ray", "ray.tune", "ray.train", "ray.air")]
    saved = [(logger, list(logger.handlers), logger.propagate) for logger in loggers]
    handler: logging.Handler | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(path, delay=True)
        handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
    except OSError:
        handler = None  # no log file: Ray's own handlers stay
    global _launch_log
    _launch_log = path
    if handler is not None:
        for logger in loggers:
            logger.handlers = [h for h in logger.handlers if not isinstance(h, logging.StreamHandler)]
        loggers[0].addHandler(handler)
        for logger in loggers[1:]:
            logger.propagate = True
    try:
        yield
    finally:
        for logger, handlers, propagate in saved:
            logger.handlers, logger.propagate = handlers, propagate
        if handler is not None:
            handler.close()


def one_line(error: BaseException, log_path: Path) -> Exception:
    """Tune wraps an error of our callback in a ``TuneError`` whose text is the traceback: the store's own
    error (``TrackingError``, one line already) is raised as it was, anything else as its last line."""
    from ablate.launch.store import TrackingError

    texts, cause = [], error
    while cause is not None and len(texts) < 10:
        texts.append(str(cause))
        cause = cause.__cause__ or cause.__context__
    lines = [line.strip() for text in texts for line in text.splitlines() if line.strip()]
    for line in reversed(lines):
        head, _, message = line.partition(": ")
        if head.endswith("TrackingError") and message:
            return TrackingError(message)
    causes = [line for line in lines if not line.startswith(("Traceback", "File ", "^", "~"))]
    last = causes[-1] if causes else type(error).__name__
    where = f"; Ray's and Tune's messages: {log_path}" if log_path.is_file() else ""
    return SchedulerFailed(f"{shown(last)[:300]}{where}")


def log_raylet_errors(lines: list[str]) -> bool:
    """A raylet's errors (``A worker died or was killed ...``: ~1,000 characters per dead worker) written to the
    launch's log file, and one short line naming it to the terminal; False (not taken: Ray prints them as it
    does) before any launch or when the log cannot be opened. ``patches.ray_raylet_errors_to`` hands them in."""
    path = _launch_log
    if path is None:
        return False
    try:
        log = path.open("a")
    except OSError:
        return False
    with log:  # the terminal's line first: a message seen in the log has been told
        for line in lines:
            sys.stderr.write(f"{raylet_summary(line)}; Ray's message in full: {path}\n")
        for line in lines:
            log.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} raylet ERROR {shown(line)}\n")
    return True


def raylet_summary(message: str) -> str:
    """``Ray: a worker died or was killed while executing a task by an unexpected system error (pid 11668,
    SYSTEM_ERROR)``: the first sentence of a raylet's error, with the worker's pid and exit type where given."""
    first = re.split(r"(?<=[a-z)])\. ", message.strip(), maxsplit=1)[0].rstrip(".")
    first = first[:1].lower() + first[1:]
    details = [
        f"{label} {m.group(1)}"
        for label, key in (("pid", "Worker PID"), ("", "Worker exit type"))
        if (m := re.search(rf"{key}: (\S+)", message))
    ]
    detail = f" ({', '.join(d.strip() for d in details)})" if details else ""
    return shown(f"Ray: {first[:200]}{detail}")
