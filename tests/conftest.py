"""Shared fixtures: one local Ray for the whole session (starting it costs ~7 s), a fresh MLflow store in
~0.1 s (tests/stores.py), and a quiet way to run on them."""

import pytest
from stores import fresh_store
from views import Clock


@pytest.fixture(scope="session")
def ray_cluster():
    import ray

    from ablate.launch.scheduler import ensure_ray

    started = ensure_ray(None)
    yield
    if started:
        ray.shutdown()


@pytest.fixture(scope="session")
def ray_address(ray_cluster):
    """The session's Ray, for a child ``ablate run`` to join (``RAY_ADDRESS``) instead of starting its own:
    ~10 s less per child on 2 cores. Children that must start their own Ray are marked ``e2e``."""
    import ray

    return ray.get_runtime_context().gcs_address


@pytest.fixture
def tracking_uri(tmp_path):
    return fresh_store(tmp_path / "mlflow.db")


@pytest.fixture(scope="session")
def run_quiet(ray_cluster):
    """``run_plan`` as tests call it: into ``tracking_uri``, Tune's files under ``folder``, no live view."""
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    def run(experiment, folder, tracking_uri, **kwargs):
        return run_plan(
            LaunchPlan(
                experiment, tracking_uri=tracking_uri, storage_path=str(folder / "ray"), show_progress=False, **kwargs
            )
        )

    return run


@pytest.fixture
def clock(monkeypatch):
    """``time.monotonic`` (the live view's and the estimate's clock) moved by hand: ``clock.now += 5``."""
    import time

    fake = Clock()
    monkeypatch.setattr(time, "monotonic", fake)
    return fake
