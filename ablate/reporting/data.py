"""The report's data, computed once (``ReportData``): the ablation and every table its sentences, figures and CSV
files read, so that no section recomputes a number beside another."""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from ablate.launch.secrets import Shown
from ablate.reporting.comparisons import claims_table, comparisons
from ablate.reporting.results import Ablation
from ablate.reporting.tables import convergence_table, side_settings, trials_table


@dataclass(frozen=True)
class ReportData:
    """Everything a report says, computed once from one ``Ablation``."""

    ablation: Ablation
    convergence: pd.DataFrame
    """``tables/convergence.csv``: one row per variant."""
    claims: pd.DataFrame
    """``tables/claims.csv``: the primary claims, the Claims section's lines."""
    comparisons: pd.DataFrame
    """``tables/comparisons.csv``: every metric, exploratory; ``claim`` repeats ``claims`` on the primary rows."""
    trials: pd.DataFrame
    """``tables/trials.csv``: every trial the report uses, its stage and settings."""
    untuned: pd.DataFrame | None
    """The comparisons at the shared base values (a tuned ablation's "depends on the learning rate?"), or None."""
    command: Shown
    """The report's own command line, masked (``secrets.shown_command``)."""


def report_data(ablation: Ablation, command: Shown) -> ReportData:
    """Compute the report's tables once: the claims first, the comparisons' ``claim`` column from them."""
    claimed = side_settings(claims_table(ablation), ablation)
    untuned = comparisons(ablation.untuned, power=False) if ablation.untuned is not None else None
    return ReportData(
        ablation,
        convergence_table(ablation),
        claimed,
        comparisons(ablation, claims=claimed),
        trials_table(ablation),
        untuned,
        command,
    )
