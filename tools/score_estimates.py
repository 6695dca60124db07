"""Score the time-left figures a launch printed against when its trials really ended (issue 37's bound).

    .venv/bin/python tools/score_estimates.py ablation.log     # the output of `make ablation-cartpole > ablation.log`

A printed estimate holds when the time that really remained lies between the round's estimate -30% and the upper
figure +30%, or within 20 s of either. Only the figures printed once a quarter of the trials had ended count (the
line says "estimating" before that); each distinct figure counts once, however often the line was redrawn.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

CLOCK = r"\d+:\d\d(?::\d\d)?"
LINE = re.compile(
    rf"\| ({CLOCK}) elapsed, (?:~({CLOCK}) left(?: in round (\d+), at most ~({CLOCK}) in all)?|all trials ended)"
)


def seconds(clock: str) -> int:
    total = 0
    for part in clock.split(":"):
        total = total * 60 + int(part)
    return total


def score(text: str) -> tuple[int, list[tuple[int, int, int, int]], int | None]:
    """(estimates within the bound, the ones outside as (at, left, most, remained), the end in seconds)."""
    found = list(LINE.finditer(text.replace("\r", "\n")))
    ends = [seconds(m[1]) for m in found if m[2] is None]
    if not ends:
        return 0, [], None
    end, held, outside, seen = ends[-1], 0, [], set()
    for m in found:
        if m[2] is None:
            continue
        at, left = seconds(m[1]), seconds(m[2])
        most = seconds(m[4]) if m[4] else left
        if (at, left, most) in seen:
            continue
        seen.add((at, left, most))
        remained = end - at
        if min(0.7 * left, left - 20) <= remained <= max(1.3 * most, most + 20):
            held += 1
        else:
            outside.append((at, left, most, remained))
    return held, outside, end


def main(argv: list[str]) -> int:
    if len(argv) != 1 or argv[0] in ("-h", "--help"):
        sys.stderr.write("usage: score_estimates.py LOG\n" + (__doc__ or ""))
        return 0 if argv in (["-h"], ["--help"]) else 2
    if not Path(argv[0]).is_file():
        sys.stderr.write(f"score_estimates: {argv[0]}: no such file\n")
        return 2
    held, outside, end = score(Path(argv[0]).read_text())
    if end is None:
        sys.stderr.write("score_estimates: no 'all trials ended' line in the log: the launch did not finish\n")
        return 1
    print(f"trials ended at {end} s; {held} of {held + len(outside)} distinct printed estimates within the bound")
    for at, left, most, remained in outside:
        print(f"  outside at {at} s: ~{left} s left in its round, at most ~{most} s; {remained} s remained")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
