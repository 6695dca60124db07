"""A Ray cluster and an MLflow tracking server on this machine, every port on 127.0.0.1: ``make cluster-up``,
``make cluster-down``, and the nodes of ``make test-cluster``.

``node``: one Ray node (head, or a worker joining ``--address``) in the foreground until SIGTERM, SIGINT or
end of stdin, then all of its processes are killed (to a cluster, a node that died). ``up``/``down``: a head
node and ``mlflow server`` (served artifacts) in the background, their process ids in ``.cluster/state.json``.
Locked as a team's cluster should be: the Ray nodes require a token (``RAY_AUTH_MODE=token``, the token in a
file) and the server runs MLflow's basic-auth app; secrets travel in files and the environment, never in argv.
``ray start``/``ray stop`` are not used: ``ray stop`` kills every Ray on the machine, not just this one, and
``ray start`` binds a worker node to the machine's address on every interface.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STATE = ROOT / ".cluster" / "state.json"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_node(head: bool, address: str | None, port: int, cpus: float, temp_dir: str | None, detached: bool) -> int:
    """Start one node bound to 127.0.0.1, print ``ready <node id> <gcs address>``, wait for SIGTERM or SIGINT
    (or, unless ``detached``, the end of stdin: the parent died), then kill the node's processes."""
    sys.path.insert(0, str(ROOT))  # run from a checkout, installed or not
    from ablate.launch.patches import ray_loopback_node  # Ray's private node API, behind ablate's one fence

    node = ray_loopback_node(head, address, port, cpus, temp_dir)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    if not detached:
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    print(f"ready {node.node_id} {node.gcs_address}", flush=True)
    stop.wait()
    node.kill_all_processes(check_alive=False, allow_graceful=False)
    return 0


def wait_http(url: str, timeout_s: float, process: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=5) as response:
                if response.status == 200:
                    return
        except OSError:
            pass
        if process is not None and process.poll() is not None:
            raise RuntimeError(f"{process.args[0]} exited with code {process.returncode} before {url} answered")
        if time.monotonic() > deadline:
            raise TimeoutError(f"{url} did not answer within {timeout_s:.0f} s")
        time.sleep(0.2)


AUTH_CONFIG = """[mlflow]
default_permission = READ
database_uri = sqlite:///{folder}/basic_auth.db
admin_username = {username}
authorization_function = mlflow.server.auth:authenticate_request_basic_auth
# A checked password is remembered this long: MLflow hashes every request's password (PBKDF2, ~1 s of CPU on a
# busy machine), which made each of the driver's writes wait on it.
auth_cache_ttl_seconds = 300
"""


def mlflow_server(
    folder: Path, port: int, backend: str | None = None, log=None, auth: tuple[str, str] | None = None
) -> subprocess.Popen:
    """``mlflow server`` on 127.0.0.1:``port``, serving artifacts from ``folder/artifacts``. ``auth``: (user,
    password) of its admin, and the server runs MLflow's basic-auth app (users kept in ``folder``). The store
    URI and the password reach the server through its environment, not its command line (``ps`` shows that)."""
    private_folder(folder)
    env = dict(os.environ, MLFLOW_BACKEND_STORE_URI=backend or f"sqlite:///{folder / 'mlflow.db'}")
    command = [str(Path(sys.executable).parent / "mlflow"), "server"]
    if auth is not None:
        config = write_secret(folder / "basic_auth.ini", AUTH_CONFIG.format(folder=folder.resolve(), username=auth[0]))
        env.update(
            MLFLOW_AUTH_CONFIG_PATH=str(config),
            MLFLOW_AUTH_ADMIN_PASSWORD=auth[1],
            MLFLOW_FLASK_SERVER_SECRET_KEY=secrets.token_hex(16),
        )
        command += ["--app-name", "basic-auth"]
    command += [
        "--serve-artifacts",
        "--artifacts-destination",
        str(folder / "artifacts"),
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--workers",
        "1",
    ]
    # umask 077: the store, the users' database and every artifact the server writes, its owner's only
    return subprocess.Popen(
        command,
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
        env=env,
        umask=0o077,
    )


def private_folder(path: Path) -> Path:
    """``path`` (and missing parents) as a folder only its owner may list or enter (0700)."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    path.chmod(0o700)
    return path


def private_log(path: Path):
    """``path`` opened for appending, readable by its owner only (0600): a server's log names its users."""
    private_folder(path.parent)
    return os.fdopen(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600), "a")


def create_user(url: str, admin: tuple[str, str], user: str, password: str) -> None:
    """As the server's ``admin`` (user, password), the account ``user`` (not an admin; MLflow gives it MANAGE
    on the experiments it creates and the server's ``default_permission`` on the others). Kept if it exists."""
    import base64
    import urllib.error

    request = urllib.request.Request(
        f"{url}/api/2.0/mlflow/users/create",
        data=json.dumps({"username": user, "password": password}).encode(),
        headers={
            "Content-Type": "application/json",
            "Authorization": "Basic " + base64.b64encode(f"{admin[0]}:{admin[1]}".encode()).decode(),
        },
        method="POST",
    )
    try:
        with urllib.request.urlopen(request, timeout=120):
            pass
    except urllib.error.HTTPError as error:
        if error.code != 400 or b"already exists" not in error.read():
            raise RuntimeError(f"creating MLflow user {user!r} as {admin[0]!r}: HTTP {error.code}") from None


def ray_token_env(token_file: Path) -> dict[str, str]:
    """What a Ray node or driver needs in its environment to join a cluster that requires ``token_file``'s token."""
    return {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token_file)}


def write_secret(path: Path, text: str) -> Path:
    """``text`` into ``path``, readable by this user only."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.touch(mode=0o600)
    path.chmod(0o600)
    path.write_text(text)
    return path


def start_node_process(
    head: bool,
    cpus: float,
    port: int = 0,
    address: str | None = None,
    wrap: list[str] | None = None,
    log=None,
    detached: bool = False,
    token_file: Path | None = None,
) -> tuple[subprocess.Popen, str, str]:
    """``node`` in a child process (inside ``wrap``, e.g. an ``unshare`` command); returns it, its node id and
    the cluster's GCS address once the node is up. ``token_file``: the node requires (a head) or presents (a
    worker) that Ray token."""
    command = [sys.executable, str(Path(__file__).resolve()), "node", "--cpus", str(cpus)]
    command += ["--head", "--port", str(port)] if head else ["--address", address]
    command += ["--detached"] if detached else []
    process = subprocess.Popen(
        [*(wrap or []), *command],
        stdin=subprocess.DEVNULL if detached else subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=log,
        text=True,
        start_new_session=True,
        env=dict(os.environ, **(ray_token_env(token_file) if token_file else {})),
    )
    line = process.stdout.readline().split()
    if len(line) != 3 or line[0] != "ready":
        process.kill()
        raise RuntimeError(f"the Ray node did not start (exit code {process.wait()}); see its log")
    return process, line[1], line[2]


def finish_process(process: subprocess.Popen, timeout_s: float = 240) -> tuple[int, str]:
    """Wait for ``process`` (text output piped); killed if it outlives ``timeout_s``. Its exit code and output."""
    try:
        output, _ = process.communicate(timeout=timeout_s)
    finally:
        if process.poll() is None:
            process.kill()
    return process.returncode, output


def stop_process(process: subprocess.Popen, timeout_s: float = 60) -> None:
    """SIGTERM, then SIGKILL of its whole process group."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def up(ray_port: int, mlflow_port: int, cpus: float) -> int:
    if STATE.exists():
        print(f"a local cluster is already up ({STATE}); make cluster-down first", file=sys.stderr)
        return 1
    folder = private_folder(STATE.parent)
    token_file, credentials = credentials_files(folder)
    admin = admin_credentials(folder)
    log = private_log(folder / "cluster.log")  # stays open in the children
    server = mlflow_server(folder / "mlflow", mlflow_port, log=log, auth=admin)
    try:
        head, node_id, gcs = start_node_process(
            True, cpus, port=ray_port, log=log, detached=True, token_file=token_file
        )
    except RuntimeError as error:
        stop_process(server)
        print(f"{error} ({folder}/cluster.log)", file=sys.stderr)
        return 1
    STATE.write_text(
        json.dumps({"pids": [head.pid, server.pid], "ray": gcs, "mlflow": f"http://127.0.0.1:{mlflow_port}"})
    )
    try:
        wait_http(f"http://127.0.0.1:{mlflow_port}/health", 120, server)
        create_user(f"http://127.0.0.1:{mlflow_port}", admin, *credentials)
    except (RuntimeError, TimeoutError) as error:
        down()
        print(f"mlflow server: {error} (port {mlflow_port} taken? see {folder}/cluster.log)", file=sys.stderr)
        return 1
    print(f"Ray head {gcs} (node {node_id[:8]}), MLflow http://127.0.0.1:{mlflow_port}; logs in {folder}/cluster.log")
    print(f"both require credentials: . {folder / ENV_FILE} (MLflow user {credentials[0]!r}, the Ray token's file)")
    print(f"the MLflow admin (accounts, permissions; not for runs) is in {folder / ADMIN_FILE}")
    print(f"  ablate run experiments/cartpole.toml --address {gcs} --tracking-uri http://127.0.0.1:{mlflow_port}")
    return 0


ENV_FILE = "credentials.env"
ADMIN_FILE = "admin.env"
ADMIN_USER = "admin"


def admin_credentials(folder: Path) -> tuple[str, str]:
    """The MLflow admin (user, password) of ``make cluster-up``: made once (random) in ``folder/admin.env``
    (this user only), for administration: the drivers log in as the account of ``credentials.env``."""
    path = folder / ADMIN_FILE
    if not path.is_file():
        write_secret(
            path,
            f"export MLFLOW_TRACKING_USERNAME={ADMIN_USER}\n"
            f"export MLFLOW_TRACKING_PASSWORD={secrets.token_urlsafe(24)}\n",
        )
    values = dict(line.removeprefix("export ").split("=", 1) for line in path.read_text().splitlines() if "=" in line)
    return values["MLFLOW_TRACKING_USERNAME"], values["MLFLOW_TRACKING_PASSWORD"]


def credentials_files(folder: Path) -> tuple[Path, tuple[str, str]]:
    """The Ray token's file and the drivers' MLflow account (user, password; not an admin) of ``make
    cluster-up``, made once (random) and kept in ``folder`` (this user only), with ``credentials.env``: the
    environment a client needs."""
    token_file = folder / "ray_token"
    if not token_file.is_file():
        write_secret(token_file, secrets.token_hex(32) + "\n")
    env_file = folder / ENV_FILE
    if not env_file.is_file():
        write_secret(
            env_file,
            f"export MLFLOW_TRACKING_USERNAME=ablate\nexport MLFLOW_TRACKING_PASSWORD={secrets.token_urlsafe(24)}\n"
            f"export RAY_AUTH_MODE=token\nexport RAY_AUTH_TOKEN_PATH={token_file.resolve()}\n",
        )
    values = dict(
        line.removeprefix("export ").split("=", 1) for line in env_file.read_text().splitlines() if "=" in line
    )
    return token_file, (values["MLFLOW_TRACKING_USERNAME"], values["MLFLOW_TRACKING_PASSWORD"])


def down() -> int:
    if not STATE.exists():
        print("no local cluster is up")
        return 0
    state = json.loads(STATE.read_text())
    for pid in state["pids"]:
        try:
            os.killpg(pid, signal.SIGTERM)
        except ProcessLookupError:
            continue
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                os.killpg(pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.2)
        else:
            os.killpg(pid, signal.SIGKILL)
    STATE.unlink()
    print(f"stopped the Ray head {state['ray']} and MLflow {state['mlflow']}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)
    node = commands.add_parser("node")
    node.add_argument("--head", action="store_true")
    node.add_argument("--address")
    node.add_argument("--port", type=int, default=0)
    node.add_argument("--cpus", type=float, default=1)
    node.add_argument("--temp-dir")
    node.add_argument("--detached", action="store_true", help="keep running when stdin ends (make cluster-up)")
    start = commands.add_parser("up")
    start.add_argument("--ray-port", type=int, default=6390)
    start.add_argument("--mlflow-port", type=int, default=5050)
    start.add_argument("--cpus", type=float, default=os.cpu_count())
    commands.add_parser("down")
    args = parser.parse_args()
    if args.command == "node":
        return run_node(args.head, args.address, args.port or free_port(), args.cpus, args.temp_dir, args.detached)
    if args.command == "up":
        return up(args.ray_port, args.mlflow_port, args.cpus)
    return down()


if __name__ == "__main__":
    raise SystemExit(main())
