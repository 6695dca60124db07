"""The report's primary claims as one family (issue 25): ``decide`` judges every primary comparison of a report
at the looks its seeds reach and says which variants need more. Pure (numpy and SciPy, no store), below the
launch layer, so the runner's rounds and the report call the same rule. docs/report.md#primary-claims argues
each choice; tests/test_claims.py measures the error rates.
"""

from ablate.claims.boundaries import ALPHA, Design, nominal_levels
from ablate.claims.family import (
    BETTER,
    EQUIVALENT,
    SEEDS_CAP,
    UNDETERMINED,
    WORSE,
    Round,
    decide,
    family_sentence,
    smallest_p,
)
from ablate.claims.permutation import Question, Sample, effect_interval, p_values, primary_question

__all__ = [
    "ALPHA",
    "BETTER",
    "EQUIVALENT",
    "SEEDS_CAP",
    "UNDETERMINED",
    "WORSE",
    "Design",
    "Question",
    "Round",
    "Sample",
    "decide",
    "effect_interval",
    "family_sentence",
    "nominal_levels",
    "p_values",
    "primary_question",
    "smallest_p",
]
