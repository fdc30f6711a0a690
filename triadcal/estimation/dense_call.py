"""Numeric evaluation of a compiled CasADi function into numpy arrays without DM conversion.

Calling a ``casadi.Function`` on numpy arrays returns ``casadi.DM`` objects, and
``numpy.asarray(DM)`` builds a Python list of every element (``DM.elements()``) before it becomes
an array: for a Jacobian of 3 outputs x 400 visits x 40 parameters that is 48 000 Python floats a
call, and it took 60 % of the time of a Levenberg-Marquardt iteration of the joint fit (profile of
a diagnosis, 2026-11-30: 11.8 s of 20 s). CasADi's ``Function.buffer()`` (its FunctionBuffer
interface) evaluates the function directly from and into caller-owned memory; this module keeps
those buffers as numpy arrays, so an evaluation costs the function's own arithmetic and one copy
of each argument.
"""

from __future__ import annotations

import threading

import casadi as ca
import numpy as np


class DenseCall:
    """``DenseCall(f)(*args)``: the outputs of ``f`` as dense numpy arrays of the outputs' shapes.

    Each argument must have the size of the function's (dense) input; a 2-D argument must have
    its exact shape (it is read column-major, as CasADi stores it); a sparse output is scattered
    into a dense array of zeros. The result arrays are new on every call. The buffers are made on
    the first call and dropped on pickling; a lock serialises calls from several threads.
    """

    def __init__(self, f: ca.Function):
        self.f = f
        # the shapes, read once: each casadi query is a call through SWIG (on a small function, such
        # as a known-pose fit's, they took as long as the evaluation)
        self._n_in = f.n_in()
        self._in_shapes = [(f.size1_in(i), f.size2_in(i)) for i in range(self._n_in)]
        self._out_shapes = [(f.size1_out(i), f.size2_out(i)) for i in range(f.n_out())]
        for i in range(self._n_in):
            if not f.sparsity_in(i).is_dense():
                raise ValueError(f"{f.name()}: input {i} is sparse; DenseCall takes dense inputs only")
        self._state = None
        self._lock = threading.Lock()

    def _setup(self):
        f = self.f
        buf, evaluate = f.buffer()
        ins = [np.zeros(f.nnz_in(i)) for i in range(f.n_in())]
        outs = [np.zeros(f.nnz_out(i)) for i in range(f.n_out())]
        for i, a in enumerate(ins):
            buf.set_arg(i, memoryview(a))
        for i, a in enumerate(outs):
            buf.set_res(i, memoryview(a))
        scatter = []
        for i in range(f.n_out()):
            sp = f.sparsity_out(i)
            if sp.is_dense():
                scatter.append(None)
            else:
                cols = np.repeat(np.arange(sp.size2()), np.diff(np.asarray(sp.colind())))
                scatter.append((np.asarray(sp.row(), dtype=np.intp), cols))
        self._state = (buf, evaluate, ins, outs, scatter)

    def __call__(self, *args):
        if len(args) != self._n_in:
            raise TypeError(f"{self.f.name()}: {self._n_in} arguments expected, got {len(args)}")
        with self._lock:
            if self._state is None:
                self._setup()
            _, evaluate, ins, outs, scatter = self._state
            for i, a in enumerate(args):
                a = np.asarray(a, dtype=float)
                shape = self._in_shapes[i]
                if a.ndim == 2 and a.shape != shape:
                    raise ValueError(f"{self.f.name()}: input {i} has shape {a.shape}, {shape} expected")
                if a.size != ins[i].size:
                    raise ValueError(f"{self.f.name()}: input {i} has {a.size} elements, {ins[i].size} expected")
                ins[i][:] = a.ravel(order="F")
            evaluate()
            res = []
            for i, out in enumerate(outs):
                shape = self._out_shapes[i]
                if scatter[i] is None:
                    res.append(out.reshape(shape, order="F").copy())
                else:
                    dense = np.zeros(shape)
                    dense[scatter[i]] = out
                    res.append(dense)
        return tuple(res)

    def __getstate__(self):
        return {"f": self.f}

    def __setstate__(self, state):
        self.__init__(state["f"])
