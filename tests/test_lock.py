"""The launch lock: one holder at a time, named in the refusal; never stale after its holder dies."""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from ablate.launch.lock import LaunchLocked, launch_lock


def test_a_second_holder_is_refused_naming_the_first(tmp_path):
    path = tmp_path / "x.lock"
    with launch_lock(path, "experiment 'x'", "ablate run x.toml"):
        info = json.loads(path.read_text())
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname()
        refused = pytest.raises(LaunchLocked, match=rf"by pid {os.getpid()} on {socket.gethostname()}, started ")
        with refused, launch_lock(path, "experiment 'x'"):
            pass
    with launch_lock(path, "experiment 'x'"):  # released on exit
        pass


def test_a_lock_whose_holder_was_killed_is_free_at_once(tmp_path):
    path = tmp_path / "x.lock"
    script = (
        "import sys, time\nfrom pathlib import Path\nfrom ablate.launch.lock import launch_lock\n"
        f"with launch_lock(Path({str(path)!r}), 'x'):\n    print('held', flush=True)\n    time.sleep(600)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        with pytest.raises(LaunchLocked, match=f"by pid {holder.pid} "), launch_lock(path, "experiment 'x'"):
            pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=60)
    with launch_lock(path, "experiment 'x'"):  # kill -9 left the file with its pid, but no lock
        pass


def test_the_lock_folder_is_created_and_an_impossible_one_is_one_line(tmp_path):
    with launch_lock(tmp_path / "cache" / "locks" / "x.lock", "experiment 'x'"):
        pass
    (tmp_path / "file").write_text("")
    refused = pytest.raises(LaunchLocked, match="cannot open the launch lock .*file/x.lock: ")
    with refused, launch_lock(tmp_path / "file" / "x.lock", "experiment 'x'"):
        pass


def _lease_client(tmp_path):
    from mlflow.tracking import MlflowClient

    return MlflowClient(f"sqlite:///{tmp_path / 'lease.db'}")


def test_the_store_lease_is_taken_once_and_names_its_holder(tmp_path):
    from ablate.launch.lock import StoreLease

    client = _lease_client(tmp_path)
    first = StoreLease(client, "x", "experiment 'x'", "ablate run x.toml --tracking-uri http://u:pw0rd99@h")
    first.acquire()
    try:
        second = StoreLease(client, "x", "experiment 'x'", "ablate run x.toml")
        with pytest.raises(LaunchLocked) as refused:
            second.acquire()
        line = str(refused.value)
        assert f"by pid {os.getpid()} on {socket.gethostname()}, started " in line and "\n" not in line
        assert "pw0rd99" not in line and "http://u:***@h" in line
        StoreLease(client, "y", "experiment 'y'", "").acquire()  # another experiment: its own lease
    finally:
        first.release()
    again = StoreLease(client, "x", "experiment 'x'", "")  # released: free at once
    again.acquire()
    again.release()


def test_a_lease_whose_holder_stopped_renewing_or_died_lapses(tmp_path, capsys):
    from ablate.launch import lock

    client = _lease_client(tmp_path)
    stale = {"ablate.lease.host": "elsewhere", "ablate.lease.pid": "4242", "ablate.lease.started": "then"}
    old = time.time() - lock.LEASE_EXPIRY_S - 5
    client.create_experiment("ablate-lease-x", tags={**stale, "ablate.lease.heartbeat": str(old)})
    fresh = {**stale, "ablate.lease.heartbeat": str(time.time())}
    client.create_experiment("ablate-lease-y", tags=fresh)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    here = {"ablate.lease.host": socket.gethostname(), "ablate.lease.pid": str(dead.pid)}
    client.create_experiment("ablate-lease-z", tags={**here, "ablate.lease.heartbeat": str(time.time())})
    for name in ("x", "z"):
        lease = lock.StoreLease(client, name, f"experiment {name!r}", "")
        lease.acquire()
        assert client.get_experiment_by_name(f"ablate-lease-{name}").tags["ablate.lease.pid"] == str(os.getpid())
        lease.release()
    err = capsys.readouterr().err
    assert "lapsed (not renewed for" in err and f"lapsed (its process {dead.pid} on this machine is gone)" in err
    with pytest.raises(LaunchLocked, match="by pid 4242 on elsewhere, started then"):
        lock.StoreLease(client, "y", "experiment 'y'", "").acquire()


def test_two_lock_folders_one_store_lease_exactly_one_holds(tmp_path):
    """Two machines (two lock folders, so flock does not meet) launching one experiment on one store."""
    from ablate.launch.lock import held_launch

    client = _lease_client(tmp_path)
    refused = pytest.raises(LaunchLocked, match=f"by pid {os.getpid()} ")
    first = held_launch(tmp_path / "host-a" / "x.lock", "experiment 'x'", "a", client, "x")
    with first, refused, held_launch(tmp_path / "host-b" / "x.lock", "experiment 'x'", "b", client, "x"):
        pass
    with held_launch(tmp_path / "host-b" / "x.lock", "experiment 'x'", "b", client, "x"):
        pass
