"""ablate: architecture ablations of policy-gradient agents."""
