"""Results computed once within a scope (core.memo): a repeat is what computing again gives, the
Generator included; anything that differs in content, identity or Generator state computes again."""

import dataclasses
import threading

import numpy as np
import pytest

from histostudy.core import GeneratorMemo, MemoScope, value_digest


@dataclasses.dataclass
class _Scene:
    image: np.ndarray
    meta: dict
    name: str = "A"


def _scene(**change):
    return dataclasses.replace(_Scene(np.arange(6.0).reshape(2, 3), {"b": 1, "a": [1, 2]}), **change)


def test_equal_content_has_one_digest_and_any_difference_another():
    assert value_digest(_scene()) == value_digest(_scene(meta={"a": [1, 2], "b": 1}))  # dict order is not content
    assert value_digest([np.zeros(3), None]) == value_digest([np.zeros(3), None])
    others = [
        _scene(image=np.arange(6.0).reshape(3, 2)),  # the same bytes, another shape
        _scene(image=np.arange(6.0, dtype=np.float32).reshape(2, 3)),  # another dtype
        _scene(image=np.arange(6.0).reshape(2, 3) + 1e-12),
        _scene(meta={"b": 1.0, "a": [1, 2]}),  # 1.0 is not 1
        _scene(meta={"b": 1, "a": (1, 2)}),  # a tuple is not a list
        _scene(name="B"),
    ]
    digests = {value_digest(v) for v in [_scene(), *others]}
    assert len(digests) == len(others) + 1
    assert value_digest(("A", 1)) != value_digest(("A1",)) != value_digest(["A", 1])


def test_a_value_pickle_refuses_has_no_digest():
    assert value_digest({"lock": threading.Lock()}) is None
    assert value_digest(lambda x: x) is None
    assert value_digest(np.array([1, None], dtype=object)) == value_digest(np.array([1, None], dtype=object))


def _drawing(calls):
    def compute(rng, n):
        calls.append(n)
        return {"draws": rng.normal(size=n)}
    return compute


def test_a_repeat_is_the_result_and_leaves_the_generator_where_computing_does():
    calls = []
    compute = _drawing(calls)
    plain_rng = np.random.default_rng(3)
    plain = compute(plain_rng, 4)
    memo = GeneratorMemo(8)
    rngs = [np.random.default_rng(3) for _ in range(2)]
    first = memo.call(value_digest(4), lambda: compute(rngs[0], 4), rng=rngs[0])
    first["draws"][:] = 0.0  # a caller's change does not reach the memo
    second = memo.call(value_digest(4), lambda: compute(rngs[1], 4), rng=rngs[1])
    np.testing.assert_array_equal(second["draws"], plain["draws"])
    assert rngs[0].random() == rngs[1].random() == plain_rng.random()
    assert (memo.hits, memo.misses, len(memo), len(calls)) == (1, 1, 1, 2)  # one plain call, one computed
    memo.call(value_digest(4), lambda: compute(np.random.default_rng(4), 4), rng=np.random.default_rng(4))
    assert (memo.hits, memo.misses) == (1, 2)  # another Generator state


def test_holders_compare_by_identity_and_the_oldest_entry_goes_first():
    memo = GeneratorMemo(2)
    model, twin = [1.0], [1.0]
    assert memo.call("k", lambda: "model", holders=(model,)) == "model"
    assert memo.call("k", lambda: "twin", holders=(twin,)) == "twin"  # equal, but another object
    assert memo.call("k", lambda: "again", holders=(model,)) == "model"
    memo.call("other", lambda: "other")  # evicts the least recently used: twin's
    assert memo.call("k", lambda: "again", holders=(twin,)) == "again"
    assert (memo.hits, memo.misses, len(memo)) == (1, 4, 2)


def test_an_error_is_raised_again_only_where_it_is_remembered():
    calls = []

    def refuse():
        calls.append(1)
        raise RuntimeError("no feature in view 'A'")

    for remember, computed in ((True, 1), (False, 2)):
        calls.clear()
        memo = GeneratorMemo(4)
        for _ in range(2):
            with pytest.raises(RuntimeError, match="no feature in view 'A'"):
                memo.call("k", refuse, rng=np.random.default_rng(0), remember_errors=remember)
        assert len(calls) == computed


def test_threads_share_one_memo_and_count_every_call():
    memo = GeneratorMemo(4)
    results = []

    def work():
        for key in range(3):
            results.append(memo.call(key, lambda key=key: key * 10, copy_result=lambda v: v))

    threads = [threading.Thread(target=work) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results) == sorted([0, 10, 20] * 6)
    assert memo.hits + memo.misses == 18 and 3 <= memo.misses <= 18


def test_scopes_nest_and_belong_to_their_thread():
    scope = MemoScope("test_scope")
    assert scope.active() is None
    with scope.open(GeneratorMemo()) as outer:
        with scope.open(GeneratorMemo()) as inner:
            assert scope.active() is inner
            seen = []
            thread = threading.Thread(target=lambda: seen.append(scope.active()))
            thread.start()
            thread.join()
            assert seen == [None]
        assert scope.active() is outer
    assert scope.active() is None


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "8"])
def test_a_memo_of_nothing_is_refused(bad):
    with pytest.raises(ValueError, match=r"max_entries must be an integer >= 1, got"):
        GeneratorMemo(bad)
