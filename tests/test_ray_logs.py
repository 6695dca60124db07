"""Ray's own messages into the launch's log: a raylet's error (a dead worker) as one line on the terminal."""

from ablate.launch import ray_logs

RAYLET = (
    "A worker died or was killed while executing a task by an unexpected system error. To troubleshoot the "
    "problem, check the logs for the dead worker. Lease ID: 0200 Worker ID: 1253 Node ID: 3493 Worker IP address: "
    "127.0.0.1 Worker port: 35219 Worker PID: 11668 Worker exit type: SYSTEM_ERROR Worker exit detail: Worker "
    "unexpectedly exits with a connection error code 2. End of file. Some common causes include: (1) the OOM killer"
)


def test_a_raylet_error_goes_to_the_launchs_log_and_one_line_to_the_terminal(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(ray_logs, "_launch_log", None)
    assert ray_logs.log_raylet_errors([RAYLET]) is False  # before any launch: Ray prints it as it does
    log = tmp_path / "ray_results" / "x-1.log"
    with ray_logs.tune_logs_to(log):
        assert ray_logs.log_raylet_errors([RAYLET]) is True
    assert ray_logs.log_raylet_errors([RAYLET]) is True  # after the trials: still the launch's log
    assert log.read_text().count("raylet ERROR A worker died") == 2 and "Worker exit detail" in log.read_text()
    lines = capsys.readouterr().err.splitlines()
    assert (
        lines
        == [
            "Ray: a worker died or was killed while executing a task by an unexpected system error "
            f"(pid 11668, SYSTEM_ERROR); Ray's message in full: {log}"
        ]
        * 2
    )
