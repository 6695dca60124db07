"""Trial keys and the part of a grid that `ablate run --only --seeds` selects."""

import pytest

from ablate.config import ConfigError, parse_experiment
from ablate.run.grid import expand, select, split_variants

EXPERIMENT = {
    "seeds": 3,
    "variants": [{"name": "base"}, {"name": "deep", "hidden_sizes": [16, 16]}],
    "grid": {"depth": [1, 2], "dropout": [0.0]},
}


def _trials():
    return expand(parse_experiment(EXPERIMENT, "exp.toml"))


def test_expand_is_variant_major_with_stable_keys():
    trials = _trials()
    assert [(t.variant, t.seed) for t in trials[:4]] == [("base", 0), ("base", 1), ("base", 2), ("deep", 0)]
    assert len(trials) == 12 and len({t.key for t in trials}) == 12
    assert [t.key for t in trials] == [t.key for t in _trials()]


def test_split_variants_keeps_grid_names_with_commas_whole():
    names = ["base", "deep", "depth=1,dropout=0.0", "depth=2,dropout=0.0"]
    assert split_variants("deep", names) == ["deep"]
    assert split_variants("base,depth=2,dropout=0.0,deep", names) == ["base", "depth=2,dropout=0.0", "deep"]
    with pytest.raises(ConfigError, match="--only: 'dep' is not a variant; valid: base, deep, depth=1,dropout=0.0"):
        split_variants("base,dep", names)


def test_select_by_variants_and_seeds():
    trials = _trials()
    assert select(trials, None, None) == trials
    chosen = select(trials, ["deep,depth=1,dropout=0.0"], [0, 2])
    assert [(t.variant, t.seed) for t in chosen] == [
        ("deep", 0),
        ("deep", 2),
        ("depth=1,dropout=0.0", 0),
        ("depth=1,dropout=0.0", 2),
    ]
    assert [t.seed for t in select(trials, ["base"], None)] == [0, 1, 2]
    assert len(select(trials, ["base", "deep"], [1])) == 2  # --only repeated
    with pytest.raises(ConfigError, match="--seeds: 7 is not a seed of this experiment; valid: 0, 1, 2"):
        select(trials, None, [7])
