"""The report read against its data (issue 36, item 4): every seed count, verdict, percentage and interval of
the claims, seeds and comparison sentences (``report_reading``), for the committed CartPole report against the
tables the same build wrote (no store of it here), for the committed Pong report against its tables, and for a
synthetic ablation with seeds in rounds against ``ablate.load`` of its store. Mutated sentences (the old
"5 per variant (0, 1, 2, 3, 4)" among them) show that each check can fail."""

import json
from pathlib import Path

import pandas as pd
import pytest
from report_reading import ReportData, check_all, check_claims, check_comparisons, check_seeds
from test_report import make_store
from test_report_claims import VARIANTS

import ablate
from ablate.launch.secrets import shown_command
from ablate.launch.tracking import Tracker
from ablate.reporting.data import report_data
from ablate.reporting.document import build_report
from ablate.reporting.reader import RunReader
from ablate.reporting.results import load_ablation

REPORTS = Path(__file__).parents[1] / "reports"


def _committed(name: str) -> tuple[str, ReportData]:
    folder = REPORTS / name
    tables = folder / "tables"
    trials = pd.read_csv(tables / "trials.csv")
    trials = trials[(trials.status == "FINISHED") & (trials.get("stage", "eval") == "eval")]
    claims = pd.read_csv(tables / "claims.csv") if (tables / "claims.csv").is_file() else None
    compare = pd.read_csv(tables / "comparisons.csv", keep_default_na=False, na_values=[""])
    data = ReportData(trials, pd.read_csv(tables / "convergence.csv"), compare, claims)
    return (folder / "report.md").read_text(), data


@pytest.fixture(scope="module")
def cartpole():
    text, data = _committed("cartpole")
    data.rounds_start = 10  # experiments/cartpole.toml: seeds = { start = 10, ... }; the store is not here
    return text, data


def test_the_committed_cartpole_report_says_what_its_tables_say(cartpole):
    text, data = cartpole
    assert len(data.claims) == 9 and len(data.trials) == 2510  # the tables are there and read
    assert check_all(text, data) == []


def test_the_committed_pong_report_says_what_its_tables_say():
    text, data = _committed("pong")
    assert len(data.claims) == 1 and set(data.trials.groupby("variant").size()) == {5}  # one claim, 5 seeds a side
    assert check_all(text, data) == []
    assert "5 and 5 seeds" in text
    # Both arms censored on a return level: the seeds counted as the budget are named (it read "budget ()").
    assert "(5 of 5 mlp seeds and 5 of 5 cnn seeds never reached -10)" in text and "budget ()" not in text


@pytest.mark.parametrize(
    "old, new",
    [
        ("| 1 | mlp | -19.1 [-19.5, -18.4] | better |", "| 1 | mlp | -19.2 [-19.5, -18.4] | better |"),
        ("| 2 | cnn | -20.4 [-20.5, -20.0] | reference |", "| 2 | cnn | -20.4 [-20.5, -20.0] | worse |"),
        (
            "4 of 5 mlp seeds and 5 of 5 cnn seeds never reached -15",
            "4 of 5 mlp seeds and 4 of 5 cnn seeds never reached -15",
        ),
    ],
)
def test_a_pong_sentence_other_than_its_tables_is_caught(old, new):
    text, data = _committed("pong")
    assert old in text and check_all(text, data) == []
    assert len(check_all(text.replace(old, new), data)) == 1


@pytest.mark.parametrize(
    "old, new, caught",
    [
        # the old Seeds sentence, written from the file's start rather than the seeds that ran
        (
            "**Seeds.** 10 to 640 per variant (0-639: 10 at first, more in rounds while one was open)",
            "**Seeds.** 10 per variant (0, 1, 2, 3, 4, 5, 6, 7, 8, 9)",
            "Seeds sentence",
        ),
        ("trains each variant's policy from 10 to 640 seeds", "trains each variant's policy from 10 seeds", "method"),
        ("- **10 to 640 seeds per variant**", "- **20 to 640 seeds per variant**", "limitations"),
        ("| narrow | 160 | worse, decided at round 5", "| narrow | 80 | worse, decided at round 5", "rounds table"),
        ("**Censoring.** 254 of 2,510", "**Censoring.** 253 of 2,510", "censoring"),
        ("- **l2**: 15 of 40 seeds", "- **l2**: 14 of 40 seeds", "l2"),
    ],
)
def test_a_seeds_sentence_other_than_the_data_is_caught(cartpole, old, new, caught):
    text, data = cartpole
    assert old in text
    problems = check_seeds(text.replace(old, new, 1), data)
    assert problems and all(caught in p for p in problems), problems


@pytest.mark.parametrize(
    "old, new",
    [
        ("**narrow** is **worse** than baseline", "**narrow** is **better** than baseline"),
        (
            "23% more episodes to solve (interval 1% to 50% more)",
            "23% more episodes to solve (interval 11% to 50% more)",
        ),
        ("14% more episodes to solve", "24% more episodes to solve"),  # not the claim's estimate
        ("IQM 616 vs 539; 640 and 640 seeds", "IQM 616 vs 564; 640 and 640 seeds"),
        ("IQM 669 vs 554; 320 and 320 seeds", "IQM 669 vs 554; 160 and 320 seeds"),
    ],
)
def test_a_claim_other_than_the_claims_table_is_caught(cartpole, old, new):
    text, data = cartpole
    assert old in text
    assert check_claims(text.replace(old, new, 1), data)


@pytest.mark.parametrize(
    "old, new",
    [
        (
            "episodes to solve: *exploratory: worse*, **29% more**",
            "episodes to solve: *exploratory: worse*, **39% more**",
        ),
        (
            "The primary claim (above): **worse**. P(fewer episodes) = 0.37",
            "The primary claim (above): **better**. P(fewer episodes) = 0.37",
        ),
        ("P(fewer episodes) = 0.37 [0.32, 0.41]", "P(fewer episodes) = 0.37 [0.32, 0.62]"),
        ("(IQM 696 vs 539; 95% CI 17% to 43% more)", "(IQM 696 vs 539; 95% CI 7% to 43% more)"),
        ("*exploratory: not separated*, IQM 487.4", "*exploratory: worse*, IQM 487.4"),
        ("19 of 40 dropout seeds and 35 of 640", "19 of 40 dropout seeds and 36 of 640"),
    ],
)
def test_a_comparison_other_than_the_comparisons_table_is_caught(cartpole, old, new):
    text, data = cartpole
    assert old in text
    assert check_comparisons(text.replace(old, new, 1), data)


ROUNDS = {"start": 8, "step": 2, "max": 10, "max_minutes": None}
SEEDS = {"base": 10, "fast": 8, "slow": 8, "spread": 10}
"""Seeds that ran: fast and slow were decided at the first look (8 seeds), spread ran to the cap with base."""


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """An ablation whose seeds came in rounds (8 per variant first, then 2 more to the open comparison and its
    reference), with ``grid.json`` and ``rounds.json`` as the runner writes them: the file's first seeds, every
    trial that ran, each variant's seeds and why it stopped (the runner's judge is the claims' rule)."""
    folder = tmp_path_factory.mktemp("against")
    ran = {f"{v}-s{s}" for v, n in SEEDS.items() for s in range(n)}
    uri = make_store(folder, "inrounds", VARIANTS, seeds=tuple(range(10)), only=ran)
    tracker = Tracker(uri, "inrounds")
    launch = tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'launch'")[0].info.run_id
    grid = json.loads(RunReader(uri, "inrounds").load_text(launch, "grid.json"))
    grid["trials"] = [t for t in grid["trials"] if t["key"] in ran]
    tracker.log_file(launch, "grid.json", json.dumps(grid | {"seeds": list(range(ROUNDS["start"]))}))
    variants = {"base": {"seeds": 10}, "spread": {"seeds": 10, "verdict": "undetermined", "why": "reached max"}}
    variants |= {
        v: {"seeds": 8, "verdict": w, "why": "decided at round 1"} for v, w in (("fast", "better"), ("slow", "worse"))
    }
    tracker.log_file(launch, "rounds.json", json.dumps({"design": ROUNDS, "round": 2, "variants": variants}))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test")
        report = build_report("inrounds", tracking_uri=uri, out_root=folder / "reports", attach=False).folder
    return (report / "report.md").read_text(), ablate.load("inrounds", tracking_uri=uri), uri


def test_a_synthetic_ablation_in_rounds_says_what_ablate_load_says(synthetic):
    text, results, uri = synthetic
    trials = results.trials[results.trials.status == "FINISHED"]
    assert trials.groupby("variant").size().to_dict() == SEEDS  # seeds in rounds: variants differ
    data = ReportData(trials, results.convergence, results.comparisons, results.claims, ROUNDS["start"])
    problems = check_all(text, data)
    assert problems == [], "\n".join(problems)
    # and against the report's own data model, computed once (reporting.data.ReportData), the same words
    model = report_data(load_ablation("inrounds", uri), shown_command(["ablate", "report", "inrounds"]))
    finished = model.trials[(model.trials.status == "FINISHED") & (model.trials.stage == "eval")]
    start = model.ablation.launch["rounds"]["design"]["start"]
    assert check_all(text, ReportData(finished, model.convergence, model.comparisons, model.claims, start)) == []
    # The grid's seeds are the first round's (0, 1, 2): the old sentence, written from them, is caught.
    old = text.replace(text.split("**Seeds.** ")[1].split(":")[0], "8 per variant (0, 1, 2, 3, 4, 5, 6, 7)", 1)
    assert any("Seeds sentence" in p for p in check_seeds(old, data))
