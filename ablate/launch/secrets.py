"""Secrets turned into their shown form: the one place every URI, command line and message passes through
before ablate prints, logs, writes, tags or hands it to Ray. Standard library only.

A URI's userinfo is masked up to the last ``@`` before its host, whatever it holds (raw ``@``, ``/``, ``:`` or
percent-encoded ones); so are credential-like parameters and every secret this process holds (``secret_values``).
Not SQLAlchemy's ``render_as_string(hide_password=True)`` nor urllib's ``urlsplit``: both end the userinfo at a
raw ``/`` (shown: ``mlflow:***@nted/pw%3A9x...``), SQLAlchemy keeps ``?password=`` and neither reads free text.
"""

from __future__ import annotations

import configparser
import contextlib
import functools
import os
import re
import shlex
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO
from urllib.parse import quote, unquote

MASK = "***"
SECRET_ENV = (
    "MLFLOW_TRACKING_PASSWORD",
    "MLFLOW_TRACKING_TOKEN",
    "MLFLOW_TRACKING_CLIENT_CERT_PATH",
    "RAY_AUTH_TOKEN",
    "PGPASSWORD",
    "MYSQL_PWD",
    "AWS_SECRET_ACCESS_KEY",
    "AWS_SESSION_TOKEN",
    "AZURE_STORAGE_ACCESS_KEY",
    "AZURE_STORAGE_CONNECTION_STRING",
    "DATABRICKS_TOKEN",
)
"""Environment variables holding secrets: their values are masked in whatever ``shown`` is given."""
MIN_SECRET = 4
"""Secrets shorter than this are not replaced in free text: they would mask ordinary words."""

# scheme://USERINFO@host; a URI whose authority is empty (sqlite:///path, file:///path) has none.
_USERINFO = re.compile(r"(?P<head>[A-Za-z][A-Za-z0-9+.-]*://)(?P<userinfo>[^\s'\"/@][^\s'\"]*)@")
_KEY = r"[A-Za-z0-9_.-]*(?:password|passwd|pwd|secret|token|api[_-]?key|access[_-]?key|credential)[A-Za-z0-9_.-]*"
_KEYWORD = re.compile(rf"(?P<head>(?:^|[?&;\s,])(?i:{_KEY})=)(?P<value>'[^']*'|\"[^\"]*\"|[^&\s'\";,#]*)")
_remembered: set[str] = set()


def remember(*values: str | None) -> None:
    """Secrets this process learned (a URI's password): masked from now on, in any spelling of them."""
    for value in values:
        if value and len(value) >= MIN_SECRET:
            _remembered.update({value, unquote(value), quote(unquote(value), safe="")})


def remember_uri(uri: str | None) -> None:
    """The password of ``uri``'s userinfo and its credential-like parameters: remembered (``remember``)."""
    if not uri:
        return
    remember(split_userinfo(uri)[2])
    remember(*(m.group("value") for m in _KEYWORD.finditer(uri)))


def split_userinfo(uri: str) -> tuple[str, str | None, str | None, str]:
    """``scheme://user:password@rest`` as (``scheme://``, user, password, rest), user and password decoded
    (percent-encoding undone); (``uri``, None, None, "") when there is no userinfo."""
    match = _USERINFO.match(uri)
    if match is None:
        return uri, None, None, ""
    userinfo = match.group("userinfo")
    user, colon, password = userinfo.partition(":")
    return match.group("head"), unquote(user), unquote(password) if colon else None, uri[match.end() :]


def encoded_uri(uri: str) -> str:
    """``uri`` with its user and password percent-encoded, so URL parsers (SQLAlchemy, requests, urllib)
    read a raw ``/``, ``@`` or ``:`` in a password as the password, not as a host, port or path."""
    head, user, password, rest = split_userinfo(uri)
    if user is None:
        return uri
    remember_uri(uri)
    userinfo = quote(user, safe="") + ("" if password is None else ":" + quote(password, safe=""))
    return f"{head}{userinfo}@{rest}"


def without_userinfo(uri: str) -> str:
    """``uri`` with no ``user:password@`` at all (the address of a tracking server)."""
    head, user, _, rest = split_userinfo(uri)
    return uri if user is None else f"{head}{rest}"


def mask_uri(text: str) -> str:
    """``text`` with every URI's password (``user:***@``) and every credential-like query or keyword value
    (``?password=***``) masked: the form of a store or server that errors, logs and the report show."""

    def userinfo(match: re.Match[str]) -> str:
        user, colon, _ = match.group("userinfo").partition(":")
        return f"{match.group('head')}{user}:{MASK}@" if colon else match.group(0)

    text = _USERINFO.sub(userinfo, text)
    return _KEYWORD.sub(lambda m: f"{m.group('head')}{MASK}", text)


def shown_uri(uri: str) -> str:
    """A store as messages show it: a tracking server without its login (ablate moves that out of the URI,
    ``store.open_uri``), any other URI with its password masked."""
    if uri.lower().startswith(("http://", "https://")):
        uri = without_userinfo(uri)
    return shown(uri)


def _read_cached(path: str) -> str:
    """The text of ``path`` ("" when it cannot be read), read again only when its mtime changes: ``shown`` runs
    on every line the CLI prints."""
    path = os.path.expanduser(path)
    with contextlib.suppress(OSError):
        return _read(path, os.stat(path).st_mtime)
    return ""


@functools.lru_cache(maxsize=8)
def _read(path: str, mtime: float) -> str:
    return Path(path).read_text(errors="replace")


def mlflow_credential(name: str) -> str:
    """``name`` in the ``[mlflow]`` section of ``~/.mlflow/credentials`` (``MLFLOW_CREDENTIALS_PATH``); "" if none."""
    parser = configparser.ConfigParser()
    with contextlib.suppress(configparser.Error):  # a malformed file, or a lone % in a value, as MLflow reads it
        parser.read_string(_read_cached(os.environ.get("MLFLOW_CREDENTIALS_PATH", "~/.mlflow/credentials")))
        return parser.get("mlflow", name, fallback="")
    return ""


def secret_values() -> list[str]:
    """The secrets this process holds, longest first (so no part of one is left behind another's mask)."""
    values = {os.environ.get(name, "") for name in SECRET_ENV} | _remembered
    token_path = os.environ.get("RAY_AUTH_TOKEN_PATH")
    if token_path:
        values.add(_read_cached(token_path).strip())
    values.add(mlflow_credential("mlflow_tracking_password"))
    values.add(split_userinfo(os.environ.get("MLFLOW_TRACKING_URI", ""))[2] or "")
    return sorted((v for v in values if len(v) >= MIN_SECRET), key=len, reverse=True)


class Shown(str):
    """Text that passed ``shown``: what a report's provenance and a launch's record take, so that no command line
    or URI reaches them unmasked (they refuse a plain ``str``)."""


def shown(text: Any) -> Shown:
    """``text`` (a message, a command line, a URI, an exception) as ablate may show or record it: every URI's
    password, credential-like parameter and secret this process holds masked."""
    text = mask_uri(str(text))
    for value in secret_values():
        if value in text:
            text = text.replace(value, MASK)
    return Shown(text)


def shown_command(words: Sequence[str]) -> Shown:
    """A command line as ablate records it (a report's provenance, a launch's tag): its words masked one by one,
    then shell-quoted (so a quote cannot split a password out of the mask's reach), and the line masked again.
    The mask alone does not quote a word: ``--tracking-uri http://alice:***@host`` reads as typed."""

    def quoted(word: str) -> str:
        plain = word.replace(MASK, "")
        return word if shlex.quote(plain) == plain else shlex.quote(word)

    return shown(" ".join(quoted(shown(word)) for word in words))


class MaskedStream:
    """A text stream that writes the shown form of what it is given to ``stream`` (``sys.stdout``, ``stderr``):
    what any library prints through Python passes the masks too (MLflow's "View run ... at: URI" lines)."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        self._stream.write(shown(text))
        return len(text)

    def __getattr__(self, name: str) -> Any:  # flush, isatty, fileno, encoding: the stream's own
        return getattr(self._stream, name)


@contextlib.contextmanager
def masked_output() -> Iterator[None]:
    """``sys.stdout`` and ``sys.stderr`` masked for the body (the CLI's whole command), then as they were."""
    with contextlib.redirect_stdout(MaskedStream(sys.stdout)), contextlib.redirect_stderr(MaskedStream(sys.stderr)):
        yield
