"""The report's variants as MLflow runs: one run per variant, nested under its launch's run, so MLflow's runs
table has a row per variant (its verdict) and its chart view a curve per variant (``curve/iqm``).

The store holds one set, the last report's (``log_variant_runs``), made anew each time: MLflow's params cannot
change and a metric logged again at a step adds a second point there.
"""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ablate.launch.mlflow_store import (
    ROLE_VARIANT,
    TAG_GENERATION,
    TAG_PARENT,
    TAG_ROLE,
    TAG_VARIANT,
    Store,
)

TAG_VERDICT = "ablate.verdict"
"""The verdict of the variant's primary claim against its reference; absent where it has none (the baseline)."""


@dataclass(frozen=True)
class VariantRecord:
    """What one variant's run holds, as plain values: the reporting layer computes it, this layer writes it."""

    name: str
    """The variant's name: the run's name and its ``ablate.variant`` tag."""
    params: dict[str, Any] = field(default_factory=dict)
    """Its settings, knob by knob, as the report's tables show them."""
    tags: dict[str, str] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    """Single values (its claim, its summary measures), logged at step 0."""
    series: dict[str, list[tuple[int, float]]] = field(default_factory=dict)
    """Metric series: per key, ``(episode, value)`` points (``curve/iqm``: its learning curve)."""
    artifacts: dict[str, bytes] = field(default_factory=dict)
    """Files by name (``learning_curve.png``: its curve with the band MLflow's charts cannot draw)."""


def variant_runs(store: Store, launch_id: str | None = None) -> list[Any]:
    """The variant runs nested under ``launch_id`` (every launch's: ``None``), MLflow ``Run`` objects, oldest first."""
    under = f" and tags.`{TAG_PARENT}` = '{launch_id}'" if launch_id else ""
    return store.all_runs(f"tags.`{TAG_ROLE}` = '{ROLE_VARIANT}'{under}")


def log_variant_runs(store: Store, launch_id: str, records: Sequence[VariantRecord]) -> list[str]:
    """Replace the experiment's variant runs (of any launch) by one run per record, nested under ``launch_id``;
    their run ids, in the records' order. The earlier runs are deleted only once every new one is written; a
    write that fails deletes what it wrote and leaves the earlier runs as they were."""
    earlier = [run.info.run_id for run in variant_runs(store)]
    generation = store.client.get_run(launch_id).data.tags.get(TAG_GENERATION, "")
    written: list[str] = []
    try:
        for record in records:
            tags = {TAG_PARENT: launch_id, TAG_ROLE: ROLE_VARIANT, TAG_VARIANT: record.name, TAG_GENERATION: generation}
            run = store.client.create_run(store.experiment_id(), run_name=record.name, tags=tags | record.tags)
            written.append(run.info.run_id)
            _fill(store, run.info.run_id, record)
    except BaseException:
        for run_id in written:
            with contextlib.suppress(Exception):  # the error that stopped the writes is the one to tell
                store.client.delete_run(run_id)
        raise
    for run_id in earlier:
        store.client.delete_run(run_id)
    return written


def _fill(store: Store, run_id: str, record: VariantRecord) -> None:
    """Log ``record``'s params, metrics and files on its new run, and close it."""
    store.log_values(run_id, record.metrics, record.params, series=record.series)
    if record.artifacts:
        with tempfile.TemporaryDirectory(prefix="ablate-variant-") as folder:
            for name, content in record.artifacts.items():
                (Path(folder) / name).write_bytes(content)
            store.client.log_artifacts(run_id, folder)
    store.client.set_terminated(run_id, "FINISHED")
