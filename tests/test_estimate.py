"""The time-left estimate (``launch.estimate``): each trial's expected cost from what finished trials took,
running trials' time left, populations on the slots, later stages and rounds, placed on the slots in the
order the trials start. Events go in through the live view, which holds the estimate's state."""

from dataclasses import replace

import pytest
from views import Watched
from views import grid_trials as _trials
from views import row as _row

from ablate.agent.records import EpisodeMetrics
from ablate.config import TrialConfig
from ablate.launch.estimate import makespan
from ablate.launch.grid import GridTrial


def test_makespan_sees_a_long_trial_that_starts_last():
    assert makespan([], [10, 10, 10, 10], slots=2) == 20
    assert makespan([], [1, 1, 1, 9], slots=2) == 10  # the 9 s trial starts at 1 s and runs alone
    assert makespan([5], [1], slots=2) == 5  # an idle slot takes the pending trial at once
    assert makespan([3, 4], [], slots=2) == 4


def test_cost_is_learned_per_variant_from_finished_trials_else_from_the_budget(clock):
    view = Watched("x", _trials(budget=100), already_done=0, enabled=False, slots=2, start=clock.now - 7)
    assert view.seconds_left() is None  # nothing is known of any trial's cost yet
    assert "0:07 elapsed" in view.headline()  # the clock counts from the command's start
    view.started("fast-s0")
    view.started("fast-s1")
    clock.now += 2
    view.episodes("fast-s0", [_row(1, 9.0), _row(20, 20.0)])  # 0.1 s per episode
    view.episodes("fast-s1", [_row(20, 30.0)])
    # Nothing finished: every trial is costed at its whole budget at 0.1 s per episode. Running ones have 80
    # episodes (8 s) left; then two slow trials of 10 s on the two slots.
    assert view.seconds_left() == pytest.approx(8 + 10)
    clock.now += 1
    view.finished("fast-s0", solved=True)
    view.finished("fast-s1", solved=True)
    # No slow trial has run: each costs its 100 episodes at the pace the fast ones finished at (3 s for 20), at once.
    assert view.seconds_left() == pytest.approx(3 / 20 * 100)
    view.started("slow-s0")
    clock.now += 30
    view.episodes("slow-s0", [_row(10, 5.0)])  # 3 s per episode: slow's whole budget is 300 s
    # slow-s0 has 90 episodes (270 s) left; slow-s1 takes the free slot now and needs 300 s. A mean over the
    # trials ended so far (3 s each) would say 3 s.
    assert view.seconds_left() == pytest.approx(300)


def test_the_expected_longest_of_a_populations_members():
    from ablate.launch.estimate import expected_max

    assert expected_max([[7.0]]) == 7.0
    assert expected_max([[10.0, 30.0]] * 3) == pytest.approx(27.5)  # the slowest of three seeds, not their mean
    assert expected_max([[1.0, 1.0, 1.0, 1.0, 10.0]] * 8) > 8.0  # one seed in five never solves: 8 members wait


def test_a_population_holds_its_slot_until_its_last_member_ends_and_costs_its_longest_member(clock):
    trials = _trials(budget=100, variants=("a",), seeds=(0, 1, 2, 3, 4, 5))

    def plan(ts):  # two populations of three seeds, on one slot
        keys = [t.key for t in ts]
        return [keys[:3], keys[3:]]

    view = Watched("x", trials, 0, enabled=False, slots=1, groups=plan(trials))
    for seed in (0, 1, 2):
        view.started(f"a-s{seed}")
    clock.now += 10
    view.episodes("a-s0", [_row(40, 195.0)])
    view.finished("a-s0", solved=True)  # 10 s: a member ends; the slot is still its population's
    clock.now += 20
    view.episodes("a-s1", [_row(80, 195.0)])
    view.finished("a-s1", solved=True)  # 30 s
    view.episodes("a-s2", [_row(50, 5.0), _row(60, 6.0)])
    # a-s2 ran past its peers' mean (20 s): it runs on at its own pace (30 s for 60 episodes: 20 s for the 40
    # left); then the second population's three members start together, each costing what a finished member
    # did (10 s or 30 s, equally likely): the population costs its longest member's, not their sum (they run at
    # once) and not their mean: the expected longest of three, 10 x 1/8 + 30 x 7/8 = 27.5 s; it waits for the slot.
    assert view.seconds_left() == pytest.approx(20 + 27.5)
    clock.now += 5
    view.finished("a-s2", solved=False)  # the first population took 35 s; the second starts after its last
    view.started("a-s3")
    assert view.gaps == [0.0]  # one slot freed (at the last member's end) and taken
    # a-s3 runs (its cost: the finished members' mean, 25 s); a-s4 and a-s5, not started, are the expected
    # longest of two draws from 10, 30 and 35 s (10 x 1/9 + 30 x 3/9 + 35 x 5/9): the population's time left.
    assert view.seconds_left() == pytest.approx((10 + 90 + 175) / 9)
    clock.now += 1
    view.started("a-s4")
    view.started("a-s5")
    assert view.gaps == [0.0]  # its mates took no slot of their own
    assert view.max_running == 1  # one population running, though it had three members


def test_two_slots_freed_at_once_are_taken_by_the_first_member_of_each_population(clock):
    trials = _trials(budget=100, variants=("a",), seeds=tuple(range(8)))

    def plan(ts):  # four populations of two seeds, on two slots
        keys = [t.key for t in ts]
        return [keys[i : i + 2] for i in range(0, len(keys), 2)]

    view = Watched("x", trials, 0, enabled=False, slots=2, groups=plan(trials))
    for seed in range(4):
        view.started(f"a-s{seed}")
    clock.now += 10
    for seed in range(4):  # both populations end at 10 s: two slots free
        view.finished(f"a-s{seed}", solved=True)
    for wait, seeds in ((1, (4, 5)), (1, (6, 7))):  # the next two start 1 s and 2 s later, member by member
        clock.now += wait
        for seed in seeds:
            view.started(f"a-s{seed}")
    assert view.gaps == [1.0, 2.0] and view.dispatch_s() == pytest.approx(1.5)
    # Each trial alone, the same events say the three members of the second population take a slot each.
    alone = Watched("x", trials, 0, enabled=False, slots=1)
    assert alone.population_of == {t.key: (t.key,) for t in trials}


def test_a_trial_past_its_peers_mean_runs_as_long_as_the_peers_that_ran_longer(clock):
    view = Watched("x", _trials(budget=1000, variants=("a",), seeds=(0, 1, 2, 3)), 0, enabled=False, slots=4)
    for seed in (0, 1, 2, 3):
        view.started(f"a-s{seed}")
    clock.now += 10
    for seed in (0, 1, 2):  # 10 s, 12 s, 14 s
        view.episodes(f"a-s{seed}", [_row(100, 195.0)])
        view.finished(f"a-s{seed}", solved=True)
        clock.now += 2
    clock.now += 6  # 22 s: a-s3 is past every peer; nothing says how long it runs
    view.episodes("a-s3", [_row(10, 1.0), _row(20, 1.0)])
    assert view.seconds_left() == pytest.approx(22 / 20 * 980)  # at its own pace for the rest of its budget
    view.trials["a-s2"].ended_at = view.trials["a-s2"].started_at + 40  # had a-s2 taken 40 s instead:
    # past the peers' mean (20.7 s) still, but one of them ran longer: as long as it took, not 980 episodes.
    assert view.seconds_left() == pytest.approx(40 - 22)


def test_recent_pace_counts_when_episodes_get_longer(clock):
    view = Watched("x", _trials(budget=1000, variants=("a",), seeds=(0,)), 0, enabled=False, slots=1)
    view.started("a-s0")
    for episode, seconds in ((100, 1), (200, 2), (300, 4), (400, 8)):  # the pace halves at every report
        clock.now += seconds
        view.episodes("a-s0", [_row(episode, 1.0)])
    # Over the last reports: 14 s for 300 episodes; since the start it would be 15 s for 400.
    assert view.seconds_left() == pytest.approx(600 * 14 / 300)


def test_costs_from_an_earlier_launch_are_scaled_to_this_launchs_pace(clock):
    prior = {"fast-s0": 2.0, "fast-s1": 4.0, "slow-s0": 20.0, "slow-s1": 40.0}
    view = Watched("x", _trials(), 0, enabled=False, slots=1, prior_costs=prior)
    # Before anything reported: the earlier launch's seconds, one slot, one after another.
    assert view.seconds_left() == pytest.approx(2 + 4 + 20 + 40)
    view.started("fast-s0")
    clock.now += 3  # this launch runs 1.5x slower than the earlier one
    view.finished("fast-s0", solved=True)
    view.started("fast-s1")
    assert view.seconds_left() == pytest.approx(1.5 * (4 + 20 + 40))
    clock.now += 1  # one second into fast-s1, expected 6 s in all
    assert view.seconds_left() == pytest.approx(1.5 * (4 + 20 + 40) - 1)


def test_a_trial_past_its_earlier_runs_time_runs_on_to_where_that_run_stopped_not_to_its_budget(clock):
    # The earlier run of the same key (the same seed) solved after 40 of its 100 episodes in 4 s; this launch
    # runs slower, so the trial is past its expected time with its solving episode still ahead.
    trials = _trials(budget=100, variants=("a",), seeds=(0,))
    view = Watched("x", trials, 0, enabled=False, slots=1, prior_costs={"a-s0": 4.0}, prior_episodes={"a-s0": 40})
    view.started("a-s0")
    for episode in (10, 20, 30):
        clock.now += 2.0  # 0.2 s per episode: twice the earlier run's pace
        view.episodes("a-s0", [_row(episode, 1.0)])
    assert view.seconds_left() == pytest.approx(10 * 0.2)  # 10 episodes to go, not 70
    for episode in (40, 50):  # this run did not stop there (another CPU's floats): the rest of its budget
        clock.now += 2.0
        view.episodes("a-s0", [_row(episode, 1.0)])
    assert view.seconds_left() == pytest.approx(50 * 0.2)


def test_a_later_stages_trials_are_costed_from_their_earlier_runs_when_they_have_some(clock):
    view = Watched("x", _trials(variants=("a",), seeds=(0,)), 0, enabled=False, slots=1, prior_costs={"a-s0": 2.0})
    view.started("a-s0")
    clock.now += 4  # this launch runs twice as slow as the earlier one
    view.finished("a-s0", solved=True)
    view.add_trials(_trials(variants=("b",), seeds=(0,)), {"b-s0": 10.0}, {"b-s0": 40})
    assert view.seconds_left() == pytest.approx(2 * 10.0)  # its earlier run's 10 s at this launch's pace
    # No stand-ins stood for b-s0 (a round of seeds): what the view knew of before did not include it.
    assert view.phases == [["a-s0"], ["b-s0"]]
    view.started("b-s0")
    for episode in (10, 20, 30):
        clock.now += 8.0  # 0.8 s per episode: past its expected 20 s with its solving episode ahead
        view.episodes("b-s0", [_row(episode, 1.0)])
    assert view._left_of_running(view.trials["b-s0"], clock.now, view._costs_seen(clock.now)) == pytest.approx(8.0)


def _a_peer_solved_in_10_s_then_a_second_trial_started(clock):
    """CartPole-v0 (threshold 195 over 100 episodes), a budget of 1,000: a-s0 solved at episode 100 after 10 s,
    then a-s1 started."""
    config = replace(TrialConfig(), env_id="CartPole-v0", max_episodes=1000, solve_window=100)
    trials = [GridTrial(f"a-s{s}", "a", s, replace(config, seed=s)) for s in (0, 1)]
    view = Watched("x", trials, already_done=0, enabled=False, slots=1, start=clock.now)
    view.started("a-s0")
    clock.now += 10
    view.episodes("a-s0", [_row(100, 196.0)])
    view.finished("a-s0", solved=True, summary={"episodes_run": 100})
    view.started("a-s1")
    return view


def test_a_trial_past_its_peers_time_whose_rolling_mean_does_not_climb_runs_out_its_budget(clock):
    view = _a_peer_solved_in_10_s_then_a_second_trial_started(clock)
    for episode, rolling_mean in ((50, 150.0), (100, 120.0), (150, 120.0)):  # falling, then flat
        clock.now += 5
        view.episodes("a-s1", [_row(episode, rolling_mean)])
    assert view.seconds_left() == pytest.approx(850 * 0.1)  # past its peer's 10 s: 850 episodes at 0.1 s


def test_a_climb_does_not_cut_a_trial_whose_earlier_run_never_solved(clock):
    config = replace(TrialConfig(), env_id="CartPole-v0", max_episodes=1000, solve_window=100)
    trials = [GridTrial("a-s0", "a", 0, config)]
    earlier = {"prior_costs": {"a-s0": 5.0}, "prior_episodes": {"a-s0": 1000}}
    view = Watched("x", trials, 0, enabled=False, slots=1, **earlier)
    view.started("a-s0")
    for episode, rolling_mean in ((50, 100.0), (100, 150.0)):  # climbing, past its earlier run's 5 s
        clock.now += 5
        view.episodes("a-s0", [_row(episode, rolling_mean)])
    assert view.seconds_left() == pytest.approx(900 * 0.1)  # the same seed ran all 1,000 before: so again


def test_the_idle_time_between_one_trial_and_the_next_counts_per_pending_trial(clock):
    view = Watched("x", _trials(variants=("a",), seeds=(0, 1, 2, 3)), 0, enabled=False, slots=1)
    view.started("a-s0")
    clock.now += 4
    view.finished("a-s0", solved=True)
    clock.now += 1  # the slot stays idle a second before the next trial starts
    view.started("a-s1")
    assert view.dispatch_s() == pytest.approx(1)
    # a-s1 has 4 s left (the mean of a's finished trials); the two pending ones take 4 s + 1 s idle each.
    assert view.seconds_left() == pytest.approx(4 + 2 * (4 + 1))


def test_peers_share_a_budget_a_trial_with_another_budget_is_costed_apart(clock):
    short = replace(TrialConfig(), max_episodes=10)
    trials = [GridTrial("a-s0", "a", 0, short), GridTrial("a-s1", "a", 1, replace(short, seed=1))]
    trials.append(GridTrial("a-s2-long", "a", 2, replace(short, seed=2, max_episodes=1000)))
    view = Watched("x", trials, 0, enabled=False, slots=1)
    view.started("a-s0")
    clock.now += 1
    view.episodes("a-s0", [_row(10, 1.0)])  # 0.1 s per episode
    view.finished("a-s0", solved=False)
    assert view.seconds_left() == pytest.approx(1.0 + 0.1 * 1000)  # a-s1: a finished peer took 1 s; a-s2-long below
    view.started("a-s1")
    view.finished("a-s1", solved=False)
    # The 1,000-episode trial has no finished peer at its budget: its peer's 10 episodes, then the rest at the
    # pace seen (a-s1 reported no episode: it says nothing), not the 10-episode mean.
    assert view.seconds_left() == pytest.approx(0.1 * 1000)


def test_every_estimate_is_logged_against_the_clock_when_asked(clock):
    view = Watched("x", _trials(variants=("a",), seeds=(0,)), 0, slots=1, start=clock.now, log_estimates=True)
    view.started("a-s0")
    clock.now += 2
    view.episodes("a-s0", [_row(50, 1.0)])
    view.finished("a-s0", solved=False)
    # (seconds since the start, trials ended, the round's estimate, the most in all, the phase)
    assert view.estimates == [
        (0.0, 0, None, None, 0),
        (2.0, 0, pytest.approx(2.0), pytest.approx(2.0), 0),
        (2.0, 1, 0.0, 0.0, 0),
    ]


def test_a_later_stage_counts_after_this_one_and_keeps_what_was_learned(clock):
    # Stage 1: two tuning trials of "a"; stage 2 (not known yet): two trials of "a" at the same budget.
    later = _trials(variants=("a",), seeds=(0, 1))  # stand-ins of the same size
    view = Watched("x", _trials(variants=("a",), seeds=(0, 1)), 0, enabled=False, slots=2, later=later)
    view.started("a-s0")
    view.started("a-s1")
    clock.now += 4
    view.episodes("a-s0", [_row(50, 1.0)])  # 0.08 s per episode; 4 s left of its 100-episode budget
    view.episodes("a-s1", [_row(50, 1.0)])
    # Stage 2 starts only when both have ended (4 s), then its two trials run side by side (8 s each).
    assert view.seconds_left() == pytest.approx(4 + 8)
    clock.now += 2
    view.finished("a-s0", solved=True)  # 6 s
    view.finished("a-s1", solved=True)
    assert "all trials ended" not in view.headline() and view.seconds_left() == pytest.approx(6)
    stage_2 = [GridTrial(f"a-lr-s{s}", "a", s, replace(TrialConfig(), max_episodes=100, seed=s)) for s in (0, 1)]
    view.add_trials(stage_2)
    assert view.seconds_left() == pytest.approx(6)  # the finished trials' cost carries over
    assert view.phases == [["a-s0", "a-s1", "a-lr-s0", "a-lr-s1"]]  # the stand-ins said it was coming
    view.started("a-lr-s0")
    view.started("a-lr-s1")
    view.finished("a-lr-s0", solved=True)
    view.finished("a-lr-s1", solved=True)
    assert "all trials ended" in view.headline() and view.seconds_left() == 0


def test_a_trial_costs_what_its_finished_peers_at_the_same_values_took_at_another_budget(clock):
    # Tuning trials (50 episodes) of two learning rates; the evaluation trials (150 episodes) at the same
    # values have no finished peer at their own budget.
    def trial(name, lr, budget, stage):
        return GridTrial(name, "a", 0, replace(TrialConfig(), learning_rate=lr, max_episodes=budget), stage)

    tuning = [trial("fast-t", 0.1, 50, "tune"), trial("slow-t", 0.01, 50, "tune")]
    evaluation = [trial("fast-e", 0.1, 150, "eval"), trial("slow-e", 0.01, 150, "eval")]
    view = Watched("x", tuning + evaluation, 0, enabled=False, slots=1)
    view.started("fast-t")
    clock.now += 3
    view.finished("fast-t", solved=True, summary={"episodes_run": 30})  # solved after 30 episodes: stopped
    view.started("slow-t")
    for episode in (10, 20, 30, 40, 50):  # its whole budget, the last episodes at 0.2 s each
        clock.now += 0.6 if episode <= 20 else 2.0
        view.episodes("slow-t", [_row(episode, 1.0)])
    view.finished("slow-t", solved=False, summary={"episodes_run": 50})
    seen = view._costs_seen(clock.now)
    fast, slow = (view._trial_cost(view.trials[k], seen) for k in ("fast-e", "slow-e"))
    assert fast == pytest.approx(3.0)  # it would stop where its tuning trial stopped
    assert slow == pytest.approx(7.2 + 100 * 0.2)  # its tuning trial's time, then 100 episodes at its last pace


def test_an_evaluation_trial_at_a_tuned_value_is_costed_between_its_tuning_trials_and_its_variants_seeds(clock):
    # The tuned value won on the tuning seeds, so its short tuning trials are an optimistic guide (an
    # evaluation seed may solve later, or not at all); the variant's finished evaluation trials at the base
    # value ran the same budget on the same seeds. The estimate takes the mean of the two.
    def trial(name, lr, budget, stage, seed=0):
        config = replace(TrialConfig(), learning_rate=lr, max_episodes=budget, seed=seed)
        return GridTrial(name, "a", seed, config, stage)

    trials = [trial("tuned-t", 0.1, 50, "tune"), trial("base-e", 0.03, 150, "eval"), trial("tuned-e", 0.1, 150, "eval")]
    view = Watched("x", trials, 0, enabled=False, slots=1)
    view.started("tuned-t")
    clock.now += 3
    view.finished("tuned-t", solved=True, summary={"episodes_run": 30})  # solved after 30 episodes: 3 s
    seen = view._costs_seen(clock.now)
    assert view._trial_cost(view.trials["tuned-e"], seen) == pytest.approx(3.0)  # nothing else seen yet
    view.started("base-e")
    clock.now += 13
    view.finished("base-e", solved=False, summary={"episodes_run": 150})  # the base value: 13 s
    seen = view._costs_seen(clock.now)
    assert view._trial_cost(view.trials["tuned-e"], seen) == pytest.approx((3.0 + 13.0) / 2)
    view.started("tuned-e")
    clock.now += 4
    view.finished("tuned-e", solved=True, summary={"episodes_run": 40})
    seen = view._costs_seen(clock.now)
    assert view._peer_cost(view.trials["tuned-e"], seen) == pytest.approx(4.0)  # its own settings' trial, once seen


def test_stand_ins_replaced_as_tuning_trials_end_count_as_the_runner_sets_them(clock):
    stage_1 = [GridTrial("a-t", "a", 10_000, replace(TrialConfig(), max_episodes=100), "tune")]
    stand_ins = _trials(variants=("a",), seeds=(0, 1))
    view = Watched("x", stage_1, 0, enabled=False, slots=1, later=stand_ins)
    view.started("a-t")
    clock.now += 5
    view.episodes("a-t", [_row(50, 1.0)])
    assert view.seconds_left() == pytest.approx(5 + 2 * 10)  # its rest, then two 100-episode stand-ins
    # the stand-ins are counted from the start, as a bound that does not move (issue 46: "of 48", then "of 42")
    bounded = "(of 1, at most 3 with the chosen values' trials;"
    assert bounded in view.headline()
    view.finished("a-t", solved=False, summary={"auc": 1.0, "episodes_run": 100})
    view.state.set_later([])  # the runner asked again: the base value ahead, stage 2 adds nothing
    assert bounded in view.headline()
    assert view.seconds_left() == 0.0 and view.trials_end is None  # the stage is still announced
    view.add_trials([])
    assert view.trials_end == clock.now and "all trials ended" in view.headline()


def test_phases_a_stage_its_stand_ins_announced_joins_the_launchs_a_round_of_seeds_opens_its_own(clock):
    stage_1 = [GridTrial(f"a-t{s}", "a", 10_000 + s, replace(TrialConfig(), max_episodes=100), "tune") for s in (0, 1)]
    view = Watched("x", stage_1, 0, slots=1, stage_coming=True, log_estimates=True)  # no stand-in yet
    for key in ("a-t0", "a-t1"):
        view.started(key)
        clock.now += 1
        view.finished(key, solved=False, summary={"auc": 1.0, "episodes_run": 100})
    stage_2 = _trials(variants=("a",), seeds=(0,))
    view.add_trials(stage_2)  # still the stage announced: the launch's phase
    assert view.phases == [["a-t0", "a-t1", "a-s0"]]
    view.started("a-s0")
    view.finished("a-s0", solved=True)
    view.add_trials(_trials(variants=("a",), seeds=(1,)))  # a round of seeds: its own phase, from now
    assert view.phases[1] == ["a-s1"] and view.estimates[-1][4] == 1 and view.estimates[-2][4] == 0


def test_a_later_stage_with_nothing_to_run_ends_the_trials(clock):
    later = _trials(variants=("a",), seeds=(0,))
    view = Watched("x", _trials(variants=("a",), seeds=(0,)), 0, enabled=False, slots=1, later=later)
    view.started("a-s0")
    clock.now += 3
    view.finished("a-s0", solved=True)
    clock.now += 1
    view.add_trials([])  # every choice was the base value: no stage-2 trials
    assert "all trials ended" in view.headline() and view.trials_end == clock.now - 1


def test_a_workers_start_paid_by_its_first_trial_is_not_charged_to_the_trials_after_it(clock):
    view = Watched("x", _trials(variants=("a", "b"), seeds=(0, 1, 2)), 0, enabled=False, slots=2)
    view.started("a-s0")  # both first on their workers: each pays a 20 s worker start
    view.started("b-s0")
    clock.now += 25
    view.finished("a-s0", solved=True, wall_s=5.0)
    view.started("a-s1")
    clock.now += 1
    view.finished("b-s0", solved=True, wall_s=4.0)
    view.started("b-s1")
    # No trial without a worker start has ended: a's trials cost their training time (5 s), not 25 s, b's 4 s:
    # a-s1 and b-s1 have 4 s left, then a-s2 (5 s) and b-s2 (4 s) on the two slots.
    assert view.seconds_left() == pytest.approx(4 + 5)
    clock.now += 6
    view.finished("a-s1", solved=True, wall_s=5.0)  # 7 s since it started: 2 s beside its training
    view.finished("b-s1", solved=True, wall_s=4.0)  # 6 s since it started: 2 s beside
    # a-s2 costs 7 s (a-s0 counts as 5 s + the 2 s beside), b-s2 6 s (4 + 2), each on a slot of its own.
    assert view.seconds_left() == pytest.approx((7 + 7) / 2)


def test_the_pace_of_a_trial_with_one_report_is_read_off_its_own_clock(clock):
    view = Watched("x", _trials(budget=40, variants=("a",), seeds=(0, 1)), 0, enabled=False, slots=1)
    view.started("a-s0")
    clock.now += 21  # 20 s of its worker's start, then 10 episodes in 1 s by the trial's own clock
    view.episodes("a-s0", [_row(10, 1.0)._replace(wall_s=1.0)])
    # 30 episodes left at 0.1 s, then a-s1's 40 episodes: not 2.1 s per episode from the wall since its start.
    assert view.seconds_left() == pytest.approx(0.1 * 30 + 0.1 * 40)


def test_a_trial_that_solved_is_writing_its_artifacts_not_running_out_its_budget(clock):
    # A CartPole trial stops at the episode whose rolling mean over solve_window reaches the env's threshold
    # (195 on v0): past its peers' time, it is writing artifacts, not running its 900 remaining episodes.
    view = _a_peer_solved_in_10_s_then_a_second_trial_started(clock)
    clock.now += 5
    view.episodes("a-s1", [_row(50, 40.0)])
    clock.now += 5
    view.episodes("a-s1", [_row(99, 150.0)])  # not yet solved
    clock.now += 3  # past the 10 s its peer took
    # Its rolling mean climbed 110 in 49 episodes: 45 more to the threshold take ~20 episodes (0.1 s each).
    assert view.seconds_left() == pytest.approx(45 * 49 / 110 * 5 / 49)
    view.episodes("a-s1", [_row(100, 195.5)])  # solved: its last episode
    assert view.seconds_left() == 0.0


def _timed(episode, wall_s, env_steps):
    """An episode row with the trial's own clock and env steps (a rolling mean far from CartPole's threshold)."""
    return EpisodeMetrics(episode, -20.0, 10, 0.0, 0.5, -20.0, env_steps, wall_s, episode)


def _a_peer_ran_400_episodes_in_205_s_then_a_second_trial_started(clock, seeds=(0, 1, 2)):
    """``seeds`` of a budget of 400 on one slot: a-s0 ran all 400 episodes at 0.5 s and 10 steps each (0.05 s
    per step), 200 s of training and 5 s after its last report; then a-s1 started (the rest pending)."""
    trials = _trials(budget=400, variants=("a",), seeds=seeds)
    view = Watched("x", trials, 0, enabled=False, slots=1)
    view.started("a-s0")
    for episode in (100, 200, 300, 400):
        clock.now += 50
        view.episodes("a-s0", [_timed(episode, episode / 2, episode * 10)])
    clock.now += 5
    view.finished("a-s0", solved=False)
    view.started("a-s1")
    return view


def test_a_running_trial_is_held_to_its_peers_per_env_step_and_the_launch_pace_scales_what_is_pending(clock):
    from ablate.launch.estimate import PACE_WINDOW_S

    view = _a_peer_ran_400_episodes_in_205_s_then_a_second_trial_started(clock)
    clock.now += 50
    view.episodes("a-s1", [_timed(50, 50.0, 500)])
    # Under PACE_WINDOW_S of its own clock: no pace yet, its peer's 205 s less the 50 s it has run, then a-s2's.
    assert PACE_WINDOW_S > 50 and view.seconds_left() == pytest.approx(155 + 205)
    clock.now += 50
    view.episodes("a-s1", [_timed(100, 100.0, 1000)])
    # 0.1 s per step where its peer took 0.05 over the same episodes: twice as slow. It has its peer's 150 s of
    # training left at that pace, then the 5 s tail; a-s2, not started, costs its peer's 205 s at the pace now.
    assert view._costs_seen(clock.now).pace == pytest.approx(2.0)
    assert view.seconds_left() == pytest.approx(2 * 150 + 5 + 2 * 205)
    clock.now += 4
    assert view.seconds_left() == pytest.approx(2 * 150 + 5 - 4 + 2 * 205)  # the time since its last report


def test_a_seed_with_longer_episodes_is_not_taken_for_a_slower_machine(clock):
    view = _a_peer_ran_400_episodes_in_205_s_then_a_second_trial_started(clock)
    clock.now += 100
    # Twice as long per episode, but twice the steps: the machine runs as fast as it did for a-s0.
    view.episodes("a-s1", [_timed(50, 50.0, 1000), _timed(100, 100.0, 2000)])
    assert view._costs_seen(clock.now).pace == pytest.approx(1.0)
    assert view.seconds_left() == pytest.approx(150 + 5 + 205)


def test_a_trial_whose_last_report_solved_it_is_not_held_to_its_peers_rest(clock):
    view = _a_peer_ran_400_episodes_in_205_s_then_a_second_trial_started(clock, seeds=(0, 1))
    clock.now += 100
    view.episodes("a-s1", [_timed(100, 100.0, 1000)])
    clock.now += 100
    solved = EpisodeMetrics(200, 500.0, 10, 0.0, 0.5, 480.0, 2000, 200.0, 200)  # CartPole-v1's threshold: 475
    view.episodes("a-s1", [solved])
    # It stops here and writes its artifacts: not its peer's 100 s of training from episode 200 at its pace.
    assert view.seconds_left() == pytest.approx(205 - 200)


def test_the_upper_figure_adds_each_round_that_may_follow_after_the_one_running(clock):
    view = Watched("x", _trials(budget=100, variants=("a",), seeds=(0, 1)), 0, slots=2, start=clock.now)
    view.state.set_possible(
        [_trials(budget=100, variants=("a",), seeds=(2, 3, 4)), _trials(variants=("a",), seeds=(5,))]
    )
    view.started("a-s0")
    view.started("a-s1")
    clock.now += 10
    view.finished("a-s0", solved=False, summary={"episodes_run": 100})  # a trial costs 10 s
    view.episodes("a-s1", [_row(50, 1.0)])  # 0.2 s per episode: 10 s left
    left, most = view.figures()
    # Round 2's three trials on two slots take 20 s after this round's 10 s; round 3's one 10 s after that.
    assert left == pytest.approx(10) and most == pytest.approx(10 + 20 + 10)
    assert "~0:10 left in round 1, at most ~0:40 in all" in view.headline()
    assert "(of 2, at most 4 more in later rounds;" in view.headline()
    view.state.set_possible([])  # every comparison decided: the launch ends with this round
    assert view.figures() == (pytest.approx(10), pytest.approx(10)) and "at most" not in view.headline()


def test_the_summary_says_which_bound_the_trials_ended_near(clock):
    view = Watched("x", _trials(budget=100, variants=("a",), seeds=(0, 1, 2, 3)), 0, slots=1, start=clock.now)
    view.state.set_possible([_trials(budget=100, variants=("a",), seeds=(4, 5, 6, 7))])
    view.started("a-s0")
    clock.now += 10
    view.finished("a-s0", solved=False, summary={"episodes_run": 100})  # a quarter: 30 s left, at most 70 s
    assert view.quarter == (10.0, pytest.approx(30), pytest.approx(70), 1)
    for seed in (1, 2, 3):
        view.started(f"a-s{seed}")
        clock.now += 10
        view.finished(f"a-s{seed}", solved=False, summary={"episodes_run": 100})
    view.state.set_possible([])  # the comparison was decided: no round followed
    line = view.bounds_line()
    assert "at 0:10 the estimate said ~0:30 left in round 1, at most ~1:10 in all" in line
    assert line.endswith("the trials ended 0:30 later, nearer the round's estimate")


def test_the_summary_names_the_round_its_estimate_was_made_in(clock):
    """A launch resumed in round 5 said "the estimate said ... left in round 1" at its end (3e01923)."""
    view = Watched("x", _trials(budget=100, variants=("a",), seeds=(0, 1, 2, 3)), 0, slots=1, start=clock.now)
    view.state.set_possible([_trials(budget=100, variants=("a",), seeds=(4, 5, 6, 7))])
    view.state.round = 5
    for seed in range(4):
        view.started(f"a-s{seed}")
        clock.now += 10
        view.finished(f"a-s{seed}", solved=False, summary={"episodes_run": 100})
    view.state.set_possible([])
    assert "~0:30 left in round 5, at most ~1:10 in all" in view.bounds_line()


def test_the_estimate_of_running_trials_imports_no_torch_in_the_driver():
    """A trial's solve threshold is the env's (Gymnasium): asked of the launch's state while Tune's callbacks run,
    it once imported the trainer, and so torch, there, where a SIGTERM landing mid-import left torch half
    imported and the launch FAILED instead of KILLED (the e2e SIGTERM test)."""
    import subprocess
    import sys

    code = (
        "import sys; from ablate.launch import runner, state, estimate, progress, recorder; "
        "from ablate.launch.grid import GridTrial; from ablate.config import DEFAULT; "
        "t = state.TrialProgress(GridTrial('k', 'v', 0, DEFAULT)); print(t.threshold, 'torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["475.0", "False"], out
