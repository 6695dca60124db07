"""Which Ray ``ablate run`` uses: a fresh local one on 127.0.0.1 even when another cluster runs on the
machine, the cluster ``RAY_ADDRESS`` names when set, and one line within seconds when it cannot be reached."""

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from stores import fresh_store

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import local_cluster  # noqa: E402
from test_cluster import _listening  # noqa: E402

from ablate.launch.tracking import Tracker  # noqa: E402

EXPERIMENT = """
name = "{name}"
seeds = 1
[base]
env_id = "CartPole-v1"
max_episodes = 10
episodes_per_update = 10
record_video = false
{extra}
[[variants]]
name = "narrow"
hidden_sizes = [8]
"""


def _launch(folder: Path, name: str, extra: str = "", **env) -> subprocess.Popen:
    folder.mkdir()
    (folder / "exp.toml").write_text(EXPERIMENT.format(name=name, extra=extra))
    fresh_store(folder / "mlflow.db")  # what the launch would create, minus MLflow's migrations
    environment = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | env
    return subprocess.Popen(
        [sys.executable, "-m", "ablate.cli", "run", "exp.toml", "--no-report"],
        cwd=folder,
        env=environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


@pytest.fixture
def other_cluster(tmp_path):
    """Another Ray cluster running on the machine (a head node with 1 CPU): what plain ``ray.init()`` finds."""
    head, node_id, gcs = local_cluster.start_node_process(True, 1, port=local_cluster.free_port())
    try:
        yield node_id, gcs
    finally:
        local_cluster.stop_process(head)


@pytest.mark.skipif(
    not os.environ.get("ABLATE_CLUSTER_TESTS"), reason="a second Ray cluster on the machine: make test-cluster"
)
def test_a_local_run_ignores_another_cluster_listens_on_loopback_and_ray_address_joins(tmp_path, other_cluster):
    other_node, gcs = other_cluster
    marker = tmp_path / "release"
    block = f'fault = "block"\nfault_marker = "{marker}"'
    launch = _launch(tmp_path / "local", "local", block)
    try:
        tracker = Tracker(f"sqlite:///{tmp_path / 'local' / 'mlflow.db'}", "local")
        deadline = time.monotonic() + 180
        while not any(r.status == "RUNNING" for r in tracker.trial_runs()):  # the trial runs: Ray is up
            assert launch.poll() is None and time.monotonic() < deadline, local_cluster.finish_process(launch)[1]
            time.sleep(0.5)
        addresses = _listening([launch.pid])
        assert len(addresses) >= 3 and set(addresses) <= {"127.0.0.1", "[::ffff:127.0.0.1]"}, addresses
    finally:
        marker.write_text("go\n")
    code, output = local_cluster.finish_process(launch)
    assert code == 0, output
    (run,) = tracker.trial_runs()
    assert run.status == "FINISHED" and run.tags["ablate.node"] != other_node  # a fresh local Ray of its own

    code, output = local_cluster.finish_process(_launch(tmp_path / "joined", "joined", RAY_ADDRESS=gcs))
    assert code == 0, output
    (run,) = Tracker(f"sqlite:///{tmp_path / 'joined' / 'mlflow.db'}", "joined").trial_runs()
    assert run.status == "FINISHED" and run.tags["ablate.node"] == other_node  # ran on that cluster


def test_an_unreachable_cluster_is_one_line_and_exit_1_within_seconds(tmp_path):
    # "Within seconds" is the probe's: a TCP connection refused at once (or given up after CONNECT_TIMEOUT_S),
    # before Ray, which retries an unreachable GCS for minutes. The test checks that the refusal is the probe's,
    # not how long the child took: on a loaded machine its imports alone took 27 s of the 60 s it once allowed.
    launch = _launch(tmp_path / "x", "x", RAY_ADDRESS=f"127.0.0.1:{local_cluster.free_port()}")
    code, output = local_cluster.finish_process(launch, timeout_s=1800)  # a guard against a hang only
    assert code == 1
    last = output.strip().splitlines()[-1]
    assert last.startswith("ablate run: cannot reach the Ray cluster at 127.0.0.1:"), output
    assert "(Connection refused); is its head node running?" in last, last  # the probe's answer, not Ray's
    assert "Traceback" not in output
    assert Tracker(f"sqlite:///{tmp_path / 'x' / 'mlflow.db'}", "x").latest_launch() is None  # nothing recorded


@pytest.mark.parametrize(("gpus", "expected"), [(0.25, {"CPU": 1.0, "GPU": 0.25}), (0.0, {"CPU": 1.0})])
def test_gpus_per_trial_reaches_ray_tunes_resource_request(gpus, expected):
    """What Tune asks Ray to reserve for each trial (no GPU or running cluster needed to build the request)."""
    from ray import tune
    from ray.tune.trainable.function_trainable import wrap_function  # what Tune turns a function trainable into

    from ablate.launch.scheduler import ClusterOptions, trial_resources

    def train(config):
        return None

    options = ClusterOptions(cpus_per_trial=1.0, gpus_per_trial=gpus)
    trainable = wrap_function(tune.with_resources(train, trial_resources(options)))
    assert trainable.default_resource_request({}).required_resources == expected


def test_what_ray_prints_while_joining_is_kept_aside_and_passed_on_when_the_join_succeeds(capfd):
    import os

    from ablate.launch.scheduler import _stderr_kept

    with _stderr_kept() as kept:
        os.write(2, b"gcs_client.cc:210: Failed to get cluster ID: InvalidAuthToken\n")
    assert "InvalidAuthToken" in kept.text
    assert "InvalidAuthToken" in capfd.readouterr().err  # a join that succeeded: passed on as it was
    with pytest.raises(ConnectionError), _stderr_kept() as kept:
        os.write(2, b"InvalidAuthToken\n")
        raise ConnectionError("Failed to connect to Ray cluster")
    assert "InvalidAuthToken" in kept.text and "InvalidAuthToken" not in capfd.readouterr().err  # kept for the line


def test_a_local_ray_that_fails_to_start_is_one_line(monkeypatch):
    """Ray gives up on a node that does not start within 30 s (seen on a machine at load 40): one line, not a
    traceback, and ClusterUnavailable so that ``ablate run`` exits 1."""
    import ray

    from ablate.launch import scheduler

    def timed_out(**_):
        raise Exception("The current node timed out during startup. This could happen because some of the Ray\nmore")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", timed_out)
    with pytest.raises(scheduler.ClusterUnavailable) as error:
        scheduler.ensure_ray(None)
    message = str(error.value)
    assert message.startswith("could not start a local Ray: The current node timed out during startup")
    assert "\n" not in message and "run the same command again" in message


def test_events_are_told_in_order_off_the_callback_and_a_failed_write_is_raised_on_the_driver():
    """Tune holds a population's worker until its callbacks return: they queue the events, a thread tells them
    (the launch's MLflow writes), in order; a write that fails is raised by the next event queued, or by close."""
    from ablate.launch.event_writer import EventWriter
    from ablate.launch.store import TrackingError

    told = []
    writer = EventWriter(None)
    for i in range(50):
        writer.put(lambda i=i: told.append(i))
    writer.close()
    assert told == list(range(50))

    def lost():
        raise TrackingError("MLflow store x stopped answering")

    writer = EventWriter(None)
    writer.put(lost)
    while writer.error is None:
        time.sleep(0.01)
    with pytest.raises(TrackingError, match="stopped answering"):
        writer.put(lambda: told.append("never"))
    with pytest.raises(TrackingError):
        writer.close()
    assert "never" not in told

    writer = EventWriter(None)  # Ctrl-C: the event being told ends, the rest are dropped, nothing is raised
    writer.put(lambda: time.sleep(0.2))
    for _ in range(5):
        writer.put(lambda: told.append("dropped"))
    writer.close(drop=True)
    assert "dropped" not in told
