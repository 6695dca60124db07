"""The figures' data (not their pixels): what each one draws."""

import numpy as np
import pandas as pd
from test_comparisons import _frame

from ablate.reporting.figures import per_seed_points


def test_never_solved_seeds_are_drawn_at_the_budget_as_bounds():
    # issue 19 item 6: Figure 4 drew never-solved seeds beyond the budget line, where they read as real values
    ablation = _frame({"a": [40, 60, None], "b": [None, None, 90]}, budget=100)
    points = per_seed_points(ablation).set_index(["variant", "seed"])
    assert points.loc[("a", 2), "bound"] and points.loc[("a", 2), "x"] == 100
    assert list(points[points.bound].x) == [100.0, 100.0, 100.0] and points.x.max() == 100
    assert not points.loc[("b", 2), "bound"] and points.loc[("b", 2), "x"] == 90
    never = _frame({"a": [None, None], "b": [None, None]}, budget=100)  # no seed solved: final returns
    assert not per_seed_points(never).bound.any()
    assert isinstance(per_seed_points(never), pd.DataFrame) and np.isfinite(per_seed_points(never).x).all()
