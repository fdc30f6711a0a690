"""DenseCall (CasADi's FunctionBuffer into numpy) gives what a CasADi call converted to numpy gives:
dense and sparse outputs, mapped functions with shared inputs, 2-D arguments read column-major; it
refuses an argument of the wrong shape and survives pickling (a problem sent to a worker)."""

import pickle
import threading

import casadi as ca
import numpy as np
import pytest

from triadcal.estimation.dense_call import DenseCall


def _mapped(n=50):
    x = ca.SX.sym("x", 4)
    c = ca.SX.sym("c", 3)
    g = ca.SX.sym("g")
    w = ca.vertcat(x[0] * ca.sin(c[0]) + x[1] * c[1] * g, x[2] * x[3] * c[2], x[3])
    f = ca.Function("f", [x, c, g], [w, ca.jacobian(w, x)])        # the Jacobian is sparse
    return f, f.map("m", "serial", n, [0, 2], [])


def test_equals_the_dm_conversion_dense_and_sparse():
    f, m = _mapped()
    assert not m.sparsity_out(1).is_dense()
    rng = np.random.default_rng(0)
    x, C = rng.normal(size=4), rng.normal(size=(3, 50))
    w, J = DenseCall(m)(x, C, 9.8)
    w0, J0 = (np.asarray(v) for v in m(x, C, 9.8))
    assert w.shape == w0.shape == (3, 50) and J.shape == J0.shape == (3, 200)
    assert np.array_equal(w, w0) and np.array_equal(J, J0)
    # a hand-derived entry: dw_1/dx_1 of visit 7 is c_1 g
    assert J[0, 7 * 4 + 1] == pytest.approx(C[1, 7] * 9.8)
    # results are new arrays: the next call does not change them
    w_again, _ = DenseCall(m)(x + 1.0, C, 9.8)
    assert np.array_equal(w, w0) and not np.array_equal(w_again, w)


def test_refuses_a_wrong_shape_and_a_wrong_count():
    _, m = _mapped()
    d = DenseCall(m)
    with pytest.raises(ValueError, match="shape"):
        d(np.zeros(4), np.zeros((50, 3)), 1.0)                  # transposed
    with pytest.raises(ValueError, match="elements"):
        d(np.zeros(5), np.zeros((3, 50)), 1.0)
    with pytest.raises(TypeError, match="arguments"):
        d(np.zeros(4), np.zeros((3, 50)))


def test_pickles_and_serves_threads():
    _, m = _mapped()
    d = DenseCall(m)
    rng = np.random.default_rng(1)
    x, C = rng.normal(size=4), rng.normal(size=(3, 50))
    ref = d(x, C, 1.0)
    d2 = pickle.loads(pickle.dumps(d))
    assert all(np.array_equal(a, b) for a, b in zip(ref, d2(x, C, 1.0)))
    out, errors = [], []

    def work(k):
        try:
            for _ in range(50):
                got = d(x * k, C, 1.0)
                out.append((k, got[0]))
        except Exception as exc:                 # pragma: no cover - reported below
            errors.append(exc)
    ts = [threading.Thread(target=work, args=(k,)) for k in (1.0, 2.0, 3.0)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors
    expect = {k: np.asarray(m(x * k, C, 1.0)[0]) for k in (1.0, 2.0, 3.0)}
    assert all(np.array_equal(w, expect[k]) for k, w in out)
