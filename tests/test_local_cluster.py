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
