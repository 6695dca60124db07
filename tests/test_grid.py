"""Trial keys and the part of a grid that `ablate run --only --seeds` selects."""

import pytest

from ablate.config import ConfigError
from ablate.experiment import parse_experiment
from ablate.launch.grid import expand, select, split_variants

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


# --- [tune] (issue 19): stage lists, and keys of untuned trials unchanged ---


def _untuned_and_tuned(path):
    import tomllib

    data = tomllib.loads(path.read_text())
    data.pop("tune", None)
    tuned = dict(data, tune={"learning_rate": [0.01, 0.1], "seeds": 2, "max_episodes": 50})
    return parse_experiment(data, str(path)), parse_experiment(tuned, str(path))


@pytest.mark.parametrize("name", ["cartpole", "smoke", "pong", "pong-smoke"])
def test_tune_leaves_every_untuned_trial_key_unchanged(name):
    from pathlib import Path

    untuned, tuned = _untuned_and_tuned(Path(__file__).parent.parent / "experiments" / f"{name}.toml")
    assert untuned.tune is None
    # The base-value trials of a tuned launch are exactly the untuned ablation's: same keys, same configs.
    assert [(t.key, t.config) for t in expand(tuned)] == [(t.key, t.config) for t in expand(untuned)]


def test_tuning_trials_use_tuning_seeds_disjoint_from_evaluation_seeds():
    from ablate.launch.grid import chosen_trials, tuning_trials

    experiment = parse_experiment(
        {
            "seeds": [0, 1, 9999],
            "variants": [{"name": "a"}, {"name": "own", "learning_rate": 0.001}],
            "tune": {"learning_rate": [0.01, 0.1], "seeds": 3, "max_episodes": 40},
        },
        "exp.toml",
    )
    tuning = tuning_trials(experiment)
    # "own" sets learning_rate itself: it has no stage 1.
    assert len(tuning) == 2 * 3 and {t.variant for t in tuning} == {"a"}
    assert {t.seed for t in tuning} == {10_000, 10_001, 10_002}
    assert not {t.seed for t in tuning} & set(experiment.seeds)
    assert all(t.stage == "tune" and t.config.max_episodes == 40 and not t.config.record_video for t in tuning)
    evaluation = expand(experiment)
    assert not {t.key for t in tuning} & {t.key for t in evaluation}
    chosen = chosen_trials(experiment, {"a": {"learning_rate": 0.1}})
    assert [(t.variant, t.seed, t.config.learning_rate, t.stage) for t in chosen] == [
        ("a", s, 0.1, "eval") for s in (0, 1, 9999)
    ]
    at_base = chosen_trials(experiment, {"a": {"learning_rate": 0.03}})
    assert [t.key for t in at_base] == [t.key for t in evaluation if t.variant == "a"]


def test_chosen_trials_of_every_round_are_the_keys_later_rounds_run_at_the_choice():
    from ablate.launch.grid import chosen_trials

    experiment = parse_experiment(
        {"seeds": {"start": 2, "step": 2, "max": 6}, "variants": [{"name": "a"}], "tune": {"learning_rate": [0.1]}},
        "exp.toml",
    )
    first = chosen_trials(experiment, {"a": {"learning_rate": 0.1}})
    every = chosen_trials(experiment, {"a": {"learning_rate": 0.1}}, every_round=True)
    assert [t.seed for t in first] == [0, 1] and [t.seed for t in every] == list(range(6))
    assert [t.key for t in every[:2]] == [t.key for t in first]
    at_base = chosen_trials(experiment, {"a": {"learning_rate": experiment.base.learning_rate}}, every_round=True)
    assert [t.key for t in at_base] == [t.key for t in expand(experiment, every_round=True)]
