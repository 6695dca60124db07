"""No secret in a report (issue 36 item 5): a password planted in ``--tracking-uri`` reaches no file under the
report folder, no artifact attached to the launch run and no line the commands print. The tracking server is a
local SQLite store behind the one seam every store is opened through (``open_uri``): everything above it (the
CLI, the commands it records, the report) sees the planted URI, password included."""

import json
from pathlib import Path

import pytest
from test_report import make_store, rising

from ablate.cli import main
from ablate.launch import secrets, store
from ablate.launch.secrets import Shown, shown_command
from ablate.reporting.provenance import _reproducibility

PASSWORD = "Planted-pw-36"
PLANTED = f"http://alice:{PASSWORD}@127.0.0.1:5999"


@pytest.fixture
def server(tmp_path, monkeypatch):
    """``PLANTED`` answered by a synthetic SQLite store: the real ``open_uri`` sees (and remembers) the URI, then
    MLflow is given the local store instead of a server."""
    monkeypatch.setattr(secrets, "_remembered", set())
    for name in ("MLFLOW_TRACKING_USERNAME", "MLFLOW_TRACKING_PASSWORD", "MLFLOW_TRACKING_URI"):
        monkeypatch.setenv(name, "")  # open_uri moves the login there: restored after the test
    uri = make_store(tmp_path / "store", "secret", {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 12)}})
    real = store.open_uri

    def open_uri(given: str) -> str:
        real(given)
        return uri if given.startswith("http://alice:") else given

    monkeypatch.setattr("ablate.launch.mlflow_store.open_uri", open_uri)  # the reader's Store opens through it too
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test")
    monkeypatch.chdir(tmp_path)
    return uri


def _files_holding(folder: Path, text: str) -> list[str]:
    return [str(p) for p in folder.rglob("*") if p.is_file() and text.encode() in p.read_bytes()]


def test_a_password_in_the_tracking_uri_reaches_no_report_file_artifact_or_output(server, tmp_path, capsys):
    assert main(["report", "secret", "--tracking-uri", PLANTED, "--no-pdf"]) == 0
    assert main(["status", "--tracking-uri", PLANTED]) == 0
    assert main(["status", "secret", "--tracking-uri", PLANTED]) == 0
    out = capsys.readouterr()
    assert PASSWORD not in out.out + out.err
    folder = tmp_path / "reports" / "secret"
    assert _files_holding(folder, PASSWORD) == []
    text = (folder / "report.md").read_text()
    assert "ablate report secret --tracking-uri http://alice:***@127.0.0.1:5999 --no-pdf" in text  # the record
    attached = list((tmp_path / "store").rglob("report.md"))  # the report as the launch run's artifact
    assert attached and _files_holding(tmp_path / "store", PASSWORD) == []


def test_every_command_a_report_or_a_launch_records_is_masked(server):
    """The command lines of ``ablate run``, ``report``, ``calibrate``, ``status`` and ``train --from`` as
    recorded: one function builds them, and the report's provenance refuses any other text."""
    for command in ("run", "report", "status", "calibrate", "train"):
        words = ["ablate", command, "experiments/x.toml", "--tracking-uri", PLANTED, "--from", "x.toml"]
        recorded = shown_command(words)
        assert isinstance(recorded, Shown) and PASSWORD not in recorded and "alice:***@127.0.0.1" in recorded
    secrets.remember(PASSWORD)  # a password seen once is masked in any word, not only inside a URI
    assert PASSWORD not in shown_command(["ablate", "run", f"--password={PASSWORD}", PASSWORD])
    ablation = json.loads('{"launch": {"tags": {}, "environment": {}, "run_id": "r"}}')
    with pytest.raises(TypeError, match="masked command"):
        _reproducibility(type("A", (), {"launch": ablation["launch"]})(), f"ablate report --tracking-uri {PLANTED}")
