"""A numpy function as a CasADi Function: for nlpsol's oracles (jac_g, hess_lag) and constraints whose values and
derivatives come from this package's own numpy code (chained sensitivities, differenced curvature) rather than
from CasADi's expression graph.

A subclass sets what its `evaluate` needs, then calls NumpyFunction.__init__ with the name and the inputs' and
outputs' (name, sparsity) pairs; `evaluate` gets every input as a flat float array and returns one array (or DM)
per output, which is projected onto the output's declared sparsity (entries outside it are dropped, structural
zeros kept). CasADi keeps no Python reference to a callback: whoever passes one to nlpsol keeps it alive."""
from __future__ import annotations

import casadi as ca
import numpy as np


class NumpyFunction(ca.Callback):

    def __init__(self, name: str, inputs: list[tuple[str, ca.Sparsity]], outputs: list[tuple[str, ca.Sparsity]]):
        ca.Callback.__init__(self)
        self._inputs, self._outputs = list(inputs), list(outputs)
        self.construct(name, {})

    def evaluate(self, *args: np.ndarray) -> list:
        raise NotImplementedError

    def get_n_in(self):
        return len(self._inputs)

    def get_n_out(self):
        return len(self._outputs)

    def get_name_in(self, i):
        return self._inputs[i][0]

    def get_name_out(self, i):
        return self._outputs[i][0]

    def get_sparsity_in(self, i):
        return self._inputs[i][1]

    def get_sparsity_out(self, i):
        return self._outputs[i][1]

    def eval(self, args):
        values = self.evaluate(*(np.array(a, dtype=float).ravel() for a in args))
        return [ca.project(ca.sparsify(ca.DM(v)), sparsity) for v, (_, sparsity) in zip(values, self._outputs)]


def hess_lag_io(nw: int, ng: int, pattern: ca.Sparsity) -> tuple[list, list]:
    """nlpsol's hess_lag signature: (x, p, lam_f, lam_g) -> the upper triangle of the Lagrangian's Hessian on
    `pattern`, for nw decisions, no parameters and ng constraints."""
    dense = ca.Sparsity.dense
    return ([("x", dense(nw)), ("p", ca.Sparsity(0, 1)), ("lam_f", dense(1)), ("lam_g", dense(ng))],
            [("triu_hess_gamma_x_x", pattern)])
