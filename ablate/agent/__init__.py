"""One trial, no Ray and no MLflow: the REINFORCE core, policies, environments, the optimiser, the trial loop."""
