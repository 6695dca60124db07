"""``launch.patches``: each private name of Ray and MLflow that ablate changes still exists in the installed
library and still has the shape the patch relies on. A library upgrade that moves one fails here, by name,
instead of silently (a password back on Ray's job table, a server's answer dropped, servers on every interface).
"""

import importlib
import inspect
import subprocess
import sys

import pytest

from ablate.launch import patches


@pytest.mark.parametrize(("module", "name"), [*patches.RAY_TARGETS, *patches.MLFLOW_TARGETS])
def test_every_private_name_a_patch_touches_exists(module, name):
    assert hasattr(importlib.import_module(module), name), (
        f"{module}.{name} is gone from the installed library: ablate.launch.patches must be rewritten "
        "(see its docstring) before this version is allowed in pyproject.toml"
    )


def test_ray_names_have_the_shapes_the_patches_use():
    import ray._private.ray_constants as constants
    import ray._private.utils as utils
    import ray._private.worker as worker

    assert isinstance(constants.ENABLE_RAY_CLUSTER, bool)
    assert callable(utils.get_entrypoint_name) and isinstance(utils.get_entrypoint_name(), str)
    assert list(inspect.signature(worker.print_to_stdstream).parameters)[0] == "data"
    # services reads the constant when it starts a node: the loopback patch has its effect there.
    import ray._private.services as services

    assert "ENABLE_RAY_CLUSTER" in inspect.getsource(services)


def test_the_entrypoint_patch_masks_and_restores():
    import ray._private.utils as utils

    original = utils.get_entrypoint_name
    with patches.ray_entrypoint_shown(lambda line: "MASKED"):
        assert utils.get_entrypoint_name() == "MASKED"
    assert utils.get_entrypoint_name is original


def test_the_mlflow_patch_turns_off_raise_on_status_in_its_process_only():
    code = (
        "import inspect; from mlflow.utils import rest_utils; from ablate.launch import patches; "
        "before = inspect.signature(rest_utils.http_request).parameters['raise_on_status'].default; "
        "patches.mlflow_answers_kept(); "
        "after = inspect.signature(rest_utils.http_request).parameters['raise_on_status'].default; "
        "print(before, after)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "False"], out


def test_raylet_errors_go_to_the_route_once_per_process_and_the_rest_print_as_ray_prints(monkeypatch):
    import ray._private.worker as worker

    assert list(inspect.signature(worker.print_to_stdstream).parameters) == ["data", "ignore_prefix"]
    assert "print_to_stdstream(" in inspect.getsource(worker.listen_error_messages)  # where Ray calls it
    printed, routed = [], []
    monkeypatch.setattr(worker, "print_to_stdstream", lambda data, ignore_prefix: printed.append(data))
    patches.ray_raylet_errors_to(lambda lines: routed.append(lines) or len(routed) > 1)
    patches.ray_raylet_errors_to(lambda lines: 1 / 0)  # once per process: a second launch does not wrap it again
    raylet, other = {"lines": ["died", " "], "pid": "raylet", "is_err": False}, {"lines": ["hi"], "pid": 42}
    for data in (raylet, raylet, other):
        worker.print_to_stdstream(data, ignore_prefix=False)
    assert routed == [["died"], ["died"]] and printed == [raylet, other]  # the first declined: printed by Ray


def test_artifacts_are_logged_straight_to_a_runs_artifact_uri(tmp_path):
    from mlflow.store.artifact.artifact_repository_registry import get_artifact_repository

    assert list(inspect.signature(get_artifact_repository).parameters)[:2] == ["artifact_uri", "tracking_uri"]
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder" / "episodes.csv").write_text("x\n")
    patches.mlflow_log_artifacts((tmp_path / "artifacts").as_uri(), "sqlite:///unused.db", tmp_path / "folder")
    assert (tmp_path / "artifacts" / "episodes.csv").read_text() == "x\n"


def test_the_loopback_node_names_have_the_shapes_it_uses():
    import ray._private.node as node
    import ray._private.parameter as parameter

    params = parameter.RayParams(
        node_ip_address="127.0.0.1", num_cpus=1, num_gpus=0, object_store_memory=2**27, min_worker_port=0,
        max_worker_port=0, include_dashboard=False, temp_dir=None,
    )  # fmt: skip
    params.update(gcs_server_port=1, gcs_address="127.0.0.1:1", include_log_monitor=False, node_manager_port=0)
    assert hasattr(params, "dashboard_agent_listen_port")
    assert {"ray_params", "head", "shutdown_at_exit", "spawn_reaper"} <= set(inspect.signature(node.Node).parameters)
    assert {"node_id", "gcs_address", "kill_all_processes"} <= set(dir(node.Node))


def test_no_other_module_names_a_private_library_internal():
    from pathlib import Path

    root = Path(patches.__file__).parents[2]
    offenders = [
        str(path.relative_to(root))
        for folder in ("ablate", "tools", "benchmarks")
        for path in (root / folder).rglob("*.py")
        if path.name != "patches.py"
        for line in path.read_text().splitlines()
        if any(name in line for name in ("ray._private", "mlflow.store", "mlflow.utils", "__defaults__ ="))
        and not line.strip().startswith(("#", "(", '"'))
    ]
    assert offenders == []


def test_the_lean_start_names_have_the_shapes_it_sets():
    import ray._private.node as node
    import ray._private.parameter as parameter

    params = parameter.RayParams()
    assert params.no_monitor is False and params.include_log_monitor in (None, True)
    assert set(inspect.signature(node.Node.start_api_server).parameters) == {
        "self",
        "include_dashboard",
        "raise_on_failure",
    }
    source = inspect.getsource(node.Node)
    # The node reads both settings and calls its API server from these places: the patch has its effect there.
    assert "self._ray_params.no_monitor" in source and "self._ray_params.include_log_monitor" in source
    assert "self.start_api_server(" in source


def test_a_lean_local_ray_starts_without_the_monitor_the_log_monitor_or_the_dashboard_and_runs_a_task():
    code = (
        "import ray; from ablate.launch.scheduler import ensure_ray; ensure_ray(None); "
        "node = ray._private.worker._global_node; "
        "print(sorted(node.all_processes)); print(ray.get(ray.remote(lambda: 7).remote()))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120).stdout
    kinds, answer = out.splitlines()[-2:]
    assert answer == "7"
    for absent in ("monitor", "log_monitor", "dashboard"):
        assert f"'{absent}'" not in kinds, kinds
    assert "'raylet'" in kinds and "'gcs_server'" in kinds, kinds


def test_metrics_written_in_bulk_read_back_as_log_batch_leaves_them(tracking_uri):
    """Two runs given the same values, one through ``log_batch``, one through ``mlflow_insert_metrics``: the same
    histories and latest values, across two writes (an older value never replaces a newer latest one), with a
    value given twice, NaN and infinities, and steps out of order."""
    from mlflow.entities import Metric
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri)
    experiment = client.create_experiment("bulk")
    by_batch, in_bulk = (client.create_run(experiment).info.run_id for _ in range(2))
    other = client.create_run(experiment).info.run_id  # a run of the same write with keys of its own
    first = [Metric("a", 1.0, 10, 2), Metric("a", 1.0, 10, 2), Metric("a", 3.0, 11, 1), Metric("b", float("nan"), 9, 0)]
    second = [Metric("a", 0.5, 5, 1), Metric("b", float("inf"), 12, 4), Metric("c", -float("inf"), 13, 0)]
    store = patches.mlflow_sql_store(client)
    assert store is not None
    for values in (first, second):
        client.log_batch(by_batch, metrics=values)
        patches.mlflow_insert_metrics(store, {in_bulk: values, other: [Metric("z", 7.0, 1, 1)]})

    def history(run_id):
        keys = client.get_run(run_id).data.metrics
        values = {k: client.get_metric_history(run_id, k) for k in keys}
        return {k: sorted((m.step, m.timestamp, str(m.value)) for m in v) for k, v in values.items()}

    assert client.get_run(in_bulk).data.metrics.keys() == {"a", "b", "c"}
    assert str(client.get_run(in_bulk).data.metrics) == str(client.get_run(by_batch).data.metrics)
    assert history(in_bulk) == history(by_batch)
    assert client.get_run(other).data.metrics == {"z": 7.0}
    assert patches.mlflow_sql_store(object()) is None  # not a client of an SQL store: the caller logs batches
