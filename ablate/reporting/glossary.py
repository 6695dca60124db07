"""The report's glossary and references: the terms its sentences use, and the papers its method and statistics
rest on (the algorithm, the course's lab, the protocol, the statistics of the claims)."""

from __future__ import annotations

from ablate.design import ALPHA, percent
from ablate.experiment import Experiment
from ablate.measures import INITIAL_EPISODES
from ablate.reporting.prose import say
from ablate.reporting.results import Ablation
from ablate.reporting.statistics import CONFIDENCE, N_RESAMPLES, SEEDS_CAP, SIMULATIONS

_FACTS = dict(level=CONFIDENCE, resamples=N_RESAMPLES, initial=INITIAL_EPISODES, simulations=SIMULATIONS, cap=SEEDS_CAP)
GLOSSARY = [entry.strip() for entry in say("glossary.entries", effect=Experiment.smallest_effect, **_FACTS).split("\n")]
"""The terms the report's sentences use, each ``**Term.** definition``, in order (``templates/glossary.j2``)."""

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
