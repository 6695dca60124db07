"""Every change ablate makes to a library's private internals, in one place: none of these has a public API or
setting (checked against Ray 2.60 and MLflow 3.17, the versions ``pyproject.toml`` allows and the README
names). ``tests/test_patches.py`` fails loudly when a library changes under one of them, before a user meets
the change as a silent loss (a password on Ray's job table, a server's answer dropped).

Each function here touches one private name and says why; the modules that need them (``scheduler``,
``tracking``, ``tools/local_cluster.py``) call these, never the private names. Ray is imported only inside the
Ray patches, so the tracker's process pays nothing for them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

RAY_TARGETS = (
    ("ray._private.utils", "get_entrypoint_name"),
    ("ray._private.ray_constants", "ENABLE_RAY_CLUSTER"),
    ("ray._private.worker", "print_to_stdstream"),
    ("ray._private.parameter", "RayParams"),
    ("ray._private.node", "Node"),
)
"""(module, name) of each private Ray name a patch below replaces or sets."""

MLFLOW_TARGETS = (
    ("mlflow.utils.rest_utils", "http_request"),
    ("mlflow.store.tracking.sqlalchemy_store", "SqlAlchemyStore"),
    ("mlflow.store.tracking.dbmodels.models", "SqlMetric"),
    ("mlflow.store.tracking.dbmodels.models", "SqlLatestMetric"),
    ("mlflow.store.artifact.artifact_repository_registry", "get_artifact_repository"),
)
"""(module, name) of each private MLflow name a patch below changes."""


@contextlib.contextmanager
def ray_entrypoint_shown(shown: Callable[[str], str]) -> Iterator[None]:
    """Ray records the driver's command line (``ps``'s, not ``sys.argv``) as its job's entrypoint, which the
    job table shows anyone on the cluster; ``ray.init`` takes no entrypoint. While ``ray.init`` runs, the
    recorded line is ``shown``'s form (a password in ``--tracking-uri`` masked)."""
    import ray._private.utils as utils

    original = utils.get_entrypoint_name
    utils.get_entrypoint_name = lambda: shown(original())
    try:
        yield
    finally:
        utils.get_entrypoint_name = original


_CLUSTERS_DEFAULT: bool | None = None


def ray_loopback_only(enabled: bool) -> None:
    """A local Ray takes this machine's network address, and its gcs_server, raylet and workers listen on
    every interface without authentication. Ray has no bind option, but with clusters disabled (its
    macOS/Windows default) a new node's address is 127.0.0.1 and every server binds to it alone. Its setting
    (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER``) is read once, when Ray is imported, so the constant is set; only
    read when this process starts a node: joined clusters and ``ray start`` are unaffected; restored for a join."""
    import ray._private.ray_constants as ray_constants

    global _CLUSTERS_DEFAULT
    if _CLUSTERS_DEFAULT is None:
        _CLUSTERS_DEFAULT = ray_constants.ENABLE_RAY_CLUSTER
    ray_constants.ENABLE_RAY_CLUSTER = False if enabled else _CLUSTERS_DEFAULT


@contextlib.contextmanager
def ray_lean_local_start() -> Iterator[None]:
    """A local ``ray.init`` without three Python processes a launch on one machine never uses: the autoscaler's
    monitor, the log monitor (``log_to_driver=False`` discards what it streams) and the dashboard's head (started
    even with ``include_dashboard=False``); ``ray.init`` took 1.8-2.0 s without them against 3.1-4.1 s
    (``docs/performance.md``). ``ray.init`` has no setting for any: while it runs, the node's parameters say no
    monitor and no log monitor (the settings ``ray start`` has) and the node skips its API server."""
    import ray._private.node as node
    import ray._private.parameter as parameter

    params_init, api_server = parameter.RayParams.__init__, node.Node.start_api_server

    def lean_params(self, *args: Any, **kwargs: Any) -> None:
        params_init(self, *args, **kwargs)
        self.no_monitor, self.include_log_monitor = True, False

    def no_api_server(self, *, include_dashboard: bool | None, raise_on_failure: bool) -> None:
        self._webui_url = None

    parameter.RayParams.__init__, node.Node.start_api_server = lean_params, no_api_server
    try:
        yield
    finally:
        parameter.RayParams.__init__, node.Node.start_api_server = params_init, api_server


def ray_raylet_errors_to(route: Callable[[list[str]], bool]) -> None:
    """Ray's driver prints the errors its raylets publish (``(raylet) A worker died or was killed ...``) to stdout
    from a thread of its own (``listen_error_messages``), past logging and ``log_to_driver=False``, through
    ``ray._private.worker.print_to_stdstream``: replaced once per process by one that hands a raylet's lines to
    ``route`` (``ray_logs.log_raylet_errors``) first. What ``route`` declines (returns False) and every other
    message print as Ray prints them."""
    import ray._private.worker as worker

    original = worker.print_to_stdstream
    if getattr(original, "ablate_routed", False):
        return

    def print_to_stdstream(data: dict[str, Any], *args: Any, **kwargs: Any) -> None:
        lines = [line for line in data.get("lines", []) if line.strip()]
        if data.get("pid") != "raylet" or not lines or not route(lines):
            original(data, *args, **kwargs)

    print_to_stdstream.ablate_routed = True  # type: ignore[attr-defined]
    worker.print_to_stdstream = print_to_stdstream


def ray_loopback_node(head: bool, address: str | None, port: int, cpus: float, temp_dir: str | None) -> Any:
    """One Ray node of this machine with every server on 127.0.0.1 (``tools/local_cluster.py``'s head and workers),
    built as ``ray start`` builds it (``RayParams``, ``Node``) with clusters disabled (``ray_loopback_only``):
    ``ray start`` binds a worker node to the machine's address on every interface and has no bind option. A head
    listens on ``port``; a worker joins the GCS at ``address``. Returns the running ``Node`` (``node_id``,
    ``gcs_address``, ``kill_all_processes``)."""
    ray_loopback_only(True)
    from ray._private.node import Node
    from ray._private.parameter import RayParams

    params = RayParams(node_ip_address="127.0.0.1", num_cpus=cpus, num_gpus=0, object_store_memory=150 * 2**20,
                       min_worker_port=0, max_worker_port=0, include_dashboard=False, temp_dir=temp_dir)  # fmt: skip
    if head:
        params.update(gcs_server_port=port)
    else:
        params.update(gcs_address=address, include_log_monitor=False, node_manager_port=0)
        params.dashboard_agent_listen_port = None
    return Node(params, head=head, shutdown_at_exit=True, spawn_reaper=True)


def mlflow_answers_kept() -> None:
    """MLflow's client retries a server error (500, 503) and then raises "too many 500 error responses",
    dropping the server's answer; with no retries left (``store_writes.fail_fast_writes``) it is told to return
    the answer instead, which its callers raise with the answer's text, so ``RetryingClient`` can say which
    error (a permission, a full disk) the store gave. ``raise_on_status`` is a parameter of MLflow's private
    ``http_request`` that no public setting reaches: its default is changed, in the writer's process only."""
    from mlflow.utils import rest_utils

    code = rest_utils.http_request.__code__
    names = code.co_varnames[: code.co_argcount]
    defaults = list(rest_utils.http_request.__defaults__ or ())
    if "raise_on_status" in names and defaults:
        defaults[names.index("raise_on_status") - (len(names) - len(defaults))] = False
        rest_utils.http_request.__defaults__ = tuple(defaults)


def mlflow_log_artifacts(artifact_uri: str, tracking_uri: str, folder: Any) -> None:
    """The files of ``folder`` written to a run's artifact folder ``artifact_uri`` (kept from the run's creation):
    ``MlflowClient.log_artifacts`` looks the run up first (~16 ms of SQLite CPU, a third of a short trial's
    tracking cost), and MLflow has no public upload to an artifact URI; its artifact repository does it."""
    from mlflow.store.artifact.artifact_repository_registry import get_artifact_repository

    get_artifact_repository(artifact_uri, tracking_uri=tracking_uri).log_artifacts(str(folder))


def mlflow_sql_store(client: Any) -> Any | None:
    """The SQL store (SQLite, PostgreSQL, MySQL) an ``MlflowClient`` writes to, for ``mlflow_insert_metrics``;
    ``None`` for a tracking server or a folder store. The client keeps it as ``_tracking_client.store``."""
    from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore

    store = getattr(getattr(client, "_tracking_client", None), "store", None)
    return store if isinstance(store, SqlAlchemyStore) else None


_IN_CHUNK = 500
"""Run ids per ``IN (...)`` of a query: under every database's limit of bound values."""


def mlflow_insert_metrics(store: Any, metrics: Mapping[str, Sequence[Any]]) -> None:
    """``metrics`` (``mlflow.entities.Metric``s by run id, of open runs) written into ``store`` in one transaction,
    as ``log_batch`` leaves them: a history row per value (a value given twice is written once) and each run's
    latest value per key (highest step, then timestamp, then value), through MLflow's own table models.
    ``log_batch`` builds an ORM object per value (~70 us of CPU each on SQLite, plus ~4 ms a call, one run a
    call): a CartPole trial's ~700 values cost the launch's one writer about a third of the trial's training."""
    from sqlalchemy.exc import IntegrityError

    rows: list[dict[str, Any]] = []
    seen: set[tuple] = set()
    latest: dict[tuple[str, str], dict[str, Any]] = {}
    for run_id, values in metrics.items():
        for metric in values:
            is_nan, value = store.sanitize_metric_value(metric.value)
            row = {"run_uuid": run_id, "key": metric.key, "value": value, "timestamp": metric.timestamp,
                   "step": metric.step, "is_nan": is_nan}  # fmt: skip
            identity = tuple(row.values())
            if identity in seen:
                continue
            seen.add(identity)
            rows.append(row)
            best = latest.get((run_id, metric.key))
            newest = (row["step"], row["timestamp"], value)
            if best is None or newest > (best["step"], best["timestamp"], best["value"]):
                latest[(run_id, metric.key)] = row
    if not rows:
        return
    try:
        _insert_metric_rows(store, list(metrics), rows, latest)
    except Exception as error:
        if not any(isinstance(e, IntegrityError) for e in _causes(error)):
            raise
        # A value some earlier write gave already (never in a launch: each point has an episode of its own):
        # MLflow's own path leaves the store as it was and adds the rest.
        for run_id, values in metrics.items():
            for i in range(0, len(values), 1000):  # log_batch's limit of values a call
                store.log_batch(run_id, metrics=list(values[i : i + 1000]), params=[], tags=[])


def _causes(error: BaseException | None) -> Iterator[BaseException]:
    while error is not None:
        yield error
        error = error.__cause__ or error.__context__


def _insert_metric_rows(store: Any, run_ids: list[str], rows: list[dict], latest: dict[tuple, dict]) -> None:
    from mlflow.store.tracking.dbmodels.models import SqlLatestMetric, SqlMetric
    from sqlalchemy import insert, select, update

    try:
        transaction = store.ManagedSessionMaker(read_only=False)
    except TypeError:  # MLflow before read replicas: every session may write
        transaction = store.ManagedSessionMaker()
    with transaction as session:
        # The tables' own INSERT (SQLAlchemy Core), not the models' bulk insert: no ORM bookkeeping per row.
        session.execute(insert(SqlMetric.__table__), rows)
        current: dict[tuple[str, str], tuple] = {}
        for i in range(0, len(run_ids), _IN_CHUNK):
            columns = (SqlLatestMetric.run_uuid, SqlLatestMetric.key, SqlLatestMetric.step, SqlLatestMetric.timestamp,
                       SqlLatestMetric.value)  # fmt: skip
            query = select(*columns).where(SqlLatestMetric.run_uuid.in_(run_ids[i : i + _IN_CHUNK]))
            current |= {(r[0], r[1]): tuple(r[2:]) for r in session.execute(query)}
        new = [row for at, row in latest.items() if at not in current]
        newer = [
            row
            for at, row in latest.items()
            if at in current and (row["step"], row["timestamp"], row["value"]) > current[at]
        ]
        if new:
            session.execute(insert(SqlLatestMetric.__table__), new)
        if newer:
            session.execute(update(SqlLatestMetric), newer)  # by primary key: (key, run_uuid) in each row
