"""``make test-cluster``: a two-node Ray cluster on this machine whose worker node cannot see the driver's
files, a real ``mlflow server`` on a free loopback port, a tiny ablation tracked on the server, then a node
lost mid-run. Locked as the team recipe says: Ray token authentication on both nodes and the driver, the server
running MLflow's basic-auth app; a driver without the token and a client without a login are refused in one
line, and the planted password and token are found nowhere ablate records or prints. Every process it starts
listens on 127.0.0.1 and is stopped, pass or fail."""

import os
import secrets
import shutil
import socket
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import quote

import psutil
import pytest
import sqlalchemy

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import local_cluster  # noqa: E402

from ablate.launch.tracking import POINT_METRICS, Tracker  # noqa: E402
from ablate.reporting.reader import RunReader  # noqa: E402

pytestmark = pytest.mark.skipif(
    not os.environ.get("ABLATE_CLUSTER_TESTS"), reason="a two-node cluster with a private mount: make test-cluster"
)
ROOT = local_cluster.ROOT
# The worker node's view: empty /tmp, /dev/shm and project folder, except the code a worker needs installed
# (the virtualenv, ablate/, tools/) and the test's control folder (the files that release blocked trials).
# The server's store, the driver's folders, Tune's and every temp folder are out of its sight.
# The kept folders wait on a tmpfs of their own while /tmp, /dev/shm and the project folder are covered; it must
# not lie above the project folder (a clone may live in /tmp or under /mnt), and the project folder is made
# again after /tmp is covered in case it lived there.
STAGE = "/srv" if ROOT.is_relative_to("/mnt") else "/mnt"
PRIVATE_MOUNTS = f"""set -e
mount -t tmpfs keep {STAGE}
for d in .venv ablate tools; do mkdir -p {STAGE}/$d; mount --bind "{ROOT}/$d" {STAGE}/$d; done
mkdir {STAGE}/control; mount --bind "$CONTROL" {STAGE}/control
mount -t tmpfs worker-private /tmp
mount -t tmpfs worker-private /dev/shm
mkdir -p "{ROOT}"
mount -t tmpfs worker-private "{ROOT}"
for d in .venv ablate tools; do mkdir "{ROOT}/$d"; mount --move {STAGE}/$d "{ROOT}/$d"; done
mkdir -p "$CONTROL"; mount --move {STAGE}/control "$CONTROL"
test ! -e "$PROBE"
exec "$@"
"""

EXPERIMENT = """
name = "{name}"
seeds = 2
[base]
env_id = "{env_id}"
max_episodes = {episodes}
episodes_per_update = 10
video_max_frames = 30
{extra}
[[variants]]
name = "narrow"
hidden_sizes = [8]
"""


NETWORK = """
from helpers import body


def create_model(observation_shape, n_actions, width=8):
    return body(observation_shape[0], width, n_actions)
"""
"""A user's own network, in a file beside the experiment on the driver's disk only, built by a helper beside it."""
HELPERS = """
from torch import nn


def body(inputs, width, n_actions):
    return nn.Sequential(nn.Linear(inputs, width), nn.LayerNorm(width), nn.Tanh(), nn.Linear(width, n_actions))
"""
ENV_MODULE = """
import gymnasium as gym

gym.register(
    id="ClusterPole-v0",
    entry_point="gymnasium.envs.classic_control:CartPoleEnv",
    max_episode_steps=500,
    reward_threshold=475.0,
)
"""
"""A user's own env module beside the experiment (the driver's disk only): it registers ClusterPole-v0."""

USER = "ablate-ci"


@pytest.fixture
def cluster(tmp_path, monkeypatch):
    """mlflow server (basic-auth), a head node (1 CPU), a worker node (1 CPU) in its own mount namespace, both
    requiring a Ray token; all stopped after. This process holds the MLflow login (to read what was tracked)."""
    log = open(tmp_path / "cluster.log", "w")  # noqa: SIM115 - closed at the end
    processes = []
    # The planted secrets: searched for afterwards in everything ablate recorded or printed. The password holds
    # a raw '@', '/' and ':', which a URI's userinfo must carry as its own.
    password, token = (
        f"planted@pw/{secrets.token_hex(6)}:{secrets.token_hex(6)}",
        f"plantedtoken{secrets.token_hex(24)}",
    )
    admin = ("admin", f"planted-admin-{secrets.token_hex(12)}")  # administration only: the driver is USER
    # Ray's session logs in a folder of the test's (a short path: Ray's socket paths must fit 107 bytes)
    ray_tmp = Path(tempfile.mkdtemp(prefix="ablate-ray-", dir="/tmp"))
    monkeypatch.setenv("RAY_TMPDIR", str(ray_tmp))
    control = tmp_path / "control"  # the worker node sees this folder (and so the token's file) only
    control.mkdir()
    token_file = local_cluster.write_secret(control / "ray_token", token + "\n")
    monkeypatch.setenv("MLFLOW_TRACKING_USERNAME", USER)
    monkeypatch.setenv("MLFLOW_TRACKING_PASSWORD", password)
    for name in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"):
        monkeypatch.delenv(name, raising=False)
    try:
        port = local_cluster.free_port()
        # ABLATE_TEST_BACKEND=postgresql+psycopg://...: the server's store in PostgreSQL instead of an SQLite file
        # (make test-cluster-postgres starts a private one)
        store = os.environ.get("ABLATE_TEST_BACKEND") or f"sqlite:///{tmp_path / 'server' / 'mlflow.db'}"
        _check_store(store)
        server = local_cluster.mlflow_server(tmp_path / "server", port, backend=store, log=log, auth=admin)
        processes.append(server)
        head, head_id, gcs = local_cluster.start_node_process(
            True, 1, port=local_cluster.free_port(), log=log, token_file=token_file
        )
        processes.append(head)
        probe = tmp_path / "server"  # the tracking server's files: the worker node must not see them
        wrap = [
            "env",
            f"PROBE={probe}",
            f"CONTROL={control}",
            "unshare",
            "--mount",
            "--propagation",
            "private",
            "sh",
            "-c",
            PRIVATE_MOUNTS,
            "sh",
        ]
        worker, worker_id, _ = local_cluster.start_node_process(
            False, 1, address=gcs, wrap=wrap, log=log, token_file=token_file
        )
        processes.append(worker)
        problem = None
        try:
            local_cluster.wait_http(f"http://127.0.0.1:{port}/health", 120, server)
        except (RuntimeError, TimeoutError) as error:
            problem = error
        if not problem:
            local_cluster.create_user(f"http://127.0.0.1:{port}", admin, USER, password)  # not an admin
        if problem:
            log.flush()
            tail = "\n".join((tmp_path / "cluster.log").read_text(errors="replace").splitlines()[-8:])
            pytest.fail(f"mlflow server with store {_safe(store)}: {problem}; its log ends:\n{tail}", pytrace=False)
        yield {
            "uri": f"http://127.0.0.1:{port}",
            "store": store,
            "gcs": gcs,
            "head": head_id,
            "worker": worker_id,
            "worker_process": worker,
            "processes": processes,
            "tmp": tmp_path,
            "control": control,
            "token_file": token_file,
            "secrets": (password, token, admin[1]),
            "outputs": [],
            "ray_tmp": ray_tmp,
            "admin": admin,
        }
    finally:
        for process in reversed(processes):
            local_cluster.stop_process(process)
        log.close()
        shutil.rmtree(ray_tmp, ignore_errors=True)


def _safe(store):
    return sqlalchemy.engine.make_url(store).render_as_string(hide_password=True)


def _check_store(store):
    """One clear failure in seconds when the store cannot be reached (MLflow's server retries for ~100 s)."""
    if store.startswith("sqlite"):
        return
    problem = None
    try:
        engine = sqlalchemy.create_engine(store, connect_args={"connect_timeout": 10})
    except ImportError as error:
        pytest.fail(f"{_safe(store)}: no driver ({error}); pip install -e '.[postgres]'", pytrace=False)
    try:
        with engine.connect():
            pass
    except sqlalchemy.exc.SQLAlchemyError as error:
        problem = str(getattr(error, "orig", error)).strip().splitlines()[0]
    finally:
        engine.dispose()
    if problem:  # outside the except: one line, not the chain of exceptions behind it
        pytest.fail(f"ABLATE_TEST_BACKEND={_safe(store)} cannot be reached: {problem}", pytrace=False)


def _store_run_ids(store, experiment):
    """Ids of the active runs of ``experiment`` read from the server's database itself, not through MLflow: the
    runs are in the store the server was given (PostgreSQL under make test-cluster-postgres), nowhere else."""
    engine = sqlalchemy.create_engine(store)
    query = sqlalchemy.text(
        "SELECT r.run_uuid FROM runs r JOIN experiments e ON r.experiment_id = e.experiment_id"
        " WHERE e.name = :name AND r.lifecycle_stage = 'active'"
    )
    try:
        with engine.connect() as connection:
            return {row[0] for row in connection.execute(query, {"name": experiment})}
    finally:
        engine.dispose()


def _env(cluster, ray_token=True, login=True):
    """A client's environment: the MLflow login (as the test process has it) and Ray's token file, or not."""
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["HOME"] = str(cluster["tmp"] / "home")  # no ~/.ray/auth_token or ~/.mlflow/credentials of this machine
    if ray_token:
        env.update(local_cluster.ray_token_env(cluster["token_file"]))
    if not login:
        env.pop("MLFLOW_TRACKING_USERNAME")
        env.pop("MLFLOW_TRACKING_PASSWORD")
    return env


def _ablate(cluster, name, episodes, extra="", env=None, uri=None, folder=None, env_id="CartPole-v1", **credentials):
    folder = cluster["tmp"] / (folder or name)
    folder.mkdir()
    (folder / "exp.toml").write_text(EXPERIMENT.format(name=name, episodes=episodes, extra=extra, env_id=env_id))
    # The driver's files only: the worker node cannot see this folder.
    for file, text in (("net.py", NETWORK), ("helpers.py", HELPERS), ("myenvs.py", ENV_MODULE)):
        (folder / file).write_text(text)
    command = [sys.executable, "-m", "ablate.cli", "run", "exp.toml", "--address", cluster["gcs"]]
    command += ["--tracking-uri", uri or cluster["uri"], "--no-report"]
    env = env or _env(cluster, **credentials)
    return subprocess.Popen(command, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _finish(cluster, process):
    code, output = local_cluster.finish_process(process)
    cluster["outputs"].append(output)
    return code, output


def _refused(output):
    """The one error line of a refused ``ablate run`` (its progress lines and warnings aside)."""
    lines = [line for line in output.splitlines() if line.startswith("ablate run: ")]  # the error line(s)
    assert len(lines) == 1 and "Traceback" not in output, output
    return lines[0]


def _wait_running(tracker, count, launch, timeout_s=300):
    deadline = time.monotonic() + timeout_s
    while sum(r.status == "RUNNING" for r in tracker.trial_runs()) < count:
        assert launch.poll() is None and time.monotonic() < deadline, local_cluster.finish_process(launch)[1]
        time.sleep(0.5)


def _listening(pids):
    """Local addresses of every TCP socket our processes (and their descendants) listen on."""
    family = set()
    for pid in pids:
        try:
            root = psutil.Process(pid)
            family |= {root, *root.children(recursive=True)}
        except psutil.Error:
            continue
    ids = {p.pid for p in family}
    out = subprocess.run(["ss", "-ltnpH"], capture_output=True, text=True, check=True).stdout
    addresses = []
    for line in out.splitlines():
        if any(f"pid={pid}," in line for pid in ids):
            addresses.append(line.split()[3].rsplit(":", 1)[0])
    return addresses


def test_two_nodes_no_shared_files_tracking_server_and_a_lost_node(cluster):
    # 1. Trials on both nodes (each blocks until both run: one per node, 1 CPU each), every run, metric and
    #    artifact on the server.
    # Experiment names new to the store: a PostgreSQL store outlives the test and may hold an earlier run's.
    spread, lost_name = (f"{name}-{secrets.token_hex(4)}" for name in ("spread", "lost"))
    marker = cluster["control"] / "release"
    # trained on both nodes: a network whose layers come from a helper beside it, an env a module beside it registers
    custom = 'model = "net.py:create_model"\nmodel_args = { width = 6 }\nenv_module = "myenvs"\n'
    extra = f'{custom}fault = "block"\nfault_marker = "{marker}"'
    launch = _ablate(cluster, spread, episodes=200, extra=extra, env_id="ClusterPole-v0")
    _wait_running(Tracker(cluster["uri"], spread), 2, launch)
    marker.write_text("go\n")
    code, output = _finish(cluster, launch)
    assert code == 0, output
    tracker = RunReader(cluster["uri"], spread)
    runs = tracker.trial_runs()
    assert len(runs) == 2 and {r.status for r in runs} == {"FINISHED"}
    tracked = {r.run_id for r in runs} | {launch.info.run_id for launch in tracker.launches()}
    assert len(tracked) == 3 and _store_run_ids(cluster["store"], spread) == tracked  # in the server's database
    assert {r.tags["ablate.node"] for r in runs} == {cluster["head"], cluster["worker"]}  # one per node
    for run in runs:
        artifacts = {a.path for a in tracker.client.list_artifacts(run.run_id)}
        assert artifacts == {"episodes.csv", "weights.pt", "config.json", "learning_curve.png", "model.py"}
        assert run.metrics["parameter_count"] == 4 * 6 + 6 + 2 * 6 + 6 * 2 + 2  # the user's LayerNorm net
        assert (run.params["env_id"], run.params["env.reward_threshold"]) == ("ClusterPole-v0", "475.0")
        for metric in POINT_METRICS:
            steps = [
                s for s, _ in sorted((m.step, m.value) for m in tracker.client.get_metric_history(run.run_id, metric))
            ]
            assert steps == list(range(2, 201, 2)), metric  # 200 episodes -> 100 points
    assert list((cluster["tmp"] / "server" / "artifacts").rglob("episodes.csv"))  # in the server's store
    # Least privilege: the server's folder, store, users' database and artifacts are its owner's only, and the
    # driver's account (which wrote all of the above) is not an admin.
    server_files = [cluster["tmp"] / "server", *(cluster["tmp"] / "server").rglob("*")]
    modes = {str(p): stat.S_IMODE(p.stat().st_mode) for p in server_files if not p.is_symlink()}
    wrong = {p: oct(m) for p, m in modes.items() if m & 0o077}
    assert not wrong and any(p.endswith("basic_auth.db") for p in modes), wrong
    with pytest.raises(RuntimeError, match="HTTP 403"):
        local_cluster.create_user(cluster["uri"], (USER, cluster["secrets"][0]), "intruder", secrets.token_hex(8))

    # 2. A node lost mid-run: both trials block until a file exists (which the worker node cannot see),
    #    the worker node dies, its trial is retried on the head, the ablation completes.
    marker = cluster["tmp"] / "release"
    launch = _ablate(cluster, lost_name, episodes=20, extra=f'fault = "block"\nfault_marker = "{marker}"')
    try:
        lost = Tracker(cluster["uri"], lost_name)
        _wait_running(lost, 2, launch)
        pids = [p.pid for p in cluster["processes"]] + [launch.pid]
        addresses = _listening(pids)
        assert addresses and set(addresses) <= {"127.0.0.1", "[::ffff:127.0.0.1]"}, addresses
        local_cluster.stop_process(cluster["worker_process"])  # kills the node's raylet and workers
        marker.write_text("go\n")
        code, output = _finish(cluster, launch)
    finally:
        marker.write_text("go\n")
        if launch.poll() is None:
            launch.kill()
    assert code == 0, output
    runs = lost.trial_runs()
    finished = [r for r in runs if r.status == "FINISHED"]
    assert len(finished) == 2 and len({r.key for r in finished}) == 2 and len(runs) == 2  # the partial run deleted
    assert {r.tags["ablate.node"] for r in finished} == {cluster["head"]}
    assert max(int(r.tags["ablate.attempt"]) for r in finished) == 2  # the lost trial ran again
    launches = lost.client.search_runs([lost.experiment_id()], "tags.`ablate.role` = 'launch'")
    assert [launch.info.status for launch in launches] == ["FINISHED"]

    # 3. Refusals, each one line, exit 1, nothing tracked: a driver without the Ray token; a client without
    #    the MLflow login (before Ray starts), with a wrong password; `ablate status` without the login.
    refused = f"refused-{secrets.token_hex(4)}"
    started = time.monotonic()
    code, output = _finish(cluster, _ablate(cluster, refused, episodes=10, ray_token=False))
    assert code == 1 and "refused this driver: its token is missing or wrong" in _refused(output), output
    assert "RAY_AUTH_TOKEN_PATH" in _refused(output)
    ray_refusal_s = time.monotonic() - started
    wrong = _env(cluster) | {"MLFLOW_TRACKING_PASSWORD": "not-the-password"}
    for name, env in (("nologin", _env(cluster, login=False)), ("wrongpw", wrong)):
        started = time.monotonic()
        launch = _ablate(cluster, f"{refused}-{name}", episodes=10, env=env)
        code, output = _finish(cluster, launch)
        line = _refused(output)
        assert code == 1 and "(HTTP 401)" in line and "MLFLOW_TRACKING_PASSWORD" in line, output
        assert cluster["uri"] in line and "Ray" not in output.split("\n", 1)[1], output  # before Ray starts
        assert time.monotonic() - started < 60, time.monotonic() - started  # MLflow's own retries: minutes
    for command in (["status"], ["report", spread, "--no-pdf"]):
        refusal = subprocess.run(
            [sys.executable, "-m", "ablate.cli", *command, "--tracking-uri", cluster["uri"]],
            cwd=cluster["tmp"],
            env=_env(cluster, login=False),
            capture_output=True,
            text=True,
            timeout=120,
        )
        cluster["outputs"].append(refusal.stdout + refusal.stderr)
        assert refusal.returncode == 1 and len((refusal.stdout + refusal.stderr).strip().splitlines()) == 1, refusal
        expected = f"ablate {command[0]}: MLflow tracking server {cluster['uri']} needs a login (HTTP 401)"
        assert expected in refusal.stderr
    assert not (cluster["tmp"] / "reports").exists()  # the refused report wrote nothing
    client = RunReader(cluster["uri"], spread).client
    refused_ids = [e.experiment_id for e in client.search_experiments() if e.name.startswith(refused)]
    # nothing tracked (the Ray refusal leaves its experiment, empty: the launch names its MLflow link first)
    assert not refused_ids or not client.search_runs(refused_ids)
    print(f"a driver without the Ray token refused after {ray_refusal_s:.1f} s")

    # 4. The planted password and token appear nowhere: the store's tags and params, every artifact and file
    #    the runs and the report left, and every command's output.
    report = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "report", spread, "--tracking-uri", cluster["uri"], "--no-pdf"],
        cwd=cluster["tmp"] / spread,
        env=_env(cluster),
        capture_output=True,
        text=True,
        timeout=600,
    )
    cluster["outputs"].append(report.stdout + report.stderr)
    assert report.returncode == 0, report.stdout + report.stderr
    _assert_no_secret(cluster)


def test_one_launch_per_experiment_per_store_from_any_spelling_or_machine(cluster):
    """Two launches at once through two spellings of the server's URI (one machine: the lock file decides),
    a third from "another machine" (its own lock folder: the store's lease decides), all refused but one,
    naming it; the holder killed (kill -9), its lease lapses and the next launch runs the experiment."""
    name = f"lease-{secrets.token_hex(4)}"
    marker = cluster["control"] / f"release-{name}"
    extra = f'fault = "block"\nfault_marker = "{marker}"'
    host = cluster["uri"].removeprefix("http://")
    both = [
        _ablate(cluster, name, 20, extra, uri=uri, folder=f"{name}-{i}")
        for i, uri in enumerate((f"http://{host}", f"http://{host}/"))
    ]
    deadline = time.monotonic() + 300
    while all(launch.poll() is None for launch in both):  # the refused one ends in seconds, before Ray starts
        assert time.monotonic() < deadline
        time.sleep(0.2)
    refused = next(launch for launch in both if launch.poll() is not None)
    holder = next(launch for launch in both if launch is not refused)
    code, output = _finish(cluster, refused)
    holder_line = f"by pid {holder.pid} on {socket.gethostname()}, started "
    assert code == 1 and "is already being run on this store " + holder_line in _refused(output), output
    try:
        tracker = Tracker(cluster["uri"], name)
        _wait_running(tracker, 2, holder)
        elsewhere = _env(cluster) | {"HOME": str(cluster["tmp"] / "home-b")}  # another machine's lock folder
        code, output = _finish(cluster, _ablate(cluster, name, 20, extra, env=elsewhere, folder=f"{name}-b"))
        line = _refused(output)
        assert code == 1 and holder_line in line and f"its lease: MLflow experiment 'ablate-lease-{name}'" in line
        holder.kill()  # kill -9: its lease is not released, and lapses (its process on this machine is gone)
        holder.wait()
    finally:
        marker.write_text("go\n")
        if holder.poll() is None:
            holder.kill()
    third = _env(cluster) | {"HOME": str(cluster["tmp"] / "home-c")}
    code, output = _finish(cluster, _ablate(cluster, name, 20, extra, env=third, folder=f"{name}-c"))
    assert code == 0 and f"lapsed (its process {holder.pid} on this machine is gone); taking it" in output, output
    runs = tracker.trial_runs()
    finished = [r for r in runs if r.status == "FINISHED"]
    assert len(finished) == 2 and len({r.key for r in finished}) == 2 and "RUNNING" not in {r.status for r in runs}
    launches = tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'launch'")
    assert sorted(launch.info.status for launch in launches) == ["FINISHED", "KILLED"]  # one each, none refused


def _launch_states(tracker):
    runs = tracker.client.search_runs([tracker.experiment_id()], "")
    return sorted(r.info.status for r in runs if r.data.tags.get("ablate.role") == "launch"), [
        r.info.status for r in runs if r.data.tags.get("ablate.role") == "trial"
    ]


def test_a_store_that_refuses_writes_or_stops_answering_ends_the_launch_as_promised(cluster):
    """The server answers a write with an error (its artifact folder immutable: PermissionError): the launch
    ends within the bound saying so, recorded FAILED with nothing left RUNNING. Then the server killed mid-run:
    the launch ends in one line and exit 1 within ``STORE_BOUND_S`` of its first failed write."""
    from ablate.launch.store_writes import STORE_BOUND_S

    artifacts = cluster["tmp"] / "server" / "artifacts"
    artifacts.mkdir(exist_ok=True)
    # Root ignores file modes: the immutable attribute makes the folder unwritable (where chattr and the file
    # system allow it; else only the lost store below is tried)
    immutable = shutil.which("chattr") and subprocess.run(["chattr", "+i", str(artifacts)]).returncode == 0
    refused_s = float("nan")
    if immutable:
        name = f"refused-writes-{secrets.token_hex(4)}"
        try:
            launch = _ablate(cluster, name, episodes=10)
            # The launch's first write that fails is its first file, right after its run is created: seen here
            # (Ray's join before it takes from seconds to minutes on a loaded machine, and is not the store's)
            tracker, deadline = Tracker(cluster["uri"], name), time.monotonic() + 600
            while tracker.latest_launch() is None and launch.poll() is None and time.monotonic() < deadline:
                time.sleep(0.2)
            started = time.monotonic()
            code, output = _finish(cluster, launch)
            refused_s = time.monotonic() - started
        finally:
            subprocess.run(["chattr", "-i", str(artifacts)], check=True)
        # The server's answer is a bare "Internal Server Error" (its log has the PermissionError): named as the
        # server's error, not as a store that stopped answering
        line = _refused(output)
        assert code == 1 and "answered every try of a write with a server error" in line and "its log says" in line
        assert "stopped answering" not in output, output
        assert refused_s < STORE_BOUND_S + 60, refused_s  # from the launch's run seen in the store to exit 1
        launches, trials = _launch_states(Tracker(cluster["uri"], name))
        assert launches == ["FAILED"] and "RUNNING" not in trials, (launches, trials)

    name = f"lost-store-{secrets.token_hex(4)}"
    marker = cluster["control"] / f"release-{name}"
    launch = _ablate(cluster, name, episodes=20, extra=f'fault = "block"\nfault_marker = "{marker}"')
    try:
        _wait_running(Tracker(cluster["uri"], name), 2, launch)
        server = cluster["processes"][0]
        local_cluster.stop_process(server)  # the server gone: the trials' ends are the next writes
        marker.write_text("go\n")
        killed_at = time.monotonic()
        code, output = _finish(cluster, launch)
        lost_s = time.monotonic() - killed_at
    finally:
        marker.write_text("go\n")
        if launch.poll() is None:
            launch.kill()
    line = _refused(output)
    assert code == 1 and "stopped answering" in line and "Traceback" not in output, output
    # The bound runs from the first failed write (~1 s after the kill); the margin is for a loaded machine's
    # teardown (the figure of record is printed: 45.8 s on the 2-core machine). MLflow's own retries took 250 s.
    assert lost_s < STORE_BOUND_S + 60, lost_s
    print(f"refused writes: {refused_s:.1f} s to exit 1; a lost store: {lost_s:.1f} s from the kill to exit 1")


def test_a_password_planted_in_every_uri_form_shows_nowhere(cluster):
    """The login in the tracking URI itself, raw (its '@', '/' and ':' as they are) for a launch on the cluster,
    percent-encoded for `ablate status`, in MLFLOW_TRACKING_URI for `ablate report`: every command works, and
    the password is in no output, report, store row, artifact, lock file, Ray session log or Ray's job table."""
    password = cluster["secrets"][0]
    host = cluster["uri"].removeprefix("http://")
    raw, encoded = f"http://{USER}:{password}@{host}/", f"http://{USER}:{quote(password, safe='')}@{host}"
    no_login = _env(cluster, login=False)
    name = f"planted-{secrets.token_hex(4)}"
    code, output = _finish(cluster, _ablate(cluster, name, episodes=10, env=no_login, uri=raw))
    assert code == 0, output
    command = RunReader(cluster["uri"], name).launches()[0].data.tags["ablate.command"]
    assert f"--tracking-uri http://{USER}:***@{host}/" in command
    done = []
    for command, env in (
        (["status", "--tracking-uri", encoded], no_login),
        (["status", name, "--tracking-uri", raw], no_login),
        (["report", name, "--no-pdf"], no_login | {"MLFLOW_TRACKING_URI": raw}),
    ):
        done.append(
            subprocess.run(
                [sys.executable, "-m", "ablate.cli", *command],
                cwd=cluster["tmp"] / name,
                env=env,
                capture_output=True,
                text=True,
                timeout=600,
            )
        )
        cluster["outputs"].append(done[-1].stdout + done[-1].stderr)
        assert done[-1].returncode == 0, done[-1].stdout + done[-1].stderr
    assert name in done[0].stdout and "2 finished" in done[1].stdout
    report = (cluster["tmp"] / name / "reports" / name / "report.md").read_text()
    assert f"http://{USER}:***@{host}/" in report  # the launch's command, as the report records it
    # Ray's job table, as anyone with the cluster's token reads it: the launch's entrypoint, masked
    table = (
        "import sys, ray\nfrom ablate.launch.scheduler import ensure_ray\nensure_ray(sys.argv[1])\n"
        "print(repr([job['Entrypoint'] for job in ray._private.state.jobs()]))\n"
    )
    jobs = subprocess.run(
        [sys.executable, "-c", table, cluster["gcs"]], env=_env(cluster), capture_output=True, text=True, timeout=300
    )
    assert jobs.returncode == 0, jobs.stderr
    assert f"--tracking-uri http://{USER}:***@{host}/" in jobs.stdout, jobs.stdout
    cluster["outputs"].append(jobs.stdout + jobs.stderr)
    _assert_no_secret(cluster)


def _assert_no_secret(cluster):
    planted = [secret.encode() for secret in cluster["secrets"]]
    planted.append(quote(cluster["secrets"][0], safe="").encode())  # the password as a URI carries it
    planted.append(quote(cluster["secrets"][0]).encode())
    if os.environ.get("PGPASSFILE"):  # make test-cluster-postgres: the database's password too
        planted.append(Path(os.environ["PGPASSFILE"]).read_text().strip().rsplit(":", 1)[1].encode())
    hits = []
    engine = sqlalchemy.create_engine(cluster["store"])
    try:
        with engine.connect() as connection:
            for table in ("tags", "params", "experiment_tags"):
                for key, value in connection.execute(sqlalchemy.text(f"SELECT key, value FROM {table}")):
                    hits += [f"{table}.{key}" for secret in planted if secret in str(value).encode()]
    finally:
        engine.dispose()
    for path in [*cluster["tmp"].rglob("*"), *cluster["ray_tmp"].rglob("*")]:  # Ray's session logs too
        if path.is_file() and path != cluster["token_file"] and not path.is_symlink():
            data = path.read_bytes()
            hits += [str(path) for secret in planted if secret in data]
    for output in cluster["outputs"]:
        hits += ["a command's output" for secret in planted if secret.decode() in output]
    assert not hits, hits
