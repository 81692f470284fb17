"""The track sampler keeps one fix per period of the vehicle's clock, on a fixed grid."""

import pytest

from guadal_cli.fleet.track import TrackSampler


def test_one_fix_per_period_on_a_fixed_grid():
    sampler = TrackSampler(1.0)
    stamps = [0.0, 0.2, 0.5, 0.99, 1.0, 1.3, 2.7, 2.9, 3.05, 6.4, 6.5, 7.0]
    kept = [t for t in stamps if sampler.take(t)]
    # a late fix (2.7) does not shift the grid: 3.05 is the next second's
    assert kept == [0.0, 1.0, 2.7, 3.05, 6.4, 7.0]


def test_rate_and_reset():
    sampler = TrackSampler(4.0)
    assert [t for t in (10.0, 10.1, 10.25, 10.3, 10.5) if sampler.take(t)] == [10.0, 10.25, 10.5]
    sampler.reset()
    assert sampler.take(0.0)
    with pytest.raises(ValueError):
        TrackSampler(0)
