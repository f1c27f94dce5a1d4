import torch

from hrl_torch.common.rng import BatchRNG


def test_a_learner_sees_the_same_stream_alone_or_in_a_population():
    pop = BatchRNG([5, 9, 13], 4, "s")
    alone = BatchRNG([9], 4, "s")
    for _ in range(3):
        assert torch.equal(pop.uniform(3)[4:8], alone.uniform(3))


def test_streams_and_counters_differ_and_reserve_reads_fixed_draws():
    a, b = BatchRNG([1], 1000, "x"), BatchRNG([1], 1000, "y")
    ua, ub = a.uniform(), b.uniform()
    assert not torch.equal(ua, ub)
    assert 0.0 <= float(ua.min()) and float(ua.max()) < 1.0
    first = a.reserve(3)
    assert torch.equal(a.uniform(counter=first + 1), a.uniform(counter=first + 1))
    assert a.counter == first + 3


def test_uniforms_look_uniform_and_integers_stay_in_range():
    u = BatchRNG([0], 100_000, "u").uniform()
    assert abs(float(u.mean()) - 0.5) < 0.005
    hist = torch.histc(u, bins=10, min=0, max=1)
    assert float(hist.min()) > 9_500
    ints = BatchRNG([0], 10_000, "i").integers(torch.full((10_000,), 7))
    assert int(ints.min()) == 0 and int(ints.max()) == 6


def test_counter_round_trips_through_state_dict():
    r = BatchRNG([3], 5, "c")
    r.uniform()
    state = r.state_dict()
    x = r.uniform()
    r.load_state_dict(state)
    assert torch.equal(r.uniform(), x)


def test_draws_computed_ahead_in_blocks_equal_draws_one_at_a_time():
    # uniform() computes the next draws of a width in blocks; interleaved widths, explicit
    # counters and a restored counter must read exactly what single draws give
    one, ahead = BatchRNG([4, 8], 3, "b"), BatchRNG([4, 8], 3, "b")
    one.AHEAD = 1
    ahead.AHEAD = 5
    for step in range(23):
        for extra in (0, 7) if step % 3 else (7, 0, 2):
            assert torch.equal(one.uniform(extra), ahead.uniform(extra))
        assert torch.equal(one.integers(5, 2), ahead.integers(5, 2))
    first = one.reserve(4)
    assert ahead.reserve(4) == first
    for c in (first + 2, first, first + 3):
        assert torch.equal(one.uniform(3, counter=c), ahead.uniform(3, counter=c))
    state = ahead.state_dict()
    later = [ahead.uniform(7) for _ in range(4)]
    ahead.load_state_dict(state)
    assert all(torch.equal(x, ahead.uniform(7)) for x in later)
    rows = torch.tensor([5, 0])
    one.load_state_dict(ahead.state_dict())
    assert torch.equal(one.uniform(2)[rows], ahead.subset(rows).uniform(2))


def test_a_draws_columns_are_the_columns_of_the_whole_draw():
    # uniform(columns=...) computes only the columns asked for; a column's numbers do not
    # depend on how many others are drawn
    whole, part = BatchRNG([2, 3], 4, "c"), BatchRNG([2, 3], 4, "c")
    cols = torch.tensor([[5, 1, 1], [0, 5, 6]])
    for _ in range(9):
        expect = whole.uniform(7)
        got = part.uniform(7, columns=cols)
        assert got.shape == (8, 2, 3)
        assert torch.equal(got, expect[:, cols])


def test_a_draw_for_some_rows_is_those_rows_of_the_whole_draw():
    rng = BatchRNG([2, 3], 5, "r")
    first = rng.reserve(3)
    rows = torch.tensor([9, 0, 4])
    cols = torch.tensor([[6, 2], [0, 1]])
    for c in (first, first + 2):
        whole = rng.uniform(8, counter=c, columns=cols)
        assert torch.equal(rng.uniform_rows(8, c, rows, cols), whole[rows])
