"""Report work spread over processes gives what one process gives, in the same order."""

import operator

import pytest

from windbench.report.parallel import pmap, worker_count


def test_workers_keep_order_and_results():
    items = list(range(7))
    assert pmap(operator.neg, items, jobs=2, per_worker=1) == [-i for i in items]


def test_worker_count_limits():
    assert worker_count(4, pieces=3, per_worker=1) == 3
    assert worker_count(4, pieces=39, per_worker=20) == 1
    assert worker_count(1, pieces=100, per_worker=1) == 1
    with pytest.raises(ValueError, match="jobs must be >= 1"):
        worker_count(0, pieces=3, per_worker=1)


def test_a_batch_closes_twice_and_the_cli_refuses_zero_jobs(tmp_path, capsys):
    from windbench.report.cli import main
    from windbench.report.parallel import Batch

    batch = Batch(operator.neg, [1, 2, 3, 4], jobs=2, per_worker=1)
    assert batch.results() == [-1, -2, -3, -4]
    batch.close()  # after results(): nothing left to stop
    with pytest.raises(SystemExit) as exit_:
        main([str(tmp_path), "--jobs", "0"])
    assert exit_.value.code == 2 and "--jobs: must be >= 1" in capsys.readouterr().err
