"""Where runs are kept, before MLflow opens it: a tracking URI checked, probed in seconds, and shown or recorded
without its password. Standard library and SQLAlchemy only (MLflow is imported by ``tracking`` and the reader).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import re
import socket
import sys
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlparse

from ablate.config import ConfigError
from ablate.launch.secrets import encoded_uri, mlflow_credential, shown, split_userinfo, without_userinfo

DEFAULT_TRACKING_URI = "sqlite:///mlflow.db"
SCHEMES = ("sqlite", "http", "https", "file", "postgresql", "mysql", "mssql", "databricks")
"""URI schemes MLflow can track to (``file`` and a bare path: its folder store)."""
PROBE_TIMEOUT_S = 10
"""Seconds to connect to a store (a tracking server's port, a database) when it is opened. MLflow's defaults
(7 retries with backoff, 120 s timeout) are right mid-run but turn a mistyped server into minutes of silence."""
ANSWER_TIMEOUT_S = 60
"""The first request to a tracking server that accepted the connection: one try, this long. A basic-auth
server hashes the password of a login it has not seen (scrypt: ~0.1 s of CPU, 10-20 s on a machine loaded
20 times over), so a server that is there is given longer to answer than to be reached."""
SQLITE_MAGIC = b"SQLite format 3\x00"

DATABASE_SCHEMES = ("postgresql", "mysql", "mssql")
"""Schemes (and ``scheme+driver``) of the SQL servers MLflow can keep its runs in."""


class TrackingError(RuntimeError):
    """The tracking store cannot be used (unknown scheme, unreachable, corrupt, read-only, experiment deleted).
    The message is one line naming the store and what to do; ``exit_code`` is 2 for a malformed URI, else 1."""

    def __init__(self, message: str, exit_code: int = 1) -> None:
        super().__init__(message)
        self.exit_code = exit_code


def resolve_uri(tracking_uri: str | None) -> str:
    """Explicit URI, else ``MLFLOW_TRACKING_URI``, else an SQLite file in the current folder."""
    return tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or DEFAULT_TRACKING_URI


def sqlite_path(uri: str) -> Path | None:
    """The database file of an ``sqlite:///`` URI (relative to the current folder, or absolute with four
    slashes); ``None`` for any other store."""
    if not uri.startswith("sqlite:///"):
        return None
    return Path(uri.removeprefix("sqlite:///").split("?", 1)[0])


class StoreNotFound(ConfigError):
    """A reader (``ablate report``, ``ablate.load``) was pointed at a local MLflow store that does not exist."""


def check_store(tracking_uri: str | None) -> str:
    """The store's URI; a local store (SQLite file or folder) that does not exist is ``StoreNotFound``, so that
    reading never creates an empty database where a path was mistyped or a notebook runs elsewhere."""
    uri = resolve_uri(tracking_uri)
    check_uri(uri)  # a server's host:port without its scheme is that, not a missing folder of that name
    path = sqlite_path(uri)
    if uri.startswith("file:"):
        path = Path(uri.removeprefix("file://").removeprefix("file:"))
    elif "://" not in uri:
        path = Path(uri)
    if path is not None and not path.exists():
        raise StoreNotFound(
            f"tracking URI {uri!r}: no MLflow store at {path.resolve()} (relative paths are read from "
            f"{Path.cwd()}); valid: the store `ablate run` wrote, e.g. 'sqlite:////abs/path/mlflow.db'"
        )
    return uri


def login_user() -> str | None:
    """The MLflow user this process logs in as: ``MLFLOW_TRACKING_USERNAME``, else ``~/.mlflow/credentials``."""
    return os.environ.get("MLFLOW_TRACKING_USERNAME") or mlflow_credential("mlflow_tracking_username") or None


_HOST_PORT = re.compile(r"^[A-Za-z0-9.-]+:\d+(/.*)?$")
LOOPBACK = ("127.0.0.1", "localhost", "::1")
_warned_insecure: set[str] = set()
_insecure_allowed = False


def open_uri(uri: str) -> str:
    """The URI as MLflow is given it: checked (``check_uri``), its userinfo percent-encoded (a raw ``/``,
    ``@`` or ``:`` in a password is the password), and, for a tracking server, the login moved out of it into
    ``MLFLOW_TRACKING_USERNAME``/``PASSWORD``: no URI MLflow builds from it (artifact and run links, request
    errors) holds the password. Its password is remembered as a secret (``secrets.remember``)."""
    check_uri(uri)
    uri = encoded_uri(uri)
    head, user, password, rest = split_userinfo(uri)
    if head.lower() in ("http://", "https://") and user is not None:
        os.environ["MLFLOW_TRACKING_USERNAME"] = user
        if password is not None:
            os.environ["MLFLOW_TRACKING_PASSWORD"] = password
        uri = without_userinfo(uri)
    warn_insecure(uri)  # a login from the URI, the environment or ~/.mlflow/credentials alike
    return uri


@contextlib.contextmanager
def insecure_http(allowed: bool) -> Iterator[None]:
    """Within it, a login over plain HTTP to another machine is ``allowed`` (``--allow-insecure-http``: warned
    once) or refused, unless an enclosing call allowed it (the CLI's flag reaches the API calls it makes); the
    stores opened inside it are checked when they are opened."""
    global _insecure_allowed
    before, _insecure_allowed = _insecure_allowed, _insecure_allowed or allowed
    try:
        yield
    finally:
        _insecure_allowed = before


def _loopback(host: str) -> bool:
    import ipaddress

    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host.lower() in LOOPBACK


def warn_insecure(uri: str) -> None:
    """A login sent over plain HTTP to a host that is not this machine travels in clear: refused, one line and
    exit 2, unless allowed (``insecure_http``), then warned once per server."""
    parsed = urlparse(uri)
    if parsed.scheme != "http" or _loopback(parsed.hostname or "") or uri in _warned_insecure:
        return
    if not (os.environ.get("MLFLOW_TRACKING_PASSWORD") or os.environ.get("MLFLOW_TRACKING_TOKEN") or login_user()):
        return
    if not _insecure_allowed:
        raise TrackingError(
            f"--tracking-uri {shown(uri)} is plain HTTP to another machine: the MLflow login would cross the "
            "network in clear; use https:// (a reverse proxy ending TLS in front of the server: docs/cluster.md, "
            "TLS), or on a network you trust add --allow-insecure-http (allow_insecure_http=True in Python)",
            exit_code=2,
        )
    _warned_insecure.add(uri)
    sys.stderr.write(
        f"warning: {shown(uri)} is plain HTTP to another machine: the MLflow login crosses the network in "
        "clear (--allow-insecure-http); put the server behind HTTPS (docs/cluster.md, TLS)\n"
    )


def store_key(uri: str) -> str:
    """One spelling per store, for the launch lock: scheme and host in lower case, the default port, no
    login or trailing ``/``, ``localhost`` as ``127.0.0.1``, a database's driver dropped, an SQLite file's path
    resolved; so ``http://127.0.0.1:5050`` and ``http://127.0.0.1:5050/`` are one store."""
    db = sqlite_path(uri)
    if db is not None:
        return f"sqlite:///{db.resolve()}"
    parsed = urlparse(without_userinfo(encoded_uri(uri)))
    scheme = parsed.scheme.lower().split("+", 1)[0]
    if not parsed.netloc:
        return f"{scheme}:{Path(parsed.path).resolve()}" if scheme in ("", "file") else uri
    host = (parsed.hostname or "").lower()
    host = "127.0.0.1" if host == "localhost" else host
    default = {"http": 80, "https": 443, "postgresql": 5432, "mysql": 3306, "mssql": 1433}.get(scheme)
    try:
        port = parsed.port or default
    except ValueError:
        port = default
    return f"{scheme}://{host}:{port}{parsed.path.rstrip('/')}"


def lock_file(uri: str, safe_name: str) -> Path:
    """The file that lets one launch at a time run experiment ``safe_name`` (a storage name: ASCII letters,
    digits, '-' and '_') on the store ``uri``: beside an SQLite file; for a server or a database, in this
    user's cache, keyed on the store's one spelling (``store_key``), serialising this machine's launches."""
    db = sqlite_path(uri)
    if db is not None:
        return db.with_name(f"{db.name}.{safe_name}.lock")
    digest = hashlib.sha1(store_key(uri).encode()).hexdigest()[:12]
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "ablate" / "locks" / f"{digest}-{safe_name}.lock"


def check_uri(uri: str) -> None:
    if _HOST_PORT.match(uri):
        raise TrackingError(
            f"--tracking-uri {shown(uri)}: unknown scheme (none given); valid: http://{shown(uri)} for a tracking "
            "server, sqlite:///path/to/mlflow.db, or another MLflow store URI (file, postgresql, mysql)",
            exit_code=2,
        )
    parsed = urlparse(encoded_uri(uri))
    try:
        parsed.port  # noqa: B018 - raises on a port that is not a number
    except ValueError:
        raise TrackingError(
            f"--tracking-uri {shown(uri)}: the port is not a number; valid: scheme://host:port "
            "(percent-encode '/', '@' or ':' in a user or password: %2F, %40, %3A)",
            exit_code=2,
        ) from None
    scheme = parsed.scheme
    if scheme and scheme not in SCHEMES and not is_database(uri):
        raise TrackingError(
            f"--tracking-uri {shown(uri)}: unknown scheme {scheme!r}; valid: sqlite:///path/to/mlflow.db, "
            "http(s)://host:port of a tracking server, or another MLflow store URI (file, postgresql, mysql)",
            exit_code=2,
        )


def check_sqlite(path: Path, write: bool) -> None:
    """Fail in a line, before MLflow tries (and retries) to use a file that cannot work as a store."""
    folder = path.parent.resolve()
    if not path.exists():
        if not folder.is_dir():
            raise TrackingError(f"MLflow store {path}: folder {folder} does not exist; create it or choose another")
        if not write:
            raise TrackingError(f"MLflow store {path}: no such file; `ablate run` creates it")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise TrackingError(f"MLflow store {path}: folder {folder} is read-only; cannot create the store there")
        return
    if not path.is_file():
        raise TrackingError(f"MLflow store {path}: not a file")
    if not os.access(path, os.R_OK):
        raise TrackingError(f"MLflow store {path}: not readable by this user")
    if write and not (os.access(path, os.W_OK) and os.access(folder, os.W_OK | os.X_OK)):
        what = "file" if not os.access(path, os.W_OK) else f"folder {folder}"
        raise TrackingError(
            f"MLflow store {path}: the {what} is read-only (SQLite writes a journal beside the file); "
            "make it writable or point --tracking-uri at a writable store"
        )
    size = path.stat().st_size
    if size == 0:
        return  # SQLite treats an empty file as a new database
    with path.open("rb") as file:
        header = file.read(100)
    if not header.startswith(SQLITE_MAGIC):
        raise TrackingError(
            f"MLflow store {path}: not an SQLite database (corrupt or another file); move it away to start a new "
            "store, or point --tracking-uri at the right one"
        )
    # The header records the page size and the page count: a shorter file was truncated (an interrupted copy).
    page_size = int.from_bytes(header[16:18], "big") if len(header) >= 18 else 0
    page_size = 65536 if page_size == 1 else page_size
    pages = int.from_bytes(header[28:32], "big") if len(header) >= 32 else 0
    if len(header) < 100 or (page_size and pages and size < page_size * pages):
        raise TrackingError(
            f"MLflow store {path}: truncated ({size:,} of {page_size * pages:,} bytes); restore it from a copy "
            "or move it away to start a new store"
        )


@contextlib.contextmanager
def store_setup_lock(path: Path | None) -> Iterator[None]:
    """Serialises the first use of an SQLite store across processes: two launches in a fresh folder would
    otherwise both run MLflow's schema migrations and one would die in them. A lock on the folder itself,
    so no file is left behind; the kernel releases it if the process dies."""
    if path is None:
        yield
        return
    fd = os.open(path.parent.resolve(), os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


_downloads: list[Path] = []


def download_folder() -> Path:
    """A new empty folder for one downloaded artifact, inside this process's one ``ablate-artifact-*`` folder
    of the system's temporary folder, which is removed when the process ends (every ``ablate report`` left
    6-7 of them behind)."""
    import atexit
    import shutil
    import tempfile

    if not _downloads:
        _downloads.append(Path(tempfile.mkdtemp(prefix="ablate-artifact-")))
        atexit.register(shutil.rmtree, _downloads[0], True)
    return Path(tempfile.mkdtemp(dir=_downloads[0]))


@contextlib.contextmanager
def fail_fast_http() -> Iterator[None]:
    names = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0", "MLFLOW_HTTP_REQUEST_TIMEOUT": str(ANSWER_TIMEOUT_S)}
    saved = {name: os.environ.get(name) for name in names}
    os.environ.update(names)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def first_line(error: BaseException) -> str:
    """The error's first line as messages show it: masked (``secrets.shown``), then cut to 300 characters."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return shown(lines[0] if lines else type(error).__name__)[:300]


def is_database(uri: str) -> bool:
    """Whether ``uri`` names an SQL server (PostgreSQL, MySQL, SQL Server) rather than a file or a server."""
    return urlparse(uri).scheme.split("+", 1)[0] in DATABASE_SCHEMES


def probe_database(uri: str) -> None:
    """One connection to the database of ``uri`` within ``PROBE_TIMEOUT_S``, else a one-line ``TrackingError``:
    MLflow's own store retries a refused connection for minutes, printing SQLAlchemy's warnings."""
    import sqlalchemy
    from sqlalchemy.pool import NullPool

    where = shown(uri)
    url = sqlalchemy.engine.make_url(uri)
    backend = url.get_backend_name()
    connect_args = {"connect_timeout": PROBE_TIMEOUT_S} if backend in ("postgresql", "mysql") else {}
    try:
        engine = sqlalchemy.create_engine(url, connect_args=connect_args, poolclass=NullPool)
    except ImportError as error:  # the URL's driver (psycopg, pymysql) is not installed
        extra = {"postgresql": "postgres", "mysql": "mysql"}.get(backend, backend)
        raise TrackingError(
            f"MLflow store {where}: no driver for {url.drivername} ({first_line(error)}); pip install -e '.[{extra}]'"
        ) from None
    problem = None
    try:
        with engine.connect():
            pass
    except sqlalchemy.exc.SQLAlchemyError as error:
        problem = _database_problem(where, getattr(error, "orig", None) or error, url)
    finally:
        engine.dispose()
    if problem:  # raised outside the except: one line, not the chain of exceptions behind it
        raise TrackingError(problem)


def _database_problem(where: str, error: BaseException, url) -> str:
    full = str(error).lower()
    text = first_line(error)
    if "password" in full or "access denied" in full or "authentication" in full or "login failed" in full:
        where = "PGPASSWORD, a ~/.pgpass line or PGPASSFILE" if url.get_backend_name() == "postgresql" else "MYSQL_PWD"
        return (
            f"MLflow store {where}: the database refused the login of user {url.username!r} ({text}); "
            f"check the user and give the password through {where}, not the command line"
        )
    if "does not exist" in full or "unknown database" in full:
        return f"MLflow store {where}: database {url.database!r} does not exist ({text}); create it, or fix the URI"
    if "timeout" in full or "timed out" in full:
        return f"MLflow store {where}: no answer in {PROBE_TIMEOUT_S} s ({text}); start the database or fix the URI"
    return f"MLflow store {where} cannot be reached ({text}); start the database or fix the URI"


def probe_server(uri: str) -> None:
    """A TCP connection to the tracking server of an ``http(s)://`` ``uri`` within ``PROBE_TIMEOUT_S``, else a
    one-line ``TrackingError``: a server that is not there is told in seconds, however long one that is there
    may take to answer (``ANSWER_TIMEOUT_S``)."""
    parsed = urlparse(uri)
    port = parsed.port or (443 if parsed.scheme == "https" else 80)
    try:
        socket.create_connection((parsed.hostname or "", port), timeout=PROBE_TIMEOUT_S).close()
    except OSError as error:
        raise TrackingError(store_problem(uri, error)) from None


def store_problem(uri: str, error: BaseException) -> str:
    """One line saying why the store at ``uri`` could not be opened, and what to set or start; the password
    of the URI and every secret of this process masked."""
    where, text, full = shown(uri), first_line(error), str(error).lower()
    if not uri.startswith(("http://", "https://")):
        return f"MLflow store {where} cannot be used: {text}"
    status = getattr(error, "get_http_status_code", lambda: None)()
    if status == 401 or "401" in full and "authenticat" in full:
        user = login_user()
        if user:
            return (
                f"MLflow tracking server {where} refused the login of {user!r} (HTTP 401): wrong password, or no "
                "such account; check MLFLOW_TRACKING_PASSWORD (or ~/.mlflow/credentials) against your account on it"
            )
        return (
            f"MLflow tracking server {where} needs a login (HTTP 401); set MLFLOW_TRACKING_USERNAME and "
            "MLFLOW_TRACKING_PASSWORD (or the [mlflow] section of ~/.mlflow/credentials) to your account on it"
        )
    if "invalid host header" in full or "dns rebinding" in full:
        host = urlparse(uri).hostname
        return (
            f"MLflow tracking server {where} refused the Host header {host!r} (HTTP 403, its DNS-rebinding guard): "
            f"start the server with --allowed-hosts naming {host!r}, or use the host name it allows"
        )
    if status == 403 or "403" in full and "permission" in full:
        user = login_user() or "this user"
        return f"MLflow tracking server {where}: {user!r} may not do this (HTTP 403, {text}); ask its admin for EDIT"
    reason = text
    if "refused" in full:
        reason = "connection refused"
    elif "timed out" in full or "timeout" in full:
        reason = f"no answer in {PROBE_TIMEOUT_S} s"
    elif isinstance(error, socket.gaierror) or "name or service not known" in full or "nodename nor servname" in full:
        reason = "unknown host"
    return f"MLflow tracking server {where} is unreachable ({reason}); start it or check --tracking-uri"
