"""Read a rendered report.md back against the data it was built from (issue 36, item 4): every seed count,
verdict, percentage and interval in its claims, seeds and comparison sentences, with its own small parser (not
the report's formatting code), so that a sentence written from anything but the data is caught. Each check
returns the problems it found (``[]``: the text says what the data say)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import pandas as pd

METRICS = {"episodes to solve": "episodes_to_solve", "area under the curve (AUC)": "auc"}
NUMBER = re.compile(r"(?<![\w.])([-+−]?)(\d[\d,]*(?:\.\d+)?)(%?)")


@dataclass
class ReportData:
    """What a report says must come from: its trials (finished evaluation trials), per-variant convergence
    table, comparisons, claims (None where the report predates ``claims.csv``) and the rounds' first seeds."""

    trials: pd.DataFrame
    convergence: pd.DataFrame
    comparisons: pd.DataFrame
    claims: pd.DataFrame | None
    rounds_start: int | None = None

    @property
    def seeds(self) -> dict[str, set[int]]:
        return {v: {int(s) for s in g.seed} for v, g in self.trials.groupby("variant")}

    def unsolved(self, variant: str) -> int:
        mine = self.trials[self.trials.variant == variant]
        return int((mine.solved.astype(float) != 1).sum())


def numbers(text: str) -> list[tuple[float, int, bool]]:
    """Every number in ``text``: (value, decimals shown, signed). ``1,500`` is 1500; ``+3.6`` is signed."""
    out = []
    for sign, digits, _ in NUMBER.findall(text):
        value = float(digits.replace(",", ""))
        decimals = len(digits.split(".")[1]) if "." in digits else 0
        out.append((-value if sign in "-−" and sign else value, decimals, bool(sign)))
    return out


def shows(token: tuple[float, int, bool], value: float) -> bool:
    """Whether the number ``token`` is ``value`` as shown (rounded to its decimals; unsigned: its magnitude)."""
    shown, decimals, signed = token
    if value is None or not math.isfinite(value):
        return False
    value = value if signed else abs(value)
    return abs(value - (shown if signed else abs(shown))) <= 0.5 * 10**-decimals + 1e-9


def unexplained(text: str, pool: list[float]) -> list[float]:
    """The numbers of ``text`` that no value of ``pool`` shows. The setting that adds seeds (a `code` span) and
    what they would cost at the launch's pace are advice derived from the claim's seeds, not data: left out."""
    text = re.sub(r"`[^`]*`", "", text)
    text = re.sub(r", [\d,]+ more trials: about [^.;]*", "", text)
    pool = [float(p) for p in pool if p is not None and not pd.isna(p)]
    return [t[0] for t in numbers(text) if not any(shows(t, p) for p in pool)]


def section(text: str, title: str) -> str:
    """The text under the heading that contains ``title``, up to the next heading of any level."""
    heading = re.search(rf"^#+ .*{re.escape(title)}.*$", text, flags=re.M)
    if not heading:
        return ""
    rest = text[heading.end() :]
    end = re.search(r"^#+ ", rest, flags=re.M)
    return rest[: end.start()] if end else rest


def seed_list(text: str) -> set[int]:
    """``0-4, 10`` or ``0, 1, 2`` as a set of seeds."""
    seeds: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if re.fullmatch(r"\d+-\d+", part):
            low, high = map(int, part.split("-"))
            seeds |= set(range(low, high + 1))
        elif part.isdigit():
            seeds.add(int(part))
    return seeds


def _span(counts: dict[str, int]) -> tuple[int, int]:
    return min(counts.values()), max(counts.values())


def check_seeds(text: str, data: ReportData) -> list[str]:
    """The seeds sentences: the method's paragraph, Appendix A's **Seeds.**, the limitations' first line (body and
    appendix), the rounds' table, the censoring line and the per-variant unsolved lines."""
    problems = []
    counts = {v: len(s) for v, s in data.seeds.items()}
    fewest, most = _span(counts)
    said = "seeds" if fewest == most else f"{fewest} to {most} seeds"
    method = section(text, "Method (generated)")
    found = re.search(r"policy from (\d+)(?: to (\d+))? seeds", method)
    if not found or (int(found[1]), int(found[2] or found[1])) != (fewest, most):
        problems.append(f"method: {found[0] if found else 'no seed count'!r}, the data: {fewest} to {most} ({said})")
    sentence = re.search(
        r"\*\*Seeds\.\*\* (\d+)(?: to (\d+))? per variant \(([^):]*)(?:: (\d+) at first[^)]*)?\)", text
    )
    if not sentence:
        problems.append("appendix: no **Seeds.** sentence")
    else:
        shown = (int(sentence[1]), int(sentence[2] or sentence[1]))
        if shown != (fewest, most):
            problems.append(f"Seeds sentence {sentence[0]!r}: counts {shown}, the data ran {fewest} to {most}")
        ran = set().union(*data.seeds.values())
        if seed_list(sentence[3]) != ran:
            problems.append(f"Seeds sentence {sentence[0]!r}: seeds {sentence[3]!r}, the data ran {sorted(ran)}")
        if sentence[4] is not None and data.rounds_start is not None and int(sentence[4]) != data.rounds_start:
            problems.append(f"Seeds sentence: {sentence[4]} at first, the rounds started at {data.rounds_start}")
    for line in re.findall(r"^- \*\*(\d+(?: to \d+)?) seeds? per variant", text, flags=re.M):
        if tuple(map(int, line.split(" to "))) not in {(fewest, most), (most,)} or (
            " to " not in line and fewest != most
        ):
            problems.append(f"limitations: {line} seeds per variant, the data ran {fewest} to {most}")
    claims = {} if data.claims is None else dict(zip(data.claims.variant, data.claims.verdict, strict=True))
    rounds = r"^\| (\S+) \| (\d+) \| (?:(\w+), )?[^|]*(?:decided|max|reference|budget|failed)[^|]*\|$"
    for variant, seeds, verdict in re.findall(rounds, text, re.M):
        if counts.get(variant) != int(seeds):
            problems.append(f"rounds table: {variant} {seeds} seeds, the data: {counts.get(variant)}")
        if verdict and claims and claims.get(variant) != verdict:
            problems.append(f"rounds table: {variant} {verdict}, the claims: {claims.get(variant)}")
    censored = re.search(r"\*\*Censoring\.\*\* ([\d,]+) of ([\d,]+) trials did not solve", text)
    unsolved = sum(data.unsolved(v) for v in counts)
    if censored and tuple(int(n.replace(",", "")) for n in censored.groups()) != (unsolved, len(data.trials)):
        problems.append(f"censoring: {censored[0]!r}, the data: {unsolved} of {len(data.trials)}")
    for variant, k, n in re.findall(r"^- \*\*(\S+)\*\*: ([\d,]+) of ([\d,]+) seeds did not solve", text, flags=re.M):
        if (int(k.replace(",", "")), int(n.replace(",", ""))) != (data.unsolved(variant), counts.get(variant)):
            problems.append(f"{variant}: {k} of {n} unsolved, the data: {data.unsolved(variant)} of {counts[variant]}")
    return problems


def _claim_interval(row) -> list[float]:
    return [x for x in (row.change_low, row.change_high) if math.isfinite(x)]


def check_claims(text: str, data: ReportData) -> list[str]:
    """The Claims section, one line per row of ``claims``: the names, the verdict, the seeds each side, the
    change and its direction, the interval's ends, the IQMs, the seeds needed, and no number the row lacks."""
    problems = []
    lines = [x for x in section(text, "Claims (generated)").splitlines() if x.startswith("- **")]
    claims = data.claims
    if len(lines) != len(claims):
        return [f"claims: {len(lines)} lines, {len(claims)} claims"]
    for line, row in zip(lines, claims.itertuples(), strict=True):
        where = f"claim {row.variant}"
        if not line.startswith(f"- **{row.variant}** ") or f" {row.reference}" not in line:
            problems.append(f"{where}: names in {line!r}")
        verdicts = re.findall(r"\*\*(better|worse|equivalent|undetermined)\*\*", line)
        if verdicts != [row.verdict]:
            problems.append(f"{where}: verdict {verdicts}, the data: {row.verdict}")
        seeds = re.search(r"(\d+) and (\d+) seeds", line)
        counts = data.seeds
        if not seeds or (int(seeds[1]), int(seeds[2])) != (row.n_variant, row.n_reference):
            problems.append(f"{where}: {seeds[0] if seeds else 'no seeds'}, claims: {row.n_variant}, {row.n_reference}")
        elif len(counts.get(row.variant, ())) != int(seeds[1]) or len(counts.get(row.reference, ())) < int(seeds[2]):
            # the variant's every seed; the reference's first ones where the claim was decided at an earlier look
            ran = (len(counts.get(row.variant, ())), len(counts.get(row.reference, ())))
            problems.append(f"{where}: {seeds[0]}, the trials ran {ran[0]} and {ran[1]}")
        if row.metric == "episodes_to_solve":
            change = re.search(r"(\d+)% (more|fewer) episodes to solve|no change", line)
            direction = "more" if row.change > 0 else "fewer"
            if not change or (
                change[0] != "no change"
                and (not shows((float(change[1]), 0, False), row.change) or change[2] != direction)
            ):
                problems.append(f"{where}: change {change[0] if change else None!r}, the data: {row.change:+.1f}%")
        interval = line.split("(interval", 1)[1].split(")", 1)[0] if "(interval" in line else ""
        ends = numbers(interval)
        expected = _claim_interval(row)
        if len(ends) != len(expected) or not all(any(shows(t, e) for e in expected) for t in ends):
            problems.append(f"{where}: interval {interval!r}, the data: {row.change_low:.1f} to {row.change_high:.1f}")
        iqms = re.search(r"(?:IQM|mean) (?:≥ )?([-\d,.]+) vs ([-\d,.]+)", line)
        if not iqms or not all(
            shows(numbers(x)[0], v) for x, v in ((iqms[1], row.variant_value), (iqms[2], row.reference_value))
        ):
            problems.append(
                f"{where}: {iqms[0] if iqms else 'no IQMs'!r}, the data: {row.variant_value} vs {row.reference_value}"
            )
        needed = re.search(r"(about (\d+)|more than (\d+)) seeds per variant", line)
        if row.verdict == "undetermined" and not pd.isna(row.seeds_needed):
            want = (
                f"more than {int(row.seeds_cap)}" if math.isinf(row.seeds_needed) else f"about {int(row.seeds_needed)}"
            )
            if not needed or needed[1] != want:
                problems.append(f"{where}: {needed[0] if needed else 'no seeds needed'!r}, the data: {want}")
        elif needed:
            problems.append(f"{where}: {needed[0]!r} on a {row.verdict} claim")
        pool = [row.change, *expected, row.variant_value, row.reference_value, row.n_variant, row.n_reference]
        pool += [row.seeds_needed, row.seeds_cap, 100 * row.level, 80, row.margin]
        # judged on the AUC: the share of its seeds censored and the rule's share (claims.CENSORED_SHARE)
        pool += [100 * getattr(row, "censored", 0.0), 25, getattr(row, "seeds_first", 0)]
        pool += [t[0] for t in numbers(str(row.reason or ""))]  # the claims table's own words
        stray = unexplained(line, pool)
        if stray:
            problems.append(f"{where}: numbers {stray} in {line!r} are not the claim's")
    return problems


def _table(block: str) -> list[dict[str, str]]:
    """The first pipe table in ``block`` as rows of {header: cell}."""
    lines = [line for line in block.splitlines() if line.startswith("|")]
    if len(lines) < 2:
        return []
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    return [dict(zip(cells[0], row, strict=True)) for row in cells[2:]]


def check_rank_table(text: str, data: ReportData) -> list[str]:
    """The Claims section's table: each variant's solved seeds (where there is a threshold), its IQM and interval
    on each metric it shows (episodes to solve, AUC), and the primary claim."""
    problems = []
    claims = {} if data.claims is None else dict(zip(data.claims.variant, data.claims.verdict, strict=True))
    table = data.convergence.drop_duplicates("variant").set_index("variant")
    rows = _table(section(text, "Claims"))
    for entry in rows:
        variant = entry["variant"]
        row = table.loc[variant]
        mine = data.trials[data.trials.variant == variant]
        if "solved" in entry:
            solved, ran = (int(x) for x in entry["solved"].split("/"))
            if (solved, ran) != (int((mine.solved.astype(float) == 1).sum()), len(mine)):
                right = f"{len(mine) - data.unsolved(variant)}/{len(mine)}"
                problems.append(f"rank table: {variant} {solved}/{ran}, the trials: {right}")
        shown = {
            "episodes to solve, IQM [95% CI]": [row.episodes_iqm, row.episodes_iqm_ci_low, row.episodes_iqm_ci_high],
            "AUC, IQM [95% CI]": [row.auc_iqm, row.auc_ci_low, row.auc_ci_high],
        }
        for column, values in shown.items():
            if column not in entry:
                continue
            found = numbers(entry[column])
            if len(found) != 3 or not all(shows(t, v) for t, v in zip(found, values, strict=True)):
                problems.append(f"rank table: {variant} {column} {entry[column]}, the data: {values}")
        claim = entry["primary claim"]
        if claims and claim != claims.get(variant, "reference"):
            problems.append(f"rank table: {variant} {claim!r}, the claims: {claims.get(variant)!r}")
    if not rows:
        problems.append("rank table: no rows")
    return problems


def _metric(name: str) -> str | None:
    found = re.fullmatch(r"return after ([\d,]+) episodes", name)
    if found:
        return f"return_at_{found[1].replace(',', '')}"
    level = re.fullmatch(r"episodes to reach a rolling return of (-?[\d.]+)", name)
    return f"episodes_to_{level[1]}" if level else METRICS.get(name)


def _check_sizes(line: str, row: pd.Series, where: str) -> list[str]:
    """A comparison's size where it is said: the two IQMs; episodes, the change first and every percentage one
    of the change and its interval's ends; returns, (change; 95% CI low to high) in that order."""
    problems = []
    if "exploratory: too few seeds" in line or "cannot separate them" in line:
        return problems
    values = re.search(r"(?:IQM|mean|\)) (?:≥ )?([-\d,.]+) vs ([-\d,.]+)|\*, ([-\d,.]+) vs ([-\d,.]+)", line)
    shown = [g for g in values.groups() if g is not None] if values else []
    if len(shown) != 2 or not all(
        shows(numbers(x)[0], v) for x, v in zip(shown, (row.variant_value, row.reference_value), strict=True)
    ):
        problems.append(f"{where}: the values {shown}, the data: {row.variant_value} vs {row.reference_value}")
    if row.metric.startswith("episodes_to_"):
        plain = re.sub(r"95% |\(\d+%\)", "", line.split(" P(fewer")[0].split(" Seeds needed")[0])
        pcts = [numbers(m)[0] for m in re.findall(r"[-+]?\d+%", plain)]
        ends = (row.change, row.change_low, row.change_high)
        if not pcts or not shows(pcts[0], row.change) or not all(any(shows(t, e) for e in ends) for t in pcts):
            problems.append(f"{where}: percentages {[t[0] for t in pcts]}, the data: {ends}")
    else:
        sized = re.search(r"\(([-+][\d.,]+); 95% CI ([-+][\d.,]+) to ([-+][\d.,]+)\)", line)
        ends = (row.change, row.change_low, row.change_high)
        if not sized or not all(shows(numbers(x)[0], e) for x, e in zip(sized.groups(), ends, strict=True)):
            problems.append(f"{where}: {sized[0] if sized else 'no interval'!r}, the data: {ends}")
    return problems


def check_comparisons(text: str, data: ReportData) -> list[str]:
    """Appendix D, per variant and metric: the exploratory verdict, the primary claim it repeats, the seeds
    needed (the claims' one figure on the primary metric), the unsolved seeds each side, and no number the
    comparison's row lacks."""
    problems = []
    appendix = section(text, "Every comparison (generated)")
    compare = data.comparisons
    claims = None if data.claims is None else data.claims.set_index("variant")
    blocks = re.split(r"^- \*\*(\S+)\*\* vs (\S+):$", appendix, flags=re.M)
    seen = 0
    for variant, reference, block in zip(blocks[1::3], blocks[2::3], blocks[3::3], strict=True):
        for line in re.findall(r"^    - (.*)$", block, flags=re.M):
            name = line.split(":", 1)[0]
            metric = _metric(name)
            rows = compare[(compare.variant == variant) & (compare.metric == metric)]
            if len(rows) != 1:
                problems.append(f"{variant} {name}: {len(rows)} rows in the comparisons")
                continue
            row, seen = rows.iloc[0], seen + 1
            where = f"{variant} vs {reference}, {name}"
            said = re.findall(r"\*(exploratory: [a-z ]+?)\*", line)
            if said[:1] != [row.verdict]:
                problems.append(f"{where}: {said[:1]}, the comparisons: {row.verdict!r}")
            primary = re.search(r"The primary claim \(above\): \*\*(\w+)\*\*", line)
            if claims is not None and str(row.primary) == "True":
                claim = claims.loc[variant]
                if not primary or primary[1] != claim.verdict:
                    problems.append(
                        f"{where}: primary claim {primary[1] if primary else None}, the claims: {claim.verdict}"
                    )
                if line.count("Seeds needed") > 1:
                    problems.append(f"{where}: two seeds-needed figures")
                needed = re.search(r"Seeds needed[^:]*: (about (\d+)|more than (\d+)) seeds per variant", line)
                if needed and claim.verdict == "undetermined":
                    want = "more than" if math.isinf(claim.seeds_needed) else f"about {int(claim.seeds_needed)}"
                    if not needed[1].startswith(want):
                        problems.append(f"{where}: seeds needed {needed[1]!r}, the claim's: {claim.seeds_needed}")
            elif primary:
                problems.append(f"{where}: a primary claim on a row that is not primary")
            problems += _check_sizes(line, row, where)
            reached = re.search(r"(\d+) of (\d+) \S+ seeds and (\d+) of (\d+) \S+ seeds never reached (-?[\d.]+)", line)
            if reached:
                counts = {v: len(s) for v, s in data.seeds.items()}
                never_at = {
                    v: int((g[f"reached_{reached[5]}"].astype(float) != 1).sum())
                    for v, g in data.trials.groupby("variant")
                }
                want = (never_at[variant], counts[variant], never_at[reference], counts[reference])
                if tuple(map(int, reached.groups()[:4])) != want:
                    problems.append(f"{where}: {reached[0]!r}, the trials: {want}")
            never = re.search(r"(\d+) of (\d+) \S+ seeds and (\d+) of (\d+) \S+ seeds never solved", line)
            if never:
                counts = {v: len(s) for v, s in data.seeds.items()}
                want = (data.unsolved(variant), counts[variant], data.unsolved(reference), counts[reference])
                if tuple(map(int, never.groups())) != want:
                    problems.append(f"{where}: {never[0]!r}, the trials: {want}")
            pool = [
                row.get(c)
                for c in (
                    "point",
                    "low",
                    "high",
                    "variant_value",
                    "reference_value",
                    "change",
                    "change_low",
                    "change_high",
                    "n_variant",
                    "n_reference",
                    "seeds_needed",
                    "seeds_needed_smallest",
                    "seeds_cap",
                    "p_improvement",
                    "p_improvement_ci_low",
                    "p_improvement_ci_high",
                )
            ]
            pool += [data.unsolved(variant), data.unsolved(reference), 95, 80, 10, 4]  # 4: 'fewer than 4 seeds'
            pool += (
                [int(s) for s in re.findall(r"leaving out seeds? ([\d, ]+)", line)[0].replace(",", " ").split()]
                if "leaving out seed" in line
                else []
            )
            if metric and metric.startswith("return_at_"):
                pool.append(float(metric.removeprefix("return_at_")))
            if metric and metric.startswith("episodes_to_") and metric != "episodes_to_solve":
                level = metric.removeprefix("episodes_to_")
                pool.append(float(level))
                pool += [
                    int((g[f"reached_{level}"].astype(float) != 1).sum()) for _, g in data.trials.groupby("variant")
                ]
            if claims is not None and str(row.primary) == "True":
                pool += [claims.loc[variant].seeds_needed, claims.loc[variant].seeds_cap]
            stray = unexplained(line, pool)
            if stray:
                problems.append(f"{where}: numbers {stray} are not the comparison's: {line!r}")
    if seen != len(compare):
        problems.append(f"appendix D: {seen} comparison lines, the comparisons table has {len(compare)} rows")
    return problems


def check_results_table(text: str, data: ReportData) -> list[str]:
    """Appendix C's episodes table: seeds, solved and the IQM with its interval, against the convergence table."""
    problems = []
    table = data.convergence.drop_duplicates("variant").set_index("variant")
    rows = re.findall(
        r"^\| (\S+) \| (\d+) \| (\d+)/(\d+) \| [^|]+ \| ([^|]+) \|", section(text, "Results (generated)"), re.M
    )
    for variant, seeds, solved, ran, iqm in rows:
        row = table.loc[variant]
        if (int(seeds), int(solved), int(ran)) != (len(data.seeds[variant]), int(row.solved), int(row.seeds_run)):
            problems.append(
                f"results table: {variant} {seeds} seeds {solved}/{ran}, the data: {int(row.solved)}/{row.seeds_run}"
            )
        values = [row.episodes_iqm, row.episodes_iqm_ci_low, row.episodes_iqm_ci_high]
        if not all(shows(t, v) for t, v in zip(numbers(iqm), values, strict=True)):
            problems.append(f"results table: {variant} {iqm.strip()}, the data: {values}")
    return problems


def check_all(text: str, data: ReportData) -> list[str]:
    """Every check this module has, for a report with claims."""
    return [
        *check_seeds(text, data),
        *check_claims(text, data),
        *check_rank_table(text, data),
        *check_results_table(text, data),
        *check_comparisons(text, data),
    ]
