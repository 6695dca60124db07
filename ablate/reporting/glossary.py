"""The report's glossary and references: the terms its sentences use, and the papers its method and statistics
rest on (the algorithm, the course's lab, the protocol, the statistics of the claims)."""

from __future__ import annotations

from ablate.design import ALPHA, percent
from ablate.measures import INITIAL_EPISODES, POWER
from ablate.reporting.results import Ablation
from ablate.reporting.statistics import CONFIDENCE, N_RESAMPLES, SEEDS_CAP

GLOSSARY = [
    ("Return", "The sum of an episode's rewards (CartPole: steps balanced; Pong: points won minus points lost)."),
    ("Rolling mean return", "The mean return of the last W episodes (W = the solve window); learning curves plot it."),
    (
        "Solved; episodes to solve",
        "The first episode at which the rolling mean over a full window reaches the threshold; the trial stops there.",
    ),
    (
        "Censored (≥)",
        "A seed that never solved has an episodes-to-solve value only known to exceed the budget; it "
        "is counted as the budget. A median or IQM that uses such a value is a lower bound, written ≥, and the upper "
        "end of its interval is no bound on the truth.",
    ),
    (
        "At least",
        "A difference sized by a bound: censoring can only make the true gap larger, so the report gives "
        f"its lower end (and the {percent(CONFIDENCE)} lower bound of that), never an upper end.",
    ),
    (
        "IQM (interquartile mean)",
        "The mean of the middle 50% of the seeds' values (25% trimmed from each end): "
        "less sensitive to one outlying seed than the mean, more efficient than the median (Agarwal et al., 2021). "
        "With fewer than 4 seeds it trims nothing and is the plain mean: the findings then say mean.",
    ),
    (
        f"{percent(CONFIDENCE)} CI (percentile bootstrap)",
        f"Resample the seeds with replacement {N_RESAMPLES:,} times (seeded), "
        "recompute the statistic each time, and take the 2.5th and 97.5th percentiles. Two variants are resampled "
        "independently. With few seeds these intervals are optimistic.",
    ),
    (
        "AUC (area under the curve)",
        "The mean rolling return over the whole budget; a trial that stopped because it "
        "solved keeps its last value. Higher is better; it rewards learning early and separates variants that never "
        "solve.",
    ),
    (
        "Return after E episodes",
        "The rolling mean return at episode E, compared at the same budgets for every variant.",
    ),
    (
        "Improvement over the untrained policy",
        f"Final rolling mean return minus the mean return of the first "
        f"{INITIAL_EPISODES} episodes (before the policy has learnt much).",
    ),
    (
        "Probability of improvement",
        "P(X < Y) + P(X = Y)/2 for X a random seed of the variant and Y one of its "
        "reference, on episodes to solve (Agarwal et al., 2021); 0.5 means no difference. Where every pair is ordered "
        "the same way the bootstrap collapses to a point (1.00 [1.00, 1.00]), which only says the sample has no other "
        "pair; there the interval is the exact Clopper-Pearson bound for min(n, m) successes in min(n, m) trials.",
    ),
    (
        "Exploratory: better, worse, not separated, too few seeds",
        "The words of the appendix's comparisons (and of the `verdict` column of tables/comparisons.csv), each "
        f"comparison on its own {percent(CONFIDENCE)} bootstrap interval, unadjusted for the others: never a claim "
        "(the claims are "
        "*better*, *worse*, *equivalent* or *undetermined*, tables/claims.csv). *Exploratory: too few seeds*: a rank "
        f"test could not reach {percent(CONFIDENCE)} confidence even with the seeds perfectly ordered (smallest "
        "two-sided p = "
        f"2 / C(n+m, n) > {1 - CONFIDENCE:.2f}, e.g. 3 seeds against 3), or one side has one seed; the estimate is "
        "shown, no direction is read from it.",
    ),
    (
        "Seeds needed",
        "On the primary metric, the claims' figure: how many seeds per variant would decide an undetermined claim "
        f"in {percent(POWER)} of experiments resampled from the observed seeds. On the other metrics, for a comparison "
        "not "
        f"separated: how many seeds per variant the exploratory rule (the {percent(CONFIDENCE)} interval excludes no "
        "difference, "
        f"censoring permitting) would need to separate the difference in {percent(POWER)} of experiments, found by "
        "drawing that "
        f"many seeds with replacement from the observed ones, 100 times. More than {SEEDS_CAP}: no effect this "
        "large is in sight; fewer: the experiment had too few seeds.",
    ),
    (
        "Smallest effect of interest",
        "The smallest difference worth finding, as a fraction of the reference's value: 10% unless the experiment "
        "file sets `smallest_effect` (episodes: 10% fewer or more; returns and AUC: 10% of the reference's value "
        "apart). The report says how many seeds would separate a difference this large, resampled from the observed "
        "seeds shifted to it.",
    ),
    (
        "Leave-one-seed-out",
        "Each claim is recomputed with every seed in turn removed from all variants; a claim "
        "that disappears for some seed is marked fragile.",
    ),
]

REFERENCES = [
    "Williams, R. J. (1992). Simple statistical gradient-following algorithms for connectionist reinforcement "
    "learning. *Machine Learning*, 8(3-4), 229-256. (REINFORCE.)",
    "Amini, A., & Amini, A. MIT 6.S191: Introduction to Deep Learning, Lab 3: Reinforcement Learning (CartPole and "
    "Pong with REINFORCE). Massachusetts Institute of Technology. (The course's lab: its policy, its loss and its "
    "training loop are the baseline's.)",
    "Patterson, A., Neumann, S., White, M., & White, A. (2024). Empirical design in reinforcement learning. "
    "*Journal of Machine Learning Research*, 25. (Seeds, tuning each arm on its own seeds, comparing on fresh "
    "ones.)",
    "Agarwal, R., Schwarzer, M., Castro, P. S., Courville, A., & Bellemare, M. G. (2021). Deep reinforcement "
    "learning at the edge of the statistical precipice. *Advances in Neural Information Processing Systems 34*. "
    "(IQM, bootstrap intervals, probability of improvement.)",
    "Colas, C., Sigaud, O., & Oudeyer, P.-Y. (2019). A hitchhiker's guide to statistical comparisons of "
    "reinforcement learning algorithms. *ICLR 2019 Workshop on Reproducibility in Machine Learning*. (How many "
    "seeds a comparison needs; which tests hold with few seeds.)",
    "Mann, H. B., & Whitney, D. R. (1947). On a test of whether one of two random variables is stochastically "
    "larger than the other. *Annals of Mathematical Statistics*, 18(1), 50-60. (The rank test behind *exploratory: "
    "too few seeds*, and the probability of improvement.)",
    "Efron, B., & Tibshirani, R. J. (1993). *An Introduction to the Bootstrap*. Chapman & Hall. (Percentile "
    "intervals.)",
    "Good, P. (2005). *Permutation, Parametric and Bootstrap Tests of Hypotheses* (3rd ed.). Springer. (The "
    "permutation test of each primary claim.)",
    "Holm, S. (1979). A simple sequentially rejective multiple test procedure. *Scandinavian Journal of "
    f"Statistics*, 6(2), 65-70. (The primary claims as one family at {percent(ALPHA)}.)",
    "Schuirmann, D. J. (1987). A comparison of the two one-sided tests procedure and the power approach for "
    "assessing the equivalence of average bioavailability. *Journal of Pharmacokinetics and Biopharmaceutics*, "
    "15(6), 657-680. (*Equivalent*: two one-sided tests within the smallest effect of interest.)",
]

ROUNDS_REFERENCES = [
    "Lan, K. K. G., & DeMets, D. L. (1983). Discrete sequential boundaries for clinical trials. *Biometrika*, "
    "70(3), 659-663. (Alpha spending across the rounds of seeds.)",
]

TUNING_REFERENCES = [
    "Eimer, T., Lindauer, M., & Raileanu, R. (2023). Hyperparameters in reinforcement learning and how to tune "
    "them. *ICML 2023*. (Tuning and evaluation seeds kept apart.)",
]

ATARI_REFERENCES = [
    "Mnih, V., et al. (2015). Human-level control through deep reinforcement learning. *Nature*, 518, 529-533. "
    "(Atari pre-processing and frame-based policies.)",
]


def references(ablation: Ablation) -> list[str]:
    """The references this report cites: the alpha-spending paper only where seeds came in rounds, the tuning paper
    only where it tuned, the Arcade Learning Environment's only for Atari games."""
    from ablate.reporting.comparisons import claims_design

    design = claims_design(ablation)
    return (
        REFERENCES
        + (ROUNDS_REFERENCES if design.max > design.start else [])
        + (TUNING_REFERENCES if ablation.tuning else [])
        + (ATARI_REFERENCES if ablation.profile.atari else [])
    )
