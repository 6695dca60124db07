"""``make cluster-up``'s credentials: made once, this user's only, in the shape a client sources."""

import stat
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import local_cluster  # noqa: E402


def test_cluster_up_makes_its_credentials_once_readable_by_this_user_only(tmp_path):
    token_file, (user, password) = local_cluster.credentials_files(tmp_path)
    env_file = tmp_path / local_cluster.ENV_FILE
    for path in (token_file, env_file):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
    text = env_file.read_text()
    assert f"export MLFLOW_TRACKING_USERNAME={user}\n" in text and f"MLFLOW_TRACKING_PASSWORD={password}\n" in text
    assert f"export RAY_AUTH_TOKEN_PATH={token_file.resolve()}\n" in text and "RAY_AUTH_MODE=token" in text
    assert len(password) >= 24 and len(token_file.read_text().strip()) == 64
    assert local_cluster.credentials_files(tmp_path) == (token_file, (user, password))  # kept: the admin exists
    assert local_cluster.ray_token_env(token_file) == {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token_file)}


def test_cluster_up_keeps_an_admin_apart_from_the_drivers_account(tmp_path):
    _, (user, password) = local_cluster.credentials_files(tmp_path)
    admin, admin_password = local_cluster.admin_credentials(tmp_path)
    assert (admin, user) == ("admin", "ablate") and admin_password != password and len(admin_password) >= 24
    assert stat.S_IMODE((tmp_path / local_cluster.ADMIN_FILE).stat().st_mode) == 0o600
    assert local_cluster.admin_credentials(tmp_path) == (admin, admin_password)  # made once


def test_the_servers_folders_and_log_are_their_owners_only(tmp_path):
    folder = local_cluster.private_folder(tmp_path / "a" / "b")
    with local_cluster.private_log(folder / "cluster.log") as log:
        log.write("x\n")
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert stat.S_IMODE((folder / "cluster.log").stat().st_mode) == 0o600
