"""Stores that cannot be used fail in one line and seconds, and no password or token is shown or recorded:
URI masking, redaction of what the writer records, and the refusals of `ablate run`, `status` and `report`."""

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ablate.launch.secrets import mask_uri
from ablate.launch.secrets import shown as redact
from ablate.launch.store import TrackingError
from ablate.launch.tracking import Tracker
from ablate.reporting.reader import RunReader, ablation_names

SECRET = "Planted-S3cret-pw"
ROOT = Path(__file__).resolve().parent.parent


def _closed_port() -> int:
    """A loopback port nothing listens on: a connection to it is refused at once."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(
    ("uri", "shown"),
    [
        (
            "postgresql+psycopg://mlflow:pw@127.0.0.1:5432/mlflow",
            "postgresql+psycopg://mlflow:***@127.0.0.1:5432/mlflow",
        ),
        ("mysql+pymysql://u:p%40ss@db.example:3306/m", "mysql+pymysql://u:***@db.example:3306/m"),
        ("https://alice:hunter22@mlflow.example", "https://alice:***@mlflow.example"),
        ("http://127.0.0.1:5000", "http://127.0.0.1:5000"),
        ("sqlite:///mlflow.db", "sqlite:///mlflow.db"),
        ("postgresql://mlflow@127.0.0.1/mlflow", "postgresql://mlflow@127.0.0.1/mlflow"),  # no password to mask
    ],
)
def test_a_uri_is_shown_with_its_password_masked(uri, shown):
    assert mask_uri(uri) == shown
    assert mask_uri(f"ablate run x.toml --tracking-uri {uri} --fresh") == (
        f"ablate run x.toml --tracking-uri {shown} --fresh"
    )


def test_redact_masks_the_secrets_this_process_holds(monkeypatch, tmp_path):
    token = tmp_path / "token"
    token.write_text("raytoken-0123456789\n")
    monkeypatch.setenv("MLFLOW_TRACKING_PASSWORD", SECRET)
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(token))
    text = redact(f"login {SECRET} failed; token raytoken-0123456789; url http://u:{SECRET}@h")
    assert SECRET not in text and "raytoken-0123456789" not in text and text.count("***") == 3


def test_what_the_writer_records_has_no_password_or_token(tracking_uri, monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_PASSWORD", SECRET)
    tracker = Tracker(tracking_uri, "secrets")
    command = f"ablate run x.toml --tracking-uri postgresql+psycopg://mlflow:{SECRET}x@127.0.0.1/mlflow"
    launch = tracker.start_launch("g", "launch", {"ablate.command": command}, {"environment.json": f'"{SECRET}"'})
    tracker.start_trial(launch, "g", "t-s0-abc", "t", 0, {"seed": 0}, "commit")
    tracker.fail_trial("t-s0-abc", f"the store said: password {SECRET} refused")
    tracker.finish_launch(launch, "FAILED", {}, note=f"failed with {SECRET}")
    reader = RunReader(tracking_uri, "secrets")
    (recorded,) = reader.launches()
    assert (
        recorded.data.tags["ablate.command"]
        == "ablate run x.toml --tracking-uri postgresql+psycopg://mlflow:***@127.0.0.1/mlflow"
    )
    assert SECRET not in reader.load_text(launch, "environment.json")
    runs = reader.client.search_runs([reader.experiment_id()])
    for run in runs:
        assert not [k for k, v in {**run.data.tags, **run.data.params}.items() if SECRET in v]


@pytest.mark.parametrize("scheme", ["postgresql+psycopg", "mysql+pymysql"])
def test_an_unreachable_database_is_one_line_in_seconds_with_the_password_masked(scheme, tmp_path):
    uri = f"{scheme}://mlflow:{SECRET}@127.0.0.1:{_closed_port()}/mlflow"
    with pytest.raises(TrackingError):  # once first: the imports (SQLAlchemy, the driver) are not the bound's
        Tracker(uri, "x")
    openers = (lambda: Tracker(uri, "x"), lambda: RunReader(uri, "x", write=False), lambda: ablation_names(uri))
    for open_store in openers:
        started = time.monotonic()
        with pytest.raises(TrackingError) as error:
            open_store()
        assert time.monotonic() - started < 10  # MLflow's own store retries a refused connection for minutes
        message = str(error.value)
        assert "\n" not in message and SECRET not in message and "mlflow:***@127.0.0.1" in message, message
        assert "cannot be reached" in message


def _cli(*args, cwd, env=None, timeout=120):
    env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "ablate.cli", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    return done, time.monotonic() - started


def _main_in(folder, monkeypatch, capsys, argv):
    """``ablate ARGV`` in this process, run from ``folder``: its exit code, seconds, stdout and stderr."""
    from ablate.cli import main

    monkeypatch.chdir(folder)
    started = time.monotonic()
    code = main(argv)
    wall_s = time.monotonic() - started
    out, err = capsys.readouterr()
    return code, wall_s, out, err


@pytest.mark.parametrize("command", ["run", "status", "report"])
def test_every_command_refuses_an_unreachable_postgresql_store_in_one_line(command, tmp_path, monkeypatch, capsys):
    uri = f"postgresql+psycopg://mlflow:{SECRET}@127.0.0.1:{_closed_port()}/mlflow"
    args = {"run": ["run", str(ROOT / "experiments" / "smoke.toml")], "status": ["status"]}
    args["report"] = ["report", "smoke"]
    if command == "run":  # the whole console command once, imports and all
        done, wall_s = _cli(*args[command], "--tracking-uri", uri, cwd=tmp_path)
        code, out, err = done.returncode, done.stdout, done.stderr
    else:  # the same path in this process: seconds of imports fewer
        code, wall_s, out, err = _main_in(tmp_path, monkeypatch, capsys, [*args[command], "--tracking-uri", uri])
    errors = err.strip().splitlines()
    assert code == 1 and len(errors) == 1, out + err
    assert f"ablate {command}: MLflow store postgresql+psycopg://mlflow:***@127.0.0.1" in errors[0]
    assert SECRET not in out + err
    assert not list(tmp_path.iterdir())  # nothing tracked, nothing written
    # MLflow's retries took over 100 s; the bound leaves room for a busy machine's imports (~20 s here)
    assert wall_s < 60, wall_s


def test_status_refuses_an_unreachable_tracking_server_in_one_line(tmp_path):
    done, wall_s = _cli("status", "--tracking-uri", f"http://127.0.0.1:{_closed_port()}", cwd=tmp_path)
    assert done.returncode == 1 and len(done.stderr.strip().splitlines()) == 1, done.stdout + done.stderr
    assert "is unreachable (connection refused)" in done.stderr
    assert wall_s < 60, wall_s  # it waited past 60 s before


class _FlakyClient:
    """An MlflowClient whose store stopped answering after ``good`` calls."""

    def __init__(self, good: int) -> None:
        self.calls, self.good = 0, good

    def set_tag(self, run_id: str, key: str, value: str) -> str:
        self.calls += 1
        if self.calls > self.good:
            raise ConnectionError(f"connection to postgresql://mlflow:{SECRET}@127.0.0.1/mlflow refused")
        return "ok"

    def bad_input(self) -> None:
        raise ValueError("not a store problem")


def test_a_store_that_goes_away_is_retried_for_a_bounded_time_then_stops_the_launch_in_one_line(monkeypatch):
    from ablate.launch import store_writes as store

    monkeypatch.setattr(store, "STORE_RETRY_S", 0.5)
    monkeypatch.setattr(store.time, "sleep", lambda s: None)
    flaky = _FlakyClient(good=1)
    client = store.RetryingClient(flaky, "postgresql://mlflow:***@db/mlflow")
    assert client.set_tag("r", "k", "v") == "ok"
    started = time.monotonic()
    with pytest.raises(TrackingError) as error:
        client.set_tag("r", "k", "v")
    assert time.monotonic() - started < 5 and flaky.calls > 2  # retried, within the bound
    message = str(error.value)
    assert "stopped answering" in message and "\n" not in message and SECRET not in message
    calls = flaky.calls
    with pytest.raises(TrackingError):  # gone: every later write fails at once, without retrying
        client.set_tag("r", "k", "v")
    assert flaky.calls == calls
    with pytest.raises(ValueError):  # not the store's absence: passed through
        store.RetryingClient(_FlakyClient(good=0), "x").bad_input()


def test_downloaded_artifacts_leave_nothing_in_the_temporary_folder_once_the_process_ends(tmp_path):
    script = (
        "from ablate.launch.store import download_folder\n"
        "a, b = download_folder(), download_folder()\n"
        "assert a != b and a.parent == b.parent and a.parent.name.startswith('ablate-artifact-')\n"
        "(a / 'episodes.csv').write_text('x')\nprint(a.parent)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "TMPDIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()).parent == tmp_path and not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ("API request to endpoint /x failed with error code 403 != 200. Response body: 'Permission denied'", "auth"),
        ("API request to endpoint /x failed with error code 401 != 200. Response body: 'Unauthorized'", "auth"),
        ("PermissionError: [Errno 13] Permission denied: '/srv/mlflow/artifacts/1'", "permission"),
        ("sqlite3.OperationalError: attempt to write a readonly database", "permission"),
        ("sqlalchemy.exc.OperationalError: (sqlite3.OperationalError) database is locked", "lost"),  # SQL: retried
        ("OSError: [Errno 28] No space left on device", "disk"),
        ("500 Server Error: Internal Server Error for url: http://h/api. Response text: Internal Server Error", "5xx"),
        ("HTTPConnectionPool(host='h', port=1): Max retries exceeded (Caused by NewConnectionError)", "lost"),
        ("ValueError: not a store problem", ""),
    ],
)
def test_a_failed_write_is_told_as_the_store_answered_it(text, kind):
    from ablate.launch.store_writes import store_fault

    assert store_fault(RuntimeError(text))[0] == kind


def test_a_store_answering_errors_is_named_at_once_or_after_the_bound_and_can_still_close_the_launch(monkeypatch):
    from ablate.launch import store_writes as store

    monkeypatch.setattr(store, "STORE_RETRY_S", 0.2)
    monkeypatch.setattr(store.time, "sleep", lambda s: None)

    class Answering:
        calls = 0

        def log_text(self, error):
            self.calls += 1
            raise RuntimeError(error)

        def set_terminated(self):
            return "closed"

    answering = Answering()
    client = store.RetryingClient(answering, "http://h:5000")
    with pytest.raises(TrackingError, match="refused a write: the server's disk is full") as error:
        client.log_text("OSError: [Errno 28] No space left on device")
    assert answering.calls == 1 and "\n" not in str(error.value)  # at once: it would answer the same again
    with pytest.raises(TrackingError, match="answered every try of a write with a server error for 0 s"):
        client.log_text("500 Server Error: Internal Server Error for url: http://h/x")
    assert answering.calls > 2 and client.set_terminated() == "closed"  # retried, and the store still usable


def test_a_store_answering_errors_is_never_called_lost_when_its_deadline_passes_between_two_looks(monkeypatch):
    """The retry loop read the clock twice: a deadline passing between the reads called a store that answers 500
    'stopped answering' (seen once in CI). A clock that ticks on every read makes that moment certain."""
    import itertools

    from ablate.launch import store_writes as store

    monkeypatch.setattr(store, "STORE_RETRY_S", 1.5)
    monkeypatch.setattr(store.time, "sleep", lambda s: None)
    monkeypatch.setattr(store.time, "monotonic", itertools.count().__next__)

    class Answering:
        def log_text(self, error):
            raise RuntimeError(error)

    client = store.RetryingClient(Answering(), "http://h:5000")
    with pytest.raises(TrackingError, match="answered every try of a write with a server error"):
        client.log_text("500 Server Error: Internal Server Error for url: http://h/x")


def test_a_password_in_a_database_uris_query_is_masked_in_the_refusal(tmp_path, monkeypatch, capsys):
    from ablate.cli import main

    monkeypatch.chdir(tmp_path)
    uri = f"postgresql+psycopg://mlflow@127.0.0.1:{_closed_port()}/mlflow?password={SECRET}&sslpassword={SECRET}2"
    assert main(["status", "--tracking-uri", uri]) == 1
    out, err = capsys.readouterr()
    assert SECRET not in out + err and "password=***&sslpassword=***" in err, err


@pytest.mark.parametrize("command", ["run", "status", "report"])
@pytest.mark.parametrize("login", ["uri", "environment"])
def test_every_command_refuses_a_login_over_plain_http_to_another_machine_in_one_line(
    command, login, tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr("ablate.launch.store._warned_insecure", set())
    monkeypatch.setenv("MLFLOW_TRACKING_USERNAME", "alice")  # open_uri moves a URI's login here: restored after
    monkeypatch.setenv("MLFLOW_TRACKING_PASSWORD", "" if login == "uri" else SECRET)
    host = "192.0.2.7:5000"  # TEST-NET-1: never routed, so a request that went out would hang, not be refused
    uri = f"http://alice:{SECRET}@{host}" if login == "uri" else f"http://{host}"
    args = {
        "run": ["run", str(ROOT / "experiments" / "smoke.toml")],
        "status": ["status"],
        "report": ["report", "smoke"],
    }
    code, wall_s, out, err = _main_in(tmp_path, monkeypatch, capsys, [*args[command], "--tracking-uri", uri])
    errors = err.strip().splitlines()
    assert code == 2 and len(errors) == 1, out + err
    assert f"ablate {command}: --tracking-uri http://" in errors[0] and "is plain HTTP to another machine" in errors[0]
    assert "https://" in errors[0] and "--allow-insecure-http" in errors[0] and "docs/cluster.md" in errors[0]
    assert SECRET not in out + err
    assert not list(tmp_path.iterdir())  # nothing tracked, nothing written
    assert wall_s < 30, wall_s  # refused before any connection


def test_allow_insecure_http_warns_once_and_goes_on_to_the_server(tmp_path, monkeypatch, capsys):
    from ablate.cli import main

    def reached(uri: str) -> None:
        raise TrackingError(f"reached {uri}")

    monkeypatch.setattr("ablate.launch.store._warned_insecure", set())
    monkeypatch.setattr("ablate.launch.mlflow_store.probe_server", reached)
    monkeypatch.setenv("MLFLOW_TRACKING_USERNAME", "alice")
    monkeypatch.setenv("MLFLOW_TRACKING_PASSWORD", SECRET)
    monkeypatch.chdir(tmp_path)
    code = main(["status", "--tracking-uri", "http://192.0.2.7:5000", "--allow-insecure-http"])
    out, err = capsys.readouterr()
    assert code == 1 and "reached http://192.0.2.7:5000" in err, out + err
    assert err.count("warning:") == 1 and "plain HTTP" in err and "--allow-insecure-http" in err
    assert SECRET not in out + err


def test_status_lists_ablations_beside_a_deleted_mlflow_experiment_of_any_name(tmp_path):
    """``ablate status`` opens the store alone: a deleted experiment (here one named ``ablate``) is not its
    business."""
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = MlflowClient(uri)
    client.delete_experiment(client.create_experiment("ablate"))
    assert ablation_names(uri) == []


def test_status_refuses_a_store_that_refuses_its_first_read_in_one_line(tmp_path, monkeypatch):
    """A server that refuses the login (as a basic-auth server refuses no credentials) answers the first read
    ``Store`` makes: ``ablate status`` says so in one line, as the writer's opening does."""
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    def refused(self, *args, **kwargs):
        raise MlflowException("API request failed with error code 401 != 200. Response body: 'unauthenticated'")

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    MlflowClient(uri).create_experiment("x")  # the store exists
    monkeypatch.setattr(MlflowClient, "search_experiments", refused)
    with pytest.raises(TrackingError, match="401") as raised:
        ablation_names(uri)
    assert "\n" not in str(raised.value)
