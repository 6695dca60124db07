"""The figures every `make bench` section adds to, by section (`bench.py --json` writes them)."""

RESULTS: dict[str, object] = {}
