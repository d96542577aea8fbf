"""Link model formulas: loss within a binomial bound, latency distributions, uplink serialisation.

Expected values are derived here (binomial / exponential / uniform / clipped-normal laws, the
transmission time 8 bytes / bandwidth); the draws are seeded, so every case is deterministic.
A batch planned once and timed in Python floats (small, merged link classes) equals the array
code: arrivals, uplinks and the generator's state.
"""
import math

import numpy as np
import pytest
from scipy import stats

from immersim.models.network.config import LinkClass
from immersim.models.network.links import TransmitPlan, latency_sum, sample_latency, transmit
from immersim.models.network.paths import Paths

from .helpers import LOSSY

T = 0.033
LINKS = {"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(20.0, 5.0, 0.0, 100.0)}


def _links(lan: LinkClass, wan: LinkClass = LinkClass()):
    return {"lan": lan, "wan": wan}


@pytest.mark.parametrize("loss_lan, loss_wan", [(0.05, 0.10), (0.3, 0.0)])
def test_packet_loss_rate_is_within_the_binomial_bound(loss_lan, loss_wan):
    """Lost messages per class ~ Binomial(n, p): the count lies within 5 sigma of n p."""
    n = 6000
    rng = np.random.default_rng(11)
    links = _links(LinkClass(latency_ms=2, jitter_ms=1, loss=loss_lan), LinkClass(latency_ms=20, jitter_ms=5, loss=loss_wan))
    cls = np.arange(n) % 2
    _, lost = transmit(rng, links, np.zeros(n), np.arange(n) % 7, cls, np.full(n, 100), np.zeros(7))
    for k, p in ((0, loss_lan), (1, loss_wan)):
        m = int(np.count_nonzero(cls == k))
        got = int(lost[cls == k].sum())
        assert abs(got - m * p) <= 5 * math.sqrt(m * p * (1 - p)) + 1e-9, (k, got, m * p)


def test_lossless_link_loses_nothing_and_certain_loss_is_impossible():
    rng = np.random.default_rng(0)
    _, lost = transmit(rng, _links(LinkClass(latency_ms=1, jitter_ms=0.5, distribution="uniform")),
                       np.zeros(500), np.zeros(500, int), np.zeros(500, int), np.full(500, 10), np.zeros(1))
    assert not lost.any()
    with pytest.raises(ValueError, match=r"link class: loss = 1.0 must be in \[0, 1\)"):
        LinkClass(loss=1.0)


@pytest.mark.parametrize("dist, law", [
    ("exponential", lambda base, j: stats.expon(loc=base, scale=j)),
    ("uniform", lambda base, j: stats.uniform(loc=base, scale=2 * j)),
])
def test_latency_follows_its_declared_distribution(dist, law):
    """base + exponential(mean jitter) or base + uniform[0, 2 jitter]: Kolmogorov-Smirnov p > 1e-3,
    and the sample mean within 5 standard errors of base + jitter."""
    base, j = 0.012, 0.004
    x = sample_latency(np.random.default_rng(5), LinkClass(latency_ms=base * 1e3, jitter_ms=j * 1e3, distribution=dist), 20000)
    assert stats.kstest(x, law(base, j).cdf).pvalue > 1e-3
    sd = j if dist == "exponential" else 2 * j / math.sqrt(12)
    assert abs(x.mean() - (base + j)) < 5 * sd / math.sqrt(len(x))
    assert x.min() >= base


def test_normal_jitter_is_clipped_at_zero_latency():
    """base + N(0, jitter), clipped at 0: P(latency = 0) = Phi(-base / jitter), the rest normal."""
    base, j = 0.002, 0.004
    x = sample_latency(np.random.default_rng(2), LinkClass(latency_ms=base * 1e3, jitter_ms=j * 1e3, distribution="normal"), 20000)
    p0 = stats.norm.cdf(-base / j)
    zero = np.count_nonzero(x == 0.0)
    assert abs(zero - len(x) * p0) < 5 * math.sqrt(len(x) * p0 * (1 - p0))
    pos = x[x > 0]
    assert stats.kstest(pos, stats.truncnorm(-base / j, np.inf, loc=base, scale=j).cdf).pvalue > 1e-3


def test_no_jitter_gives_the_base_latency_exactly():
    np.testing.assert_array_equal(sample_latency(np.random.default_rng(0), LinkClass(latency_ms=7.5), 4), np.full(4, 0.0075))


@pytest.mark.parametrize("n", [3, 20])
def test_latency_sum_is_the_sum_of_the_same_draws(n):
    link = LinkClass(latency_ms=3, jitter_ms=2)
    a = latency_sum(np.random.default_rng(9), link, n)
    b = 0.003 * n + np.random.default_rng(9).exponential(0.002, n).sum()
    assert a == pytest.approx(b, rel=1e-13)


@pytest.mark.parametrize("jitter_ms", [0.0, 1.5])
def test_uplink_serialises_messages_at_eight_bytes_over_bandwidth(jitter_ms):
    """One sender, three 1000-byte messages at 1 Mbit/s: each takes 8 ms on the uplink, so they leave
    at 8, 16, 24 ms after max(send, uplink busy) and arrive ``scale * latency`` later; the uplink
    stays busy until the last one left. A second sender is independent of the first."""
    base = 0.005
    link = LinkClass(latency_ms=base * 1e3, jitter_ms=jitter_ms, bandwidth_mbps=1.0)
    rng = np.random.default_rng(4)
    busy = np.array([0.100, 0.0])
    send = np.full(4, 0.090)
    arrival, lost = transmit(rng, _links(link), send, np.array([0, 0, 0, 1]), np.zeros(4, int),
                             np.array([1000, 1000, 1000, 500]), busy, scale=2.0)
    jit = np.random.default_rng(4).exponential(jitter_ms * 1e-3, 4) if jitter_ms else np.zeros(4)
    leave = np.array([0.108, 0.116, 0.124, 0.094])
    np.testing.assert_allclose(arrival, leave + 2.0 * (base + jit), rtol=1e-12)
    np.testing.assert_allclose(busy, [0.124, 0.094], rtol=1e-12)
    assert not lost.any()


def test_unlimited_bandwidth_arrives_after_the_latency_alone():
    link = LinkClass(latency_ms=4.0)
    busy = np.zeros(2)
    arrival, _ = transmit(np.random.default_rng(1), _links(link), np.array([1.0, 2.0]), np.array([0, 1]),
                          np.zeros(2, int), np.array([10 ** 6, 10 ** 6]), busy, scale=1.5)
    np.testing.assert_allclose(arrival, [1.006, 2.006], rtol=1e-14)
    np.testing.assert_array_equal(busy, 0.0)


@pytest.mark.parametrize("bandwidth", [100.0, 0.0, 0.05])
def test_float_batches_equal_the_array_code(bandwidth):
    links = {"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(20.0, 5.0, 0.0, bandwidth)}
    gen = np.random.default_rng(7)
    for trial in range(60):
        n = int(gen.integers(1, Paths().float_batch + 1))
        sender = gen.integers(0, 5, n)
        link = gen.integers(0, 2, n) if trial % 5 else np.ones(n, np.int64)   # some one-class batches
        nbytes = gen.integers(20, 3000, n)
        plan = TransmitPlan(links, sender, link, nbytes)
        if plan.floats is None:          # one class: not merged, the array code only
            assert not (link == 0).any() or not (link == 1).any()
            continue
        rng_a, rng_b = np.random.default_rng(trial), np.random.default_rng(trial)
        busy_a = gen.uniform(0.0, 0.01, 5) * (gen.random(5) < 0.5)
        busy_b = busy_a.copy()
        for k in range(4):
            send = k * T + np.where(gen.random(n) < 0.4, 0.002, 0.0)
            scale = float(gen.choice([1.0, 0.0, 2.5]))
            arrival, lost = plan.run(rng_a, send, busy_a, scale)
            floats = plan.run_floats(rng_b, send.tolist(), busy_b, scale)
            assert floats == arrival.tolist() and not lost.any()
            assert np.array_equal(busy_a, busy_b)
        assert rng_a.bit_generator.state == rng_b.bit_generator.state


def test_single_class_float_batches_equal_the_array_code():
    gen = np.random.default_rng(3)
    for trial in range(40):
        n = int(gen.integers(1, Paths().float_batch + 1))
        sender, nbytes = gen.integers(0, 4, n), gen.integers(20, 3000, n)
        plan = TransmitPlan(LINKS, sender, np.full(n, trial % 2), nbytes)
        assert plan.floats is not None
        rng_a, rng_b = np.random.default_rng(trial), np.random.default_rng(trial)
        busy_a = gen.uniform(0.0, 0.01, 4)
        busy_b = busy_a.copy()
        for k in range(3):
            send = k * T + np.where(gen.random(n) < 0.4, 0.002, 0.0)
            arrival, lost = plan.run(rng_a, send, busy_a, 1.5)
            assert plan.run_floats(rng_b, send.tolist(), busy_b, 1.5) == arrival.tolist()
            assert np.array_equal(busy_a, busy_b) and not lost.any()
        assert rng_a.bit_generator.state == rng_b.bit_generator.state


@pytest.mark.parametrize("dist", ["exponential", "uniform", "normal"])
def test_latency_sum_equals_the_array_code(dist):
    for n in (1, 2, 3, 7, 8, 20):
        for link in (LinkClass(20.0, 5.0, 0.0, 100.0, dist), LinkClass(0.0, 3.0, 0.0, 0.0, dist),
                     LinkClass(20.0, 0.0, 0.0, 100.0, dist), LinkClass(5.0, 2.0, 0.1, 10.0, dist)):
            a, b = np.random.default_rng(n), np.random.default_rng(n)
            for _ in range(20):
                assert latency_sum(a, link, n) == float(sample_latency(b, link, n).sum())
            assert a.bit_generator.state == b.bit_generator.state


def test_transmit_plan_reused_over_batches_equals_fresh_batches():
    links = LOSSY
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    sender = np.array([0, 2, 0, 1, 2, 2, 0])
    link = np.array([1, 0, 1, 1, 0, 1, 0])
    nbytes = np.array([100, 1500, 40, 9000, 64, 700, 3000])
    busy_a, busy_b = np.zeros(3), np.zeros(3)
    plan = TransmitPlan(links, sender, link, nbytes)
    for k in range(5):
        send = np.full(7, k * T) + np.where(np.arange(7) % 2, 0.002, 0.0)
        a = plan.run(rng_a, send, busy_a, 1.5)
        b = transmit(rng_b, links, send, sender, link, nbytes, busy_b, 1.5)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and np.array_equal(busy_a, busy_b)
