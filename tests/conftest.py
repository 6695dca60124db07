"""Shared fixtures: one local Ray for the whole session (starting it costs ~7 s)."""

import pytest


@pytest.fixture(scope="session")
def ray_cluster():
    import ray

    from ablate.scheduler import ensure_ray

    started = ensure_ray(None)
    yield
    if started:
        ray.shutdown()


@pytest.fixture
def tracking_uri(tmp_path):
    return f"sqlite:///{tmp_path / 'mlflow.db'}"
