"""The shipped experiment files: the default Pong ablation's grid, and the Pong smoke ablation end to end,
its tuning stage included, through real Ray and a real MLflow store (the report is tested with the report)."""

from pathlib import Path

from ablate.env_spec import profile_of
from ablate.experiment import load_experiment
from ablate.launch.grid import expand
from ablate.reporting.reader import RunReader

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"


def test_pong_ablation_is_the_cnn_against_the_mlp_with_five_seeds_and_long_trials():
    experiment = load_experiment(EXPERIMENTS / "pong.toml")
    assert len(experiment.seeds) >= 5 and experiment.base.gamma == 0.99 and profile_of(experiment.base).resets_on_score
    variants = {v.name: v.config for v in experiment.variants}
    assert {name: config.model.architecture for name, config in variants.items()} == {"cnn": "cnn", "mlp": "mlp"}
    assert all(config.max_episodes >= 300 for config in variants.values())
    # Bench's Pong section reads these two variants' settings (emulators, action set) for its speed trials.
    assert variants["cnn"].model.hidden_sizes == variants["mlp"].model.hidden_sizes
    # Each arm at its own rate, tuned on 2 seeds over at least 300 episodes (Pong's curves leave -20.5 by then).
    assert experiment.tune is not None
    assert dict(experiment.tune.knobs).keys() == {"learning_rate"} and len(experiment.tune.seeds) >= 2
    assert (experiment.tune.max_episodes or variants["cnn"].max_episodes) >= 300


def test_pong_knobs_changes_each_knob_of_each_architecture_alone():
    experiment = load_experiment(EXPERIMENTS / "pong-knobs.toml")
    assert len(experiment.seeds) >= 5 and experiment.base.gamma == 0.99
    variants = {v.name: v.config for v in experiment.variants}
    for arch in ("cnn", "mlp"):
        base = variants[arch]
        assert base.model.architecture == arch
        changed = {
            "deep": lambda c, base=base: len(c.model.hidden_sizes) > len(base.model.hidden_sizes),
            "wide": lambda c, base=base: c.model.hidden_sizes[0] > base.model.hidden_sizes[0],
            "dropout": lambda c: c.model.dropout > 0,
            "l2": lambda c: c.l2 > 0,
        }
        for knob, differs in changed.items():
            config = variants[f"{arch}-{knob}"]
            assert config.model.architecture == arch and differs(config), f"{arch}-{knob}"
            # Each architecture's variants share its (tuned) learning rate: only the knob differs.
            assert config.learning_rate == base.learning_rate, f"{arch}-{knob}"
    assert len(expand(experiment)) == len(variants) * len(experiment.seeds)


def test_pong_smoke_ablation_with_tune_through_ray_and_mlflow(run_quiet, tmp_path, tracking_uri):
    import json
    import math

    import ablate

    experiment = load_experiment(EXPERIMENTS / "pong-smoke.toml")
    assert experiment.base.max_episode_steps > 0  # capped episodes: seconds per trial
    assert experiment.tune is not None and 0.001 not in dict(experiment.tune.knobs)["learning_rate"]
    outcome = run_quiet(experiment, tmp_path, tracking_uri)
    # 2 arms x 2 candidates x 1 tuning seed; the base value on seed 0; the choice (never the base) on seed 0
    assert outcome.exit_code == 0 and len(outcome.finished) == 4 + 2 + 2 and not outcome.failed
    tracker = RunReader(tracking_uri, "pong-smoke")
    runs = tracker.trial_runs()
    assert all(r.status == "FINISHED" for r in runs) and len({r.key for r in runs}) == len(runs) == 8
    tuning_runs = [r for r in runs if r.tags["ablate.stage"] == "tune"]
    evaluation = [r for r in runs if r.tags["ablate.stage"] == "eval"]
    assert sorted((r.variant, r.seed) for r in tuning_runs) == [("cnn", 10_000)] * 2 + [("mlp", 10_000)] * 2
    assert all(r.metrics["episodes_run"] == 2 for r in tuning_runs)  # the tuning budget

    # The launch's choice is the argmax of the tuning table (ties: the candidate nearest the base in log space),
    # and the evaluation ran at it on the evaluation seeds, beside the base value.
    table = ablate.load("pong-smoke", tracking_uri=tracking_uri).tuning
    assert len(table) == 4 and set(table.status) == {"FINISHED"}
    document = json.loads(tracker.load_text(tracker.launches()[0].info.run_id, "tuning.json"))
    for arm in ("cnn", "mlp"):
        means = table[table.variant == arm].groupby("learning_rate")["auc"].mean()
        best = [lr for lr, mean in means.items() if mean == means.max()]
        chosen = min(best, key=lambda lr: abs(math.log(lr / 0.001)))
        assert document["choices"][arm]["values"] == {"learning_rate": chosen}, means
        rates = sorted(float(r.params["learning_rate"]) for r in evaluation if r.variant == arm)
        assert rates == sorted([0.001, chosen])
        assert sorted(r.seed for r in evaluation if r.variant == arm) == [0, 0]

    for run in evaluation:
        assert run.params["action_set"] == "move"
        # What it ran against, recorded (issue 44): the report and the rounds read these, not the env's name.
        recorded = {k: v for k, v in run.params.items() if k.startswith("env.")}
        assert recorded["env.id"] == "ALE/Pong-v5" and recorded["env.solve_threshold"] == "None"
        assert recorded["env.obs_shape"] == "1x80x80" and recorded["env.obs_dtype"] == "int8"
        assert recorded["env.n_actions"] == "2" and recorded["env.max_episode_steps"] == "50"
        assert recorded["env.reward_threshold"] == "None" and recorded["env.ale_py_version"][0].isdigit()
        returns = sorted((m.step, m.value) for m in tracker.client.get_metric_history(run.run_id, "episode/return"))
        assert [step for step, _ in returns] == [1, 2, 3, 4]
        assert all(-50 <= value <= 1 for _, value in returns)  # at most a point or two in 50 steps
        assert run.metrics["episodes_run"] == 4 and run.metrics["env_steps"] == 4 * 50
        artifacts = {a.path for a in tracker.client.list_artifacts(run.run_id)}
        assert artifacts == {
            "episodes.csv",
            "weights.pt",
            "config.json",
            "learning_curve.png",
            "observation.png",
            "videos",
        }
        videos = [a.path for a in tracker.client.list_artifacts(run.run_id, "videos")]
        assert videos[0] == "videos/episode_00001.mp4" and len(videos) >= 2


def test_cartpole_ablation_tunes_each_variants_learning_rate_past_the_probes_best(tmp_path, monkeypatch):
    experiment = load_experiment(EXPERIMENTS / "cartpole.toml")
    spec = experiment.tune
    (rates,) = [values for knob, values in spec.knobs if knob == "learning_rate"]
    assert min(rates) < experiment.base.learning_rate < max(rates) and max(rates) > 0.1  # the probe: best at 0.1
    assert 2 <= len(spec.seeds) <= 3 and spec.max_episodes < experiment.base.max_episodes
    variants = {v.name: v for v in experiment.variants}
    assert spec.tuned_knobs(variants["course"]) == () and variants["course"].config.learning_rate == 1e-3
    assert all(spec.tuned_knobs(v) == ("learning_rate",) for name, v in variants.items() if name != "course")
    # The bench's untuned twin is the same ablation: the same trials, no [tune].
    monkeypatch.syspath_prepend(str(EXPERIMENTS.parent / "benchmarks"))
    import bench_estimate  # the bench's tuning section

    untuned = tmp_path / "cartpole.toml"
    untuned.write_text(bench_estimate.without_tune((EXPERIMENTS / "cartpole.toml").read_text()))
    twin = load_experiment(untuned)
    assert twin.tune is None and [t.key for t in expand(twin)] == [t.key for t in expand(experiment)]


# --- the primary question (issue 25): report-level keys leave every trial key as it was ----------------------


def test_primary_and_smallest_effect_change_no_trial_key(tmp_path):
    text = (EXPERIMENTS / "cartpole.toml").read_text()
    plain = load_experiment(EXPERIMENTS / "cartpole.toml")
    assert plain.primary is None and plain.primary_metric == "episodes_to_solve"  # CartPole can solve
    keyed = tmp_path / "cartpole.toml"
    keyed.write_text("primary = 'auc'\nsmallest_effect = 0.25\n" + text)
    experiment = load_experiment(keyed)
    assert experiment.primary_metric == "auc" and experiment.smallest_effect == 0.25
    assert [(t.key, t.config) for t in expand(experiment)] == [(t.key, t.config) for t in expand(plain)]


def test_pong_claims_rest_on_the_area_under_the_curve_by_default():
    pong = load_experiment(EXPERIMENTS / "pong.toml")
    assert pong.primary is None and pong.primary_metric == "auc"  # Pong has no solve threshold


def test_your_model_runs_the_students_network_and_a_layernorm_one_beside_the_baseline():
    """experiments/your-model.toml as docs/your-model.md gives it: the lab's zero-argument create_cartpole_model
    (the built-in baseline's very layers, so the same run bit for bit) and a LayerNorm MLP with model_args."""
    from dataclasses import replace

    from ablate.agent.trainer import run_population, run_trial
    from ablate.launch.grid import expand

    experiment = load_experiment(EXPERIMENTS / "your-model.toml")
    variants = {v.name: v.config for v in experiment.variants}
    assert variants["student"].model.factory.endswith("student.py:create_cartpole_model")
    assert dict(variants["layernorm"].model.factory_args) == {"width": 32}
    assert len({t.key for t in expand(experiment)}) == 9
    short = {name: replace(c, max_episodes=64, record_video=False) for name, c in variants.items()}
    baseline, student = run_trial(short["baseline"]), run_trial(short["student"])
    assert [m[:7] for m in baseline.episodes] == [m[:7] for m in student.episodes]
    members = run_population([replace(short["layernorm"], seed=s) for s in range(3)])
    assert all(len(m.episodes) == 64 and m.parameter_count == 4 * 32 + 32 + 2 * 32 + 32 * 2 + 2 for m in members)


def test_breakout_with_the_pong_profile_trains_on_pongs_frames_and_names_its_two_actions(
    run_quiet, tmp_path, tracking_uri
):
    """The Pong pipeline is a profile any Atari game may use (issue 57): Breakout with ``env_profile = "pong"`` and
    ``action_set = "move"`` gets Pong's 80x80 int8 frame differences, its return rule and its two moves, as
    Breakout names them, in the trial's record and the report's variants table."""
    import ablate

    path = tmp_path / "breakout-pong.toml"
    path.write_text(
        'name = "breakout-pong"\nseeds = 1\n[base]\nenv_id = "ALE/Breakout-v5"\nenv_profile = "pong"\n'
        'action_set = "move"\nmax_episode_steps = 40\nmax_episodes = 2\nepisodes_per_update = 1\n'
        "video_max_frames = 10\nhidden_sizes = [8]\n"
        '[[variants]]\nname = "cnn"\narchitecture = "cnn"\n[[variants]]\nname = "mlp"\n'
    )
    experiment = load_experiment(path)
    assert profile_of(experiment.base).resets_on_score and experiment.base.checkpoint_interval == 50
    outcome = run_quiet(experiment, tmp_path, tracking_uri)
    assert outcome.exit_code == 0 and len(outcome.finished) == 2 and not outcome.failed
    for run in RunReader(tracking_uri, "breakout-pong").trial_runs():
        recorded = {k: v for k, v in run.params.items() if k.startswith("env.")}
        assert recorded["env.id"] == "ALE/Breakout-v5" and recorded["env.obs_shape"] == "1x80x80"
        assert recorded["env.obs_dtype"] == "int8" and recorded["env.actions"] == "RIGHT, LEFT"
        assert run.params["env_profile"] == "pong" and run.metrics["episodes_run"] == 2
    folder = ablate.report("breakout-pong", tracking_uri=tracking_uri, reports_folder=tmp_path / "reports", pdf=False)
    variants = (folder / "report.md").read_text(encoding="utf-8")
    assert "80×80 frame difference: conv" in variants and "80×80 frame difference: dense" in variants
    assert variants.count("; 2 actions (RIGHT, LEFT)") == 2
