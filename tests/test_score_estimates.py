"""tools/score_estimates.py: the printed time-left figures scored against the trials' true end, each distinct
figure once, from a quarter of the trials on; a log without an end is said to be one."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "tools"))
from score_estimates import main, score  # noqa: E402

LOG = """\
x: 0 done (of 9) | 0:05 elapsed, time left: estimating until a quarter of the trials have ended (0 of 9)
x: 3 done (of 9) | 0:20 elapsed, ~1:00 left in round 1, at most ~2:00 in all
x: 3 done (of 9) | 0:20 elapsed, ~1:00 left in round 1, at most ~2:00 in all
x: 5 done (of 9) | 0:40 elapsed, ~0:10 left in round 1, at most ~0:20 in all
x: 9 done (of 9) | 1:40 elapsed, all trials ended
"""


def test_each_distinct_figure_is_scored_once_against_the_true_end(tmp_path, capsys):
    held, outside, end = score(LOG)
    # At 0:20, 80 s remained: within [0.7 x 60, 1.3 x 120]. At 0:40, 60 s remained: above 20 + 20 s.
    assert (held, outside, end) == (1, [(40, 10, 20, 60)], 100)
    (tmp_path / "a.log").write_text(LOG)
    assert main([str(tmp_path / "a.log")]) == 0
    assert "1 of 2 distinct printed estimates within the bound" in capsys.readouterr().out


def test_a_launch_that_did_not_finish_has_nothing_to_score(tmp_path, capsys):
    (tmp_path / "b.log").write_text(LOG.rsplit("\n", 2)[0])
    assert main([str(tmp_path / "b.log")]) == 1
    assert "did not finish" in capsys.readouterr().err


def test_help_and_a_missing_log_are_one_line_not_a_traceback(tmp_path, capsys):
    assert main(["--help"]) == 0 and "usage: score_estimates.py LOG" in capsys.readouterr().err
    assert main([str(tmp_path / "none.log")]) == 2
    assert capsys.readouterr().err == f"score_estimates: {tmp_path / 'none.log'}: no such file\n"
