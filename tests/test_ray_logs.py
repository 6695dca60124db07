"""Ray's own messages into the launch's log: a raylet's error (a dead worker) as one line on the terminal."""

from types import SimpleNamespace

from ablate.launch import ray_logs

RAYLET = (
    "A worker died or was killed while executing a task by an unexpected system error. To troubleshoot the "
    "problem, check the logs for the dead worker. Lease ID: 0200 Worker ID: 1253 Node ID: 3493 Worker IP address: "
    "127.0.0.1 Worker port: 35219 Worker PID: 11668 Worker exit type: SYSTEM_ERROR Worker exit detail: Worker "
    "unexpectedly exits with a connection error code 2. End of file. Some common causes include: (1) the OOM killer"
)


def test_a_raylet_error_goes_to_the_launchs_log_and_one_line_to_the_terminal(tmp_path, monkeypatch, capsys):
    printed = []
    worker = SimpleNamespace(print_to_stdstream=lambda data, ignore_prefix: printed.append(data))
    monkeypatch.setattr(ray_logs, "_launch_log", None)
    ray_logs.route_raylet_errors(worker)
    ray_logs.route_raylet_errors(worker)  # once per process: a second launch does not wrap it again
    raylet = {"lines": [RAYLET], "pid": "raylet", "is_err": False}
    worker.print_to_stdstream(raylet, ignore_prefix=False)  # before any launch: as Ray prints it
    assert printed == [raylet]
    log = tmp_path / "ray_results" / "x-1.log"
    with ray_logs.tune_logs_to(log):
        worker.print_to_stdstream(raylet, ignore_prefix=False)
    worker.print_to_stdstream(raylet, ignore_prefix=False)  # after the trials: still the launch's log
    other = {"lines": ["hello"], "pid": 42, "is_err": False}
    worker.print_to_stdstream(other, ignore_prefix=False)
    assert printed == [raylet, other]
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
