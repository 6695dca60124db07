"""ablate.reporting.layout and discussion: the hand-in's body and appendix, every sentence true for the run it
describes (small stores: tuned values that differ, too few seeds for any claim, too few for the leave-one-out
check, no tuning), and the student's discussion.md kept across regenerations and printed under their name."""

import os
import re

import numpy as np
import pandas as pd
import pytest
from test_report import make_store, rising
from test_report_tuning import make_tuned_store

from ablate.reporting import discussion
from ablate.reporting.document import build_report


@pytest.fixture(autouse=True)
def _no_pdf(monkeypatch):
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test")


def _report(folder, name, uri):
    return (
        build_report(name, tracking_uri=uri, out_root=folder / "reports", attach=False).folder / "report.md"
    ).read_text()


def _body(text):
    return text.split("\n## Appendix\n")[0]


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    """Untuned stores: 3 seeds (no claim can exist), 4 seeds (claims, but leaving one out leaves 3 and 3)."""
    folder = tmp_path_factory.mktemp("layout")
    apart = {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 10)}}
    uri = make_store(folder, "three", apart, seeds=(0, 1, 2))
    make_store(folder, "four", apart, seeds=(0, 1, 2, 3))
    return folder, uri


def test_too_few_seeds_for_any_claim_promises_no_leave_one_out(stores, tmp_path):
    _, uri = stores
    text = _report(tmp_path, "three", uri)
    assert "*exploratory: too few seeds*" in text
    assert "no comparison here reached a claim, so no claim was checked by leaving out a seed" in _body(text)
    assert "survives leaving out any one seed" not in text and "marked **fragile**" not in text


def test_too_few_seeds_for_the_leave_one_out_check_says_so(stores, tmp_path):
    _, uri = stores
    text = _report(tmp_path, "four", uri)
    assert "**lower**" in text  # 4 against 4 seeds can reach a claim ...
    assert "no claim here was checked that way: each rests on every seed" in _body(text)  # ... but not its check
    assert "each claim says whether it survives" not in text


def test_an_untuned_report_says_nothing_of_tuning(stores, tmp_path):
    _, uri = stores
    text = _report(tmp_path, "four", uri)
    assert "Tuning (generated)" not in text and "depend on the learning rate" not in text
    assert "chosen among" not in text and "Eimer" not in text
    assert "more than one knob" not in text  # a and b differ in nothing but their curves here


@pytest.fixture(scope="module")
def tuned4(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tuned4")
    return folder, make_tuned_store(folder)


def test_a_comparison_at_two_tuned_values_is_the_design_not_a_second_change(tuned4, tmp_path):
    """Each variant at its own chosen learning rate is how the comparison is made (Patterson et al., 2024), so a
    chosen value that differs from the reference's is not a second knob the difference "cannot be put down to":
    the report said "deep against baseline changes hidden sizes and learning rate (0.03 against 0.1)" in the
    claims and again as a limitation. The chosen values stay where they are read: the tuning and the
    learning-rate appendices."""
    _, uri = tuned4
    text = _report(tmp_path, "tuned", uri)
    body = _body(text)
    assert "compared at their chosen values on evaluation seeds tuning never saw" in body
    assert "more than one knob" not in text and "knobs at once" not in text, text
    assert "isolates one change" not in text
    depends = text.split("Does the finding depend on the learning rate? (generated)")[1].split("\n### ")[0]
    assert "deep vs baseline, area under the curve (AUC): at the base value (both at learning rate 0.03)" in depends
    assert "at the chosen values (learning rate 0.03 against 0.1)" in depends


def test_no_change_with_the_learning_rate_says_none_could_with_three_seeds(tmp_path_factory, tmp_path):
    folder = tmp_path_factory.mktemp("tuned3")
    uri = make_tuned_store(folder, eval_seeds=[0, 1, 2])
    text = _report(tmp_path, "tuned", uri)
    depends = text.split("Does the finding depend on the learning rate? (generated)")[1].split("\n### ")[0]
    assert "No finding changes with the learning rate, but none could" in depends
    assert re.search(r"The estimates did move: \S+ vs baseline on .+ went from \S+ at the base value", depends)


def test_the_body_comes_first_and_the_rest_is_in_the_appendix(tuned4, tmp_path):
    _, uri = tuned4
    text = _report(tmp_path, "tuned", uri)
    body, appendix = text.split("\n## Appendix\n")
    headings = re.findall(r"^## (.+)$", body, flags=re.M)
    assert headings == [
        "Question (generated)",
        "Method (generated)",
        "Claims (generated)",
        "Figures (generated)",
        "Limitations (generated)",
        "Discussion",
        "References",
    ]
    assert len(re.findall(r"^!\[", body, flags=re.M)) == 2 or "probability_of_improvement" not in text
    for moved in ("Tuning (generated)", "Every comparison (", "Reproducibility (", "Glossary", "Wall-clock times"):
        assert moved in appendix and moved not in body, moved
    for reference in ("Williams, R. J. (1992)", "MIT 6.S191", "Patterson", "Agarwal", "Colas", "Eimer"):
        assert reference in body, reference


def test_the_discussion_is_created_once_kept_and_printed_under_its_author(stores, tmp_path):
    _, uri = stores
    result = build_report("four", tracking_uri=uri, out_root=tmp_path / "reports", attach=False)
    path = result.folder / "discussion.md"
    assert path.read_text() == discussion.TEMPLATE
    assert oct(result.folder.stat().st_mode & 0o777) == "0o755"
    text = (result.folder / "report.md").read_text()
    assert "*The discussion is missing: write it in" in text and "the student's own" in text
    mine = "Author: Ada Student\n\nI expected **b** to learn faster; it did not.\n\n- next: 10 seeds\n"
    path.write_text(mine)
    again = build_report("four", tracking_uri=uri, out_root=tmp_path / "reports", attach=False)
    assert (again.folder / "discussion.md").read_text() == mine  # survives the rebuild's swap
    text = (again.folder / "report.md").read_text()
    body = _body(text)
    assert "## Discussion — Ada Student" in body and "discussion is missing" not in text
    assert "I expected **b** to learn faster; it did not.\n\n- next: 10 seeds" in body  # verbatim
    assert "the Discussion is Ada Student's own" in body
    typst_source = (again.folder / "report.typ").read_text()
    assert '"Ada Student"' in typst_source or "Ada Student" in typst_source
    assert "Written about other data" not in text  # saved after the launch it discusses
    # Saved before the launch whose trials the report shows: the student's "6 to 8 seeds would decide" was printed
    # unchanged after the data moved to 42 seeds (3e01923). Now the report says the text is about other data.
    os.utime(again.folder / "discussion.md", (86_400, 86_400))  # 1970-01-02
    stale = build_report("four", tracking_uri=uri, out_root=tmp_path / "reports", attach=False)
    body = _body((stale.folder / "report.md").read_text())
    assert "**Written about other data:** discussion.md was last saved 1970-01-02 00:00 UTC, before the launch" in body


def test_the_discussion_template_reads_as_missing_and_an_edit_as_written(tmp_path):
    assert discussion.read(tmp_path) == discussion.Discussion(None, None)  # no file yet
    (tmp_path / discussion.FILE).write_text(discussion.TEMPLATE)
    assert discussion.read(tmp_path).text is None
    (tmp_path / discussion.FILE).write_text(discussion.TEMPLATE.replace("(your name)", "Bo"))
    written = discussion.read(tmp_path)
    assert written.author == "Bo" and written.text and "What surprised you?" in written.text


def test_every_variant_has_a_role_in_the_variants_table(stores, tmp_path):
    _, uri = stores
    text = _report(tmp_path, "four", uri)
    assert "| b | compared with a |" in text and "| a | baseline (reference) |" in text


def test_markdown_keeps_quotes_and_counts_one_episode():
    from ablate.reporting.sections import _episodes
    from ablate.reporting.text import esc

    assert esc("the course's <b>") == "the course's &lt;b&gt;"
    assert _episodes(1) == "1 episode" and _episodes(32) == "32 episodes"


def test_the_terminal_summary_lines_up_under_its_header(tmp_path):
    import pandas as pd

    from ablate.reporting.document import terminal_summary

    (tmp_path / "tables").mkdir()
    rows = [
        {"variant": "activation=tanh,depth=1", "seeds_run": 3, "solved": 3, "median_censored": False},
        {"variant": "a", "seeds_run": 3, "solved": 1, "median_censored": True},
    ]
    for row, (median, final) in zip(rows, [(644.0, 480.2), (1000.0, 90.0)], strict=True):
        row |= {"episodes_median": median, "final_rolling_mean_iqm": final}
    pd.DataFrame(rows).to_csv(tmp_path / "tables" / "convergence.csv", index=False)
    lines = terminal_summary(tmp_path).splitlines()
    assert len({len(line) for line in lines}) == 1, lines  # every column ends where its header ends
    assert lines[1].index("3/3") + 3 == lines[0].index("solved") + len("solved")


def test_status_lists_variants_in_the_files_order_else_by_number():
    from ablate.reporting.status import _variant_table

    states = {
        "k1": ("relu,depth=2", "FINISHED"),
        "k2": ("relu,depth=1", "FINISHED"),
        "k3": ("relu,depth=10", "RUNNING"),
    }
    names = [line.split()[0] for line in _variant_table(states).splitlines()[1:]]
    assert names == ["relu,depth=1", "relu,depth=2", "relu,depth=10"]
    names = [line.split()[0] for line in _variant_table(states, ["relu,depth=10", "relu,depth=2"]).splitlines()[1:]]
    assert names == ["relu,depth=10", "relu,depth=2", "relu,depth=1"]


def test_each_way_to_a_report_says_in_one_line_why_there_is_no_pdf(stores, tmp_path, monkeypatch, capsys):
    import sys

    import ablate
    from ablate.cli import main

    _, uri = stores
    monkeypatch.undo()  # the real PDF path, without the typst package: as on a machine that lacks it
    monkeypatch.setitem(sys.modules, "typst", None)
    assert main(["report", "four", "--tracking-uri", uri, "--out", str(tmp_path / "cli")]) == 0
    out = capsys.readouterr().out
    assert "no PDF: the typst package is missing (pip install typst, or make setup)" in out.splitlines()
    ablate.report("four", tracking_uri=uri, reports_folder=tmp_path / "api")
    err = capsys.readouterr().err
    assert "no PDF: the typst package is missing (pip install typst, or make setup)" in err.splitlines()
    assert (
        not (tmp_path / "api" / "four" / "report.pdf").exists() and (tmp_path / "api" / "four" / "report.typ").exists()
    )


def test_a_launch_with_seeds_in_rounds_says_each_variants_seeds_and_why_it_stopped(tmp_path):
    import json

    from ablate.launch.tracking import Tracker

    apart = {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 10)}}
    uri = make_store(tmp_path, "rounds", apart, seeds=(0, 1, 2))
    make_store(tmp_path, "plain", apart, seeds=(0, 1, 2))
    tracker = Tracker(uri, "rounds")
    launch = tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'launch'")[0].info.run_id
    document = {
        "design": {"start": 3, "step": 3, "max": 9, "max_minutes": None},
        "round": 3,
        "variants": {"a": {"seeds": 9}, "b": {"seeds": 9, "verdict": "undetermined", "why": "reached max"}},
    }
    tracker.log_file(launch, "rounds.json", json.dumps(document))
    appendix = _report(tmp_path, "rounds", uri).split("\n## Appendix\n")[1]
    assert "Seeds were added in rounds: 3 per variant first, then 3 more per round" in appendix
    assert "| b | 9 | reached the most seeds (max) undecided |" in appendix
    assert "Seeds were added in rounds" not in _report(tmp_path, "plain", uri)


def test_seeds_that_differ_between_variants_are_said_as_a_range_not_the_grids_count(tmp_path):
    apart = {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 10)}}
    ran = {f"a-s{s}" for s in range(6)} | {f"b-s{s}" for s in range(3)}
    uri = make_store(tmp_path, "uneven", apart, seeds=tuple(range(6)), only=ran)
    body = _body(_report(tmp_path, "uneven", uri))
    assert "from 3 to 6 seeds on" in body and "from 6 seeds" not in body
    assert "**3 to 6 seeds per variant**" in body
    assert "(added in rounds" not in body  # no rounds.json: the range is not said to come from rounds
    # The method says the seeds that ran, not the file's 6 (it said "6 per variant (0, 1, 2, 3, 4, 5)").
    assert "**Seeds.** 3 to 6 per variant (0-5): each seeds torch" in _report(tmp_path, "uneven", uri)


def test_a_difference_claimed_by_a_later_holm_step_says_why_its_interval_still_reaches_no_change():
    from ablate.claims import Question
    from ablate.reporting.findings import claim_line

    question = Question("episodes_to_solve", relative=True, lower_is_better=True, smallest_effect=0.1, budget=100)
    fields = dict(variant="v", reference="base", metric="episodes_to_solve", verdict="worse", change=86.0)
    fields |= dict(p_difference=0.004, p_equivalence=0.9, level=0.01, margin=10.0, n_variant=30, n_reference=30)
    fields |= dict(look=5, bound="", seeds_needed=np.nan, seeds_cap=100, reason="")
    fields |= dict(variant_value=1049.0, reference_value=564.0)
    crossing = claim_line(pd.Series(dict(change_low=-7.0, change_high=163.0, **fields)), question)
    assert "Holm's step-down made this claim at the 1.00% level" in crossing and "still reaches no change" in crossing
    clear = claim_line(pd.Series(dict(change_low=3.0, change_high=163.0, **fields)), question)
    assert "Holm" not in clear


def test_the_question_without_a_solve_threshold_asks_how_fast_it_learns():
    from types import SimpleNamespace

    from ablate.reporting.layout import question

    pong = SimpleNamespace(
        variants=["cnn", "mlp"], baseline="cnn", any_solved=False, threshold=None, env_id="ALE/Pong-v5",
        grid={"description": "CNN vs MLP."}, reference=lambda v: "cnn", primary_metric="auc",
    )  # fmt: skip
    text = question(pong)
    assert "how fast REINFORCE learns on `ALE/Pong-v5`?" in text and "learns to learn" not in text
    assert "first on the area under the learning curve." in text
    cartpole = SimpleNamespace(
        **{**vars(pong), "threshold": 475.0, "any_solved": True, "env_id": "CartPole-v1"}
        | {"primary_metric": "episodes_to_solve"}
    )
    text = question(cartpole)
    assert "learns to reach a rolling mean return of 475 on `CartPole-v1`?" in text
    assert "first on episodes to solve (a comparison with more than 25% of its seeds unsolved" in text


def test_the_question_names_the_metric_the_claims_are_on_even_where_no_seed_solved():
    """Acrobot's claims were on episodes to solve (its file's primary, a threshold exists) while no seed had
    solved yet, and the Question said "first on the area under the learning curve" (3e01923)."""
    from types import SimpleNamespace

    from ablate.reporting.layout import question

    acrobot = SimpleNamespace(
        variants=["base", "wide"], baseline="base", any_solved=False, threshold=-100.0, env_id="Acrobot-v1",
        grid={}, reference=lambda v: "base", primary_metric="episodes_to_solve",
    )  # fmt: skip
    assert "first on episodes to solve" in question(acrobot)
    returns = SimpleNamespace(**{**vars(acrobot), "primary_metric": "return_at_500"})
    assert "first on return after 500 episodes." in question(returns)


def test_a_knob_written_at_the_bases_value_is_no_change(tmp_path):
    # A student's baseline wrote activation = "relu", the default: the report said "deep changes 2 knobs at once
    # against relu (activation and hidden sizes)" and listed "activation = relu" as the baseline's change.
    from ablate.reporting.results import Ablation
    from ablate.reporting.sections import changed_settings

    variants = {
        "relu": {"curve": rising(5, 30), "overrides": {"activation": "relu"}},
        "tanh": {"curve": rising(5, 20), "overrides": {"activation": "tanh"}},
        "deep": {"curve": rising(5, 10), "overrides": {"hidden_sizes": [8, 8]}, "hidden": [8, 8]},
        "same": {"curve": rising(5, 25), "overrides": {"hidden_sizes": [8], "depth": 1}},
    }
    base = {"model.activation": "relu", "model.hidden_sizes": [8]}
    uri = make_store(tmp_path, "knobs", variants, seeds=(0, 1, 2, 3), base=base)
    text = _report(tmp_path, "knobs", uri)
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if "compared with" in line}
    rows |= {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if "baseline (reference)" in line}
    assert "| nothing (the base) |" in rows["relu"] and "activation = relu" not in text
    assert "| hidden_sizes = [8, 8] |" in rows["deep"] and "| activation = tanh |" in rows["tanh"]
    assert "| nothing (the base) |" in rows["same"]  # [8] and depth 1 are the base's one layer of 8
    assert "knobs at once" not in text and "more than one knob" not in text
    grid = {
        "baseline": "relu",
        "base": base,
        "variants": [{"name": v, "overrides": s["overrides"]} for v, s in variants.items()],
    }
    ablation = Ablation("knobs", grid, {}, pd.DataFrame(), pd.DataFrame())
    assert ablation.changes("deep") == {"hidden_sizes": [8, 8]} and changed_settings(ablation, "deep") == [
        "hidden sizes"
    ]
    assert ablation.changes("tanh") == {"activation": "tanh"} and ablation.changes("same") == {}


def test_a_users_network_with_its_arguments_is_one_change():
    """A user's network with ``model_args`` was "mynet changes 2 knobs at once (model and model args)" (3e01923);
    the arguments alone, on the same network, are still a change of their own."""
    from ablate.reporting.results import Ablation
    from ablate.reporting.sections import changed_settings, comparison_intro

    grid = {
        "baseline": "baseline",
        "base": {"model.hidden_sizes": [32]},
        "variants": [
            {"name": "baseline", "overrides": {}},
            {"name": "mynet", "overrides": {"model": "mynet:make", "model_args": {"blocks": 2}}},
            {"name": "mynet4", "overrides": {"model": "mynet:make", "model_args": {"blocks": 4}}},
        ],
    }
    ablation = Ablation("mine", grid, {}, pd.DataFrame(), pd.DataFrame())
    assert changed_settings(ablation, "mynet") == ["model"] and comparison_intro(ablation) == []
    assert ablation.changes("mynet4", "mynet") == {"model_args": {"blocks": 4}}


def test_a_report_without_videos_promises_none_and_says_one_word_per_verdict(stores, tmp_path):
    # The limitations said "Videos show one greedy episode..." where the appendix said "No videos were
    # recorded"; the references named the exploratory "too few seeds" rule "too few seeds to tell".
    _, uri = stores
    text = _report(tmp_path, "three", uri)
    assert "No videos were recorded." in text and "Videos show" not in text and "Each video is" not in text
    assert "too few seeds to tell" not in text and "(The rank test behind *exploratory: too few seeds*" in text


def test_a_report_says_in_one_line_when_the_experiment_file_changed_since_its_launch(tmp_path, capsys):
    # A student removed a line from the file after the launch: the report kept describing the launch's copy and
    # never said the file had changed since.
    from ablate.cli import main
    from ablate.launch.tracking import Tracker

    apart = {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 10)}}
    uri = make_store(tmp_path, "edited", apart, seeds=(0, 1, 2))
    tracker = Tracker(uri, "edited")
    launch = tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'launch'")[0].info.run_id
    ran = 'name = "edited"\nseeds = 3\nbaseline = "a"\n[[variants]]\nname = "a"\nactivation = "relu"\n'
    tracker.log_file(launch, "experiment.toml", ran)
    path = tmp_path / "edited.toml"
    tracker.client.set_tag(launch, "ablate.experiment_file", str(path))
    path.write_text(ran)
    assert "has changed since this launch ran it" not in _report(tmp_path, "edited", uri)
    path.write_text(ran.replace('activation = "relu"\n', ""))
    lines = [x for x in _report(tmp_path, "edited", uri).splitlines() if "has changed since" in x]
    assert len(lines) == 1 and f"The experiment file {path} has changed since this launch ran it" in lines[0]
    assert f"ablate run {path} --fresh" in lines[0]
    assert main(["report", "edited", "--tracking-uri", uri, "--out", str(tmp_path / "cli"), "--no-pdf"]) == 0
    assert "has changed since this launch ran it" in capsys.readouterr().out
