"""Bad input and broken environments: every case is one line on stderr, the right exit code (2 bad input, 1 an
environment problem), no traceback, well within 30 s, and the store exactly as it was (files hashed, runs and
experiments counted). All fail before Ray starts, so they run in-process; only the read-only cases, which need
a user the file modes apply to, run as a subprocess."""

import fcntl
import hashlib
import json
import os
import shutil
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest
from stores import fresh_store

from ablate.cli import main

GOOD = """
name = "tiny"
seeds = 2
[base]
max_episodes = 10
[[variants]]
name = "baseline"
[[variants]]
name = "deep"
hidden_sizes = [16, 16]
"""


@pytest.fixture(scope="session")
def seeded_store(tmp_path_factory):
    """An MLflow store holding experiment ``tiny`` with one finished launch and trial (no Ray needed)."""
    from ablate.launch.tracking import Tracker

    folder = tmp_path_factory.mktemp("seeded")
    tracker = Tracker(fresh_store(folder / "mlflow.db"), "tiny")
    launch = tracker.start_launch("g1", "tiny launch", {}, {"grid.json": "{}"})
    tracker.start_trial(launch, "g1", "baseline-s0-x", "baseline", 0, {"seed": 0}, "abc")
    tracker.finish_trial("baseline-s0-x", {"episodes_to_solve": 5.0}, None)
    tracker.finish_launch(launch, "FINISHED", {"trials_finished": 1})
    tracker.start_launch("g2", "deleted", {}, {})
    other = Tracker(f"sqlite:///{folder / 'mlflow.db'}", "gone")
    other.client.delete_experiment(other.experiment_id())
    return folder


def _snapshot(folder: Path) -> dict:
    files = {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }
    counts = {}
    db = folder / "mlflow.db"
    if db.is_file():
        try:
            with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as connection:
                counts = {
                    t: connection.execute(f"select count(*) from {t}").fetchone()[0] for t in ("runs", "experiments")
                }
        except sqlite3.DatabaseError:
            counts = {"unreadable": 1}
    return {"files": files, "counts": counts}


def _cli(argv, capsys):
    start = time.monotonic()
    try:
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err, time.monotonic() - start


def _one_line(err: str) -> str:
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def _nested_arrays(depth: int) -> str:
    return 'name = "deep"\nx = ' + "[" * depth + "]" * depth + "\n"


def _nested_tables(depth: int) -> str:
    return 'name = "deep"\nx = ' + "{a = " * depth + "1" + "}" * depth + "\n"


BIG_GRID = "[grid]\nlearning_rate = [" + ", ".join(f"{(i + 1) / 2000}" for i in range(1000)) + "]\n"
BIG_GRID += "dropout = [" + ", ".join(f"{i / 1001}" for i in range(1000)) + "]\n"

# (id, experiment text, extra argv, exit code, a part of the message)
CONFIG_CASES = [
    ("threshold-nan", GOOD + "solve_threshold = nan\n", [], 2, "solve_threshold = nan is invalid"),
    ("threshold-inf", GOOD + "solve_threshold = inf\n", [], 2, "solve_threshold = inf is invalid"),
    ("threshold-minus-inf", GOOD + "solve_threshold = -inf\n", [], 2, "solve_threshold = -inf is invalid"),
    ("base-threshold-nan", GOOD.replace("[base]", "[base]\nsolve_threshold = nan"), [], 2, "base.solve_threshold"),
    ("grid-threshold-inf", GOOD + "[grid]\nsolve_threshold = [100.0, inf]\n", [], 2, "grid.solve_threshold = inf"),
    ("learning-rate-nan", GOOD + "learning_rate = nan\n", [], 2, "learning_rate = nan is invalid"),
    ("learning-rate-inf", GOOD + "learning_rate = inf\n", [], 2, "learning_rate = inf is invalid"),
    ("dropout-nan", GOOD + "dropout = nan\n", [], 2, "dropout = nan is invalid"),
    ("gamma-minus-inf", GOOD + "gamma = -inf\n", [], 2, "gamma = -inf is invalid"),
    ("l2-nan", GOOD + "l2 = nan\n", [], 2, "l2 = nan is invalid"),
    ("cpus-nan", "cpus_per_trial = nan\n" + GOOD, [], 2, "cpus_per_trial = nan is invalid"),
    ("cpus-zero", "cpus_per_trial = 0\n" + GOOD, [], 2, "cpus_per_trial = 0 is invalid"),
    (
        "cpus-more-than-machine",
        f"cpus_per_trial = {(os.cpu_count() or 1) + 1}\n" + GOOD,
        [],
        2,
        f"is more than this machine's {os.cpu_count()} CPUs",
    ),
    ("slug-clash-space", GOOD + '[[variants]]\nname = "a b"\n[[variants]]\nname = "a_b"\n', [], 2, "'a b' and 'a_b'"),
    ("slug-clash-edge", GOOD + '[[variants]]\nname = "x"\n[[variants]]\nname = "_x_"\n', [], 2, "'x' and '_x_'"),
    ("slug-clash-symbols", GOOD + '[[variants]]\nname = "a/b"\n[[variants]]\nname = "a:b"\n', [], 2, "share"),
    ("name-300", GOOD.replace('"tiny"', '"' + "n" * 300 + '"'), [], 2, "(300 characters); valid: 1 to 100 characters"),
    ("name-101", GOOD.replace('"tiny"', '"' + "n" * 101 + '"'), [], 2, "(101 characters)"),
    ("variant-name-300", GOOD.replace('"deep"', '"' + "v" * 300 + '"'), [], 2, "at most 200 characters"),
    ("name-path", GOOD.replace('"tiny"', '"../../etc"'), [], 2, "name = '../../etc' is invalid"),
    ("name-empty", GOOD.replace('"tiny"', '""'), [], 2, "name = '' is invalid"),
    # Names in any script are valid (issue 18); a control character is not.
    ("name-control", GOOD.replace('"tiny"', '"caf\\u0007"'), [], 2, "(a control or unassigned character); valid"),
    ("nested-arrays-100k", _nested_arrays(100_000), [], 2, "nested too deeply"),
    ("nested-tables-100k", _nested_tables(100_000), [], 2, "nested too deeply"),
    ("grid-million", 'name = "big"\n' + BIG_GRID, [], 2, "1000 learning_rate x 1000 dropout x 5 seeds is 5,000,000"),
    ("grid-seeds-over-cap", GOOD + "[grid]\ndepth = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n", [], None, None),
    ("seeds-zero", GOOD.replace("seeds = 2", "seeds = 0"), [], 2, "seeds = 0 is invalid"),
    ("seeds-duplicate", GOOD.replace("seeds = 2", "seeds = [1, 1]"), [], 2, "seeds = [1, 1] is invalid"),
    ("grid-empty-axis", GOOD + "[grid]\ndepth = []\n", [], 2, "grid.depth = [] is invalid"),
    ("max-episodes-float", GOOD + "max_episodes = 1e9\n", [], 2, "max_episodes = 1000000000.0 is invalid"),
    ("bom-then-bad-toml", "\ufeffname = 'x'\n[base\n", [], 2, "not valid TOML"),
    ("binary-file", None, [], 2, "not a UTF-8 text file"),
    ("empty-file", "", [], 2, "the grid is empty"),
    ("max-concurrent-negative", GOOD, ["--max-concurrent", "-3"], 2, "--max-concurrent = -3 is invalid"),
]
# A 10-variant grid x 2 seeds is fine; make the seeds count push it over the cap instead.
CONFIG_CASES[[c[0] for c in CONFIG_CASES].index("grid-seeds-over-cap")] = (
    "grid-seeds-over-cap",
    GOOD.replace("seeds = 2", "seeds = 1000") + "[grid]\ndepth = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n",
    [],
    2,
    "is 12,000 trials; valid: at most 10,000",
)


@pytest.mark.parametrize(
    ("text", "argv", "code", "message"), [c[1:] for c in CONFIG_CASES], ids=[c[0] for c in CONFIG_CASES]
)
def test_bad_experiment_is_one_line_and_leaves_the_store(
    tmp_path, seeded_store, capsys, monkeypatch, text, argv, code, message
):
    store = tmp_path / "store"
    shutil.copytree(seeded_store, store)
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "exp.toml"
    if text is None:
        path.write_bytes(b"\x80\x81\xfe\xff" * 100)
    else:
        path.write_text(text, encoding="utf-8")
    before = _snapshot(store)
    result, out, err, seconds = _cli(
        ["run", str(path), "--tracking-uri", f"sqlite:///{store / 'mlflow.db'}", *argv], capsys
    )
    assert (result, message in _one_line(err)) == (code, True), err
    assert seconds < 30
    assert _snapshot(store) == before
    assert not (tmp_path / "ray_results").exists() and not (tmp_path / "reports").exists()


def test_a_million_variant_grid_is_refused_before_it_is_expanded(tmp_path, capsys):
    path = tmp_path / "big.toml"
    path.write_text('name = "big"\n' + BIG_GRID)
    code, _, err, seconds = _cli(["run", str(path), "--tracking-uri", f"sqlite:///{tmp_path / 'm.db'}"], capsys)
    assert code == 2 and "5,000,000" in _one_line(err)
    assert seconds < 10, seconds  # counted, not expanded: 5 million variants would not be built in 10 s
    assert not (tmp_path / "m.db").exists()


def _corrupt(store: Path) -> None:
    (store / "mlflow.db").write_bytes(os.urandom(4096))


def _truncate(store: Path) -> None:
    db = store / "mlflow.db"
    db.write_bytes(db.read_bytes()[:20_000])


def _text_file(store: Path) -> None:
    (store / "mlflow.db").write_text("this is not a database\n" * 10)


def _directory(store: Path) -> None:
    (store / "mlflow.db").unlink()
    (store / "mlflow.db").mkdir()
    (store / "mlflow.db" / "keep").write_text("x")


def _nothing(store: Path) -> None:
    pass


STORE = "sqlite:///{store}/mlflow.db"
# (id, command, experiment name, tracking URI, store setup, exit code, a part of the message)
STORE_CASES = [
    ("run-nonsense-scheme", "run", "tiny", "nonsense://x", _nothing, 2, "unknown scheme 'nonsense'"),
    ("run-ftp-scheme", "run", "tiny", "ftp://host/x", _nothing, 2, "unknown scheme 'ftp'"),
    ("report-nonsense-scheme", "report", "tiny", "nonsense://x", _nothing, 2, "unknown scheme 'nonsense'"),
    ("run-corrupt-db", "run", "tiny", STORE, _corrupt, 1, "not an SQLite database"),
    ("report-corrupt-db", "report", "tiny", STORE, _corrupt, 1, "not an SQLite database"),
    ("run-truncated-db", "run", "tiny", STORE, _truncate, 1, "truncated"),
    ("report-truncated-db", "report", "tiny", STORE, _truncate, 1, "truncated"),
    ("run-text-file-db", "run", "tiny", STORE, _text_file, 1, "not an SQLite database"),
    ("run-db-is-a-folder", "run", "tiny", STORE, _directory, 1, "not a file"),
    ("run-missing-folder", "run", "tiny", "sqlite:///{store}/nope/sub/mlflow.db", _nothing, 1, "does not exist"),
    ("run-folder-is-a-file", "run", "tiny", "sqlite:///{store}/mlflow.db/x.db", _nothing, 1, "does not exist"),
    ("run-unreachable-server", "run", "tiny", "http://127.0.0.1:9", _nothing, 1, "is unreachable (connection refused)"),
    ("run-host-port-no-scheme", "run", "tiny", "127.0.0.1:5050", _nothing, 2, "unknown scheme (none given)"),
    ("status-host-port-no-scheme", "status", "tiny", "127.0.0.1:5050", _nothing, 2, "unknown scheme (none given)"),
    ("run-raw-slash-in-password", "run", "tiny", "http://u:a/b@127.0.0.1:9", _nothing, 1, "is unreachable"),
    ("run-port-not-a-number", "run", "tiny", "http://127.0.0.1:50x", _nothing, 2, "the port is not a number"),
    ("report-unreachable-server", "report", "tiny", "http://127.0.0.1:9", _nothing, 1, "is unreachable"),
    ("run-deleted-experiment", "run", "gone", STORE, _nothing, 1, "mlflow experiments restore --experiment-id"),
    ("report-deleted-experiment", "report", "gone", STORE, _nothing, 1, "is deleted; restore it"),
]


@pytest.mark.parametrize(
    ("command", "name", "uri", "setup", "code", "message"),
    [c[1:] for c in STORE_CASES],
    ids=[c[0] for c in STORE_CASES],
)
def test_unusable_store_is_one_line_and_left_as_it_was(
    tmp_path, seeded_store, capsys, monkeypatch, command, name, uri, setup, code, message
):
    store = tmp_path / "store"
    shutil.copytree(seeded_store, store)
    setup(store)
    monkeypatch.chdir(tmp_path)
    path = tmp_path / f"{name}.toml"
    path.write_text(GOOD.replace('"tiny"', f'"{name}"'))
    before = _snapshot(store)
    argv = [command, str(path), "--tracking-uri", uri.format(store=store)]
    result, out, err, seconds = _cli(argv, capsys)
    assert (result, message in _one_line(err)) == (code, True), err
    assert seconds < 30
    assert _snapshot(store) == before
    assert not (tmp_path / "reports").exists() and not (tmp_path / "ray_results").exists()


def test_tracking_uri_from_the_environment_is_checked_too(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "nonsense://x")
    (tmp_path / "tiny.toml").write_text(GOOD)
    code, _, err, _ = _cli(["run", "tiny.toml"], capsys)
    assert code == 2 and "unknown scheme 'nonsense'" in _one_line(err)
    assert list(tmp_path.iterdir()) == [tmp_path / "tiny.toml"]


def test_a_second_launch_is_refused_naming_the_first(tmp_path, seeded_store, capsys, monkeypatch):
    from ablate.launch.store import lock_file
    from ablate.launch.tracking import Tracker

    store = tmp_path / "store"
    shutil.copytree(seeded_store, store)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny.toml").write_text(GOOD)
    uri = f"sqlite:///{store / 'mlflow.db'}"
    tracker = Tracker(uri, "tiny")
    lock = lock_file(tracker.uri, tracker.experiment_name)
    holder = os.open(lock, os.O_RDWR | os.O_CREAT)  # a second open file: flock conflicts even in one process
    try:
        fcntl.flock(holder, fcntl.LOCK_EX)
        info = {"pid": 4242, "host": "elsewhere", "started": "2026-01-01 10:00:00", "command": "ablate run tiny.toml"}
        os.write(holder, json.dumps(info).encode())
        before = _snapshot(store)
        code, _, err, seconds = _cli(["run", "tiny.toml", "--tracking-uri", uri], capsys)
    finally:
        os.close(holder)
    line = _one_line(err)
    assert code == 1 and "experiment 'tiny' is already being run on this store by pid 4242 on elsewhere" in line
    assert "started 2026-01-01 10:00:00" in line and seconds < 30
    assert _snapshot(store) == before


def _read_only(paths: list[Path], on: bool) -> None:
    """Make ``paths`` read-only for this user: file modes for a user, the immutable attribute for root (modes
    do not bind root)."""
    for path in paths:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "+i" if on else "-i", str(path)], check=True, capture_output=True)
        else:
            path.chmod((0o555 if path.is_dir() else 0o444) if on else (0o755 if path.is_dir() else 0o644))


@pytest.mark.parametrize("what", ["database", "folder-with-database", "folder-without-database"])
def test_read_only_store_is_one_line_exit_1_at_once(tmp_path, seeded_store, capsys, monkeypatch, what):
    if os.geteuid() == 0 and not shutil.which("chattr"):
        pytest.skip("running as root without chattr: nothing is read-only to root")
    store = tmp_path / "store"
    shutil.copytree(seeded_store, store)
    if what == "folder-without-database":
        (store / "mlflow.db").unlink()
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny.toml").write_text(GOOD)
    locked = [store / "mlflow.db"] if what == "database" else [*store.rglob("*"), store]
    before = _snapshot(store)
    _read_only(locked, True)
    try:
        code, _, err, seconds = _cli(["run", "tiny.toml", "--tracking-uri", f"sqlite:///{store}/mlflow.db"], capsys)
    finally:
        _read_only(locked, False)
    assert code == 1 and "read-only" in _one_line(err), err
    assert seconds < 30
    assert _snapshot(store) == before


def test_a_report_whose_artifacts_were_removed_is_one_line_naming_what_is_missing(
    tmp_path, seeded_store, capsys, monkeypatch
):
    store = tmp_path / "store"
    shutil.copytree(seeded_store, store)
    shutil.rmtree(store / "mlartifacts")  # the server's artifact folder removed, the runs kept
    monkeypatch.chdir(tmp_path)
    code, _, err, seconds = _cli(["report", "tiny", "--tracking-uri", f"sqlite:///{store / 'mlflow.db'}"], capsys)
    line = _one_line(err)
    assert code == 1 and "artifact 'grid.json' of run " in line and "cannot be read" in line, err
    assert seconds < 30
