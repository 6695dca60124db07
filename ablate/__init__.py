"""ablate: architecture ablations of policy-gradient agents."""

import os

# Before torch is imported (it reads this once, at its first allocation): PyTorch's CPU allocator then puts
# every tensor of 2 MB or more on transparent huge pages. A Pong CNN update allocates ~400 MB of activations
# and gradients per 1,024 frames; on 4 KB pages, faulting them in (each update anew, as the trial returns
# large blocks to the system to keep its memory flat) doubled the cost of forward + backward.
os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")

from ablate.api import Results, load, report, run  # noqa: E402  (after the variable above; none imports torch)

__all__ = ["Results", "load", "report", "run"]
