"""The launch lock: one holder at a time, named in the refusal; never stale after its holder dies."""

import json
import os
import signal
import socket
import subprocess
import sys

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
