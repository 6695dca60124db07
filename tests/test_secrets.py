"""The shown form of URIs, command lines and messages: every spelling of a password masked, nothing else."""

import io
import sys

import pytest

from ablate.launch import secrets
from ablate.launch.secrets import MaskedStream, encoded_uri, mask_uri, remember, shown, split_userinfo
from ablate.launch.store import TrackingError, check_uri, insecure_http, open_uri, store_key

PW = "Pl@nted/pw:9x"


@pytest.fixture(autouse=True)
def _forget(monkeypatch):
    monkeypatch.setattr(secrets, "_remembered", set())
    for name in (*secrets.SECRET_ENV, "MLFLOW_TRACKING_USERNAME", "MLFLOW_TRACKING_URI", "RAY_AUTH_TOKEN_PATH"):
        monkeypatch.delenv(name, raising=False)


@pytest.mark.parametrize(
    ("uri", "shown_form"),
    [
        (f"http://alice:{PW}@127.0.0.1:5050", "http://alice:***@127.0.0.1:5050"),  # raw '@', '/', ':'
        ("http://alice:Pl%40nted%2Fpw%3A9x@127.0.0.1:5050/", "http://alice:***@127.0.0.1:5050/"),
        ("https://a@b.example:hunter22@mlflow.example", "https://a@b.example:***@mlflow.example"),
        (
            "postgresql+psycopg://mlflow@db:5432/mlflow?sslmode=require&password=hunter22&sslpassword=k3y",
            "postgresql+psycopg://mlflow@db:5432/mlflow?sslmode=require&password=***&sslpassword=***",
        ),
        ("databricks://x?token=dapi0123&x=1", "databricks://x?token=***&x=1"),
        ("sqlite:////home/a@b/mlflow.db", "sqlite:////home/a@b/mlflow.db"),  # no authority, nothing to mask
        ("postgresql://mlflow@127.0.0.1/mlflow", "postgresql://mlflow@127.0.0.1/mlflow"),
    ],
)
def test_every_uri_form_is_masked_up_to_the_last_at_and_in_its_query(uri, shown_form):
    assert mask_uri(uri) == shown_form
    assert (
        mask_uri(f"ablate run x.toml --tracking-uri {uri} --fresh")
        == f"ablate run x.toml --tracking-uri {shown_form} --fresh"
    )


def test_a_raw_slash_at_or_colon_in_a_password_is_read_as_the_password():
    assert split_userinfo(f"http://alice:{PW}@h:5050/x") == ("http://", "alice", PW, "h:5050/x")
    assert encoded_uri(f"http://alice:{PW}@h:5050") == "http://alice:Pl%40nted%2Fpw%3A9x@h:5050"
    check_uri(f"http://alice:{PW}@h:5050")  # no "Port could not be cast"


def test_a_password_once_seen_is_masked_in_any_spelling_and_free_text(monkeypatch):
    open_uri(f"http://alice:{PW}@127.0.0.1:5050")
    for text in (PW, "Pl%40nted%2Fpw%3A9x", f"the server said {PW!r}"):
        assert PW not in shown(text) and "Pl%40nted" not in shown(text), text
    monkeypatch.setenv("MLFLOW_TRACKING_TOKEN", "tok-0123456789")
    assert shown("Bearer tok-0123456789") == "Bearer ***"
    assert shown("password=abc sslpassword='x' MLFLOW_TRACKING_PASSWORD=zz") == (
        "password=*** sslpassword=*** MLFLOW_TRACKING_PASSWORD=***"
    )
    remember("ab")  # too short to replace in free text
    assert shown("about") == "about"


def test_a_servers_login_leaves_the_uri_for_the_environment(monkeypatch):
    uri = open_uri(f"http://alice:{PW}@127.0.0.1:5050/")
    assert uri == "http://127.0.0.1:5050/"
    import os

    assert os.environ["MLFLOW_TRACKING_USERNAME"] == "alice" and os.environ["MLFLOW_TRACKING_PASSWORD"] == PW


def test_plain_http_with_a_login_to_another_host_is_refused_unless_allowed_then_warned_once(monkeypatch, capsys):
    monkeypatch.setattr("ablate.launch.store._warned_insecure", set())
    for name in ("MLFLOW_TRACKING_USERNAME", "MLFLOW_TRACKING_PASSWORD"):  # open_uri moves the login there
        monkeypatch.setenv(name, "")
    with pytest.raises(TrackingError, match="is plain HTTP to another machine") as refused:
        open_uri("http://alice:hunter22@mlflow.example:5000")
    assert refused.value.exit_code == 2 and "--allow-insecure-http" in str(refused.value)
    assert "https://" in str(refused.value) and "hunter22" not in str(refused.value)
    with pytest.raises(TrackingError):
        open_uri("http://alice:hunter22@10.1.2.3:5000")
    open_uri("https://alice:hunter22@mlflow.example")
    open_uri("http://alice:hunter22@127.0.0.1:5000")
    open_uri("http://alice:hunter22@127.0.0.2:5000")  # all of 127/8 is this machine
    open_uri("http://alice:hunter22@[::1]:5000")
    assert capsys.readouterr().err == ""
    with insecure_http(True):
        open_uri("http://alice:hunter22@mlflow.example:5000")
        open_uri("http://alice:hunter22@mlflow.example:5000")
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and "plain HTTP" in err and "hunter22" not in err
    with insecure_http(True), insecure_http(False):  # the CLI's flag reaches the API calls it makes
        open_uri("http://alice:hunter22@mlflow.example:5000")
    with pytest.raises(TrackingError):  # allowed only inside
        open_uri("http://alice:hunter22@other.example:5000")


def test_plain_http_without_a_login_is_neither_refused_nor_warned(monkeypatch, capsys, tmp_path):
    for name in ("MLFLOW_TRACKING_USERNAME", "MLFLOW_TRACKING_PASSWORD", "MLFLOW_TRACKING_TOKEN"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("MLFLOW_CREDENTIALS_PATH", str(tmp_path / "none"))
    assert open_uri("http://mlflow.example:5000") == "http://mlflow.example:5000"
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("uri", ["127.0.0.1:5050", "mlflow.example:5000/x"])
def test_a_host_and_port_without_a_scheme_is_bad_input(uri):
    with pytest.raises(TrackingError, match="unknown scheme") as error:
        check_uri(uri)
    assert error.value.exit_code == 2


def test_one_store_has_one_key_however_it_is_spelled(tmp_path, monkeypatch):
    same = ["http://127.0.0.1:5050", "http://127.0.0.1:5050/", "HTTP://LOCALHOST:5050", "http://bob:pw@127.0.0.1:5050"]
    assert len({store_key(uri) for uri in same}) == 1
    assert store_key("https://h") == store_key("https://h:443/") != store_key("http://h")
    db = ["postgresql://a:x@db/mlflow", "postgresql+psycopg://b@db:5432/mlflow?sslmode=require"]
    assert store_key(db[0]) == store_key(db[1])
    monkeypatch.chdir(tmp_path)
    assert store_key("sqlite:///mlflow.db") == store_key(f"sqlite:///{tmp_path}/mlflow.db")
    assert store_key("http://127.0.0.1:5050") != store_key("http://127.0.0.1:5051")


def test_the_masked_stream_masks_what_any_library_prints(monkeypatch):
    out = io.StringIO()
    monkeypatch.setattr(sys, "stdout", MaskedStream(out))
    print("View run x at: http://alice:hunter22@h:5000/#/experiments/1")
    assert out.getvalue() == "View run x at: http://alice:***@h:5000/#/experiments/1\n"


def test_a_credentials_file_mlflow_cannot_read_masks_nothing_and_breaks_no_line(tmp_path, monkeypatch):
    """configparser reads a value's % as MLflow does: %% is one %, a lone % is an error that must not reach
    every line the CLI prints."""
    good, bad = tmp_path / "good", tmp_path / "bad"  # two files: the reader caches a file by its mtime
    good.write_text("[mlflow]\nmlflow_tracking_password = pa%%ss-Planted\n")
    bad.write_text("[mlflow]\nmlflow_tracking_password = pa%ss-Planted\n")
    monkeypatch.setenv("MLFLOW_CREDENTIALS_PATH", str(good))
    assert shown("login pa%ss-Planted failed") == "login *** failed"
    monkeypatch.setenv("MLFLOW_CREDENTIALS_PATH", str(bad))
    assert shown("login failed") == "login failed"
