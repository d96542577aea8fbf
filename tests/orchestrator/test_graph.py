"""Gauss-Seidel order: topological, scenario order on ties, cycles broken at a documented place."""
from immersim.orchestrator.graph import gauss_seidel_order
from immersim.orchestrator.scenario import Connection


def c(a, b):
    return Connection(a, "y", b, "u")


def test_chain_is_topological_regardless_of_file_order():
    order, delayed = gauss_seidel_order(["plat", "coll", "net"], [c("net", "coll"), c("coll", "plat")])
    assert order == ["net", "coll", "plat"] and delayed == []


def test_independent_units_keep_file_order():
    order, delayed = gauss_seidel_order(["b", "a", "c"], [])
    assert order == ["b", "a", "c"] and delayed == []


def test_cycle_is_broken_at_the_backward_connection():
    # the reference scene: network -> collision -> network, and network -> platform
    conns = [c("net", "coll"), c("coll", "net"), c("net", "plat"), c("coll", "plat")]
    order, delayed = gauss_seidel_order(["net", "coll", "plat"], conns)
    assert order == ["net", "coll", "plat"]
    assert delayed == [c("coll", "net")]


def test_cycle_breaking_follows_file_order_inside_the_cycle():
    conns = [c("a", "b"), c("b", "a")]
    assert gauss_seidel_order(["b", "a"], conns) == (["b", "a"], [c("a", "b")])


def test_self_loop_is_delayed():
    order, delayed = gauss_seidel_order(["a"], [c("a", "a")])
    assert order == ["a"] and delayed == [c("a", "a")]


def test_declared_delayed_connections_do_not_order_their_units():
    """``delayed = true``: left out of the graph and always delayed. net <-> coll both declared
    delayed, net -> plat fresh: net and coll are independent in a step, plat follows net."""
    d = lambda a, b: Connection(a, "y", b, "u", delayed=True)   # noqa: E731
    conns = [d("net", "coll"), d("coll", "net"), c("net", "plat")]
    order, delayed = gauss_seidel_order(["plat", "coll", "net"], conns)
    assert order == ["coll", "net", "plat"] and delayed == [d("net", "coll"), d("coll", "net")]
    # one direction declared: the other orders the units (here against the file order)
    order, delayed = gauss_seidel_order(["a", "b"], [d("a", "b"), c("b", "a")])
    assert order == ["b", "a"] and delayed == [d("a", "b")]
