"""A DPP cvxpy problem solved from its compiled parametric program by a kept Clarabel solver,
without ``Problem.solve``: the cvxpy backend's fast route for the vertex-form QP (20).

Why. cvxpy compiles a DPP problem once into a parametric cone program: sparse tensors that map the
vector of parameter values (each parameter flattened in column-major order, then a constant 1) to
Clarabel's data (P, q, A, b of ``min ½ yᵀP y + qᵀy  s.t.  A y + s = b, s ∈ K``). ``Problem.solve``
applies that map and then spends about as long again in generic bookkeeping around it: the
reduction chain's parameter hooks, building new scipy matrices and slicing them, the solver
interface's settings parsing, inverting the chain and unpacking every variable and dual value. On
Example 1 (8 facets, N = 10) that modelling layer measured 1.45-2.3 ms per solve against Clarabel's
own 1.06-1.58 ms (``benchmarks/solver_floor.py``), so the cvxpy step could not come within 1.3× of
the Drake step through ``Problem.solve`` (floor 1.6×).

What stays cvxpy's. The formulation (:mod:`amcp_reference.tube_vertex`), its canonicalisation and
the parameter-to-data tensors are cvxpy's, compiled by cvxpy's own ``get_problem_data``: the
reference backend stays independent of Drake's formulation. This module only evaluates cvxpy's
affine map (three sparse products whose results fill arrays of fixed sparsity pattern), hands the
values to a Clarabel solver kept between solves (``update`` of values only), and slices the
variables out of Clarabel's primal vector at cvxpy's own column offsets.

How it is trusted. (1) At construction the data evaluated here is compared with cvxpy's
``get_problem_data`` for the parameter values set then and for random values of every parameter
(seed :data:`CHECK_SEED`; the values set then are restored): every entry the parameters reach is
exercised, not only those that happen to be nonzero (:data:`DATA_MATCH_TOL`, relative to each
matrix's largest entry); any difference, or a cvxpy whose compiled program lacks what is read
here, leaves the route off (:attr:`CompiledClarabel.reason`) and the caller uses ``Problem.solve``.
(2) ``tests/test_compiled_clarabel.py`` compares the data with ``get_problem_data`` on random
parameter values and the solution with ``Problem.solve``. (3) Every answer of the controller is
checked against the original rows (``amcp_drake.online.answer_checks``) whatever route produced it.
(4) Any Clarabel status other than ``Solved`` is returned as it is, and the caller solves the step
again through ``Problem.solve`` (with its retry ladder): the fast route never decides a hard step.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: Largest difference allowed at construction between the data evaluated here and cvxpy's own
#: ``get_problem_data``, relative to the largest entry of each of P, q, A, b. Both evaluate the same
#: sparse products, so they agree to round-off (measured 0 on Example 1); anything larger means the
#: compiled program is not read as cvxpy reads it.
DATA_MATCH_TOL = 1e-12
#: Seed of the random parameter values of the construction check.
CHECK_SEED = 20261124
#: Clarabel's status string of an answer (cvxpy's ``CLARABEL.STATUS_MAP`` maps it to ``optimal``).
SOLVED = "Solved"


class CompiledClarabel:
    """Clarabel's data of a compiled DPP problem, evaluated from the parameters' current values.

    ``problem``: a DPP ``cvxpy.Problem`` whose parameters all have values; ``settings``: every
    Clarabel setting by name (``SolverCall``'s base options); ``read``: the variables the caller will
    read with :meth:`value` (checked to be in the compiled program now, not at the first answer).
    :attr:`reason` is None when the route is usable, else why not (then :meth:`solve` must not be
    called).
    """

    def __init__(self, problem, settings: dict, read: tuple = ()) -> None:
        self.problem = problem
        self.settings = dict(settings)
        self._read = tuple(read)
        self._solver = None
        #: the values of P and A last given to the solver
        self._last: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
        self.reason: str | None = None
        try:
            self._compile()
        except Exception as exc:  # noqa: BLE001 - any surprise in cvxpy's internals turns the route off
            self.reason = f"compiled route off: {type(exc).__name__}: {exc}"

    # -- construction -------------------------------------------------------------------------------
    def _compile(self) -> None:
        import cvxpy.settings as cps
        from cvxpy.lin_ops.lin_op import CONSTANT_ID
        from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import dims_to_solver_cones

        data, _, _ = self.problem.get_problem_data("CLARABEL", enforce_dpp=True)
        prog = data[cps.PARAM_PROB]
        if getattr(prog, "lb_tensor", None) is not None or getattr(prog, "ub_tensor", None) is not None:
            raise ValueError("the compiled program has variable bounds, which Clarabel's form here does not take")
        self.n = int(prog.x.size)
        # the parameter vector: every parameter at its column offset, the constant 1 at its own column
        self._param_vec = np.zeros(int(prog.total_param_size) + 1)
        self._slots = []
        for pid, col in prog.param_id_to_col.items():
            if pid == CONSTANT_ID:
                self._param_vec[col] = 1.0
            else:
                self._slots.append((prog.id_to_param[pid], int(col), int(prog.param_id_to_size[pid])))
        self._q_tensor = sp.csr_array(prog.q)
        prog.reduced_A.cache(keep_zeros=False)
        self._A_tensor = sp.csr_array(prog.reduced_A.reduced_mat)
        self._A_map, self._A_pattern, self._b_rows, self._b_map = _split_offset(prog.reduced_A.problem_data_index)
        self._m = self._A_pattern.shape[0]
        if prog.reduced_P.matrix_data is not None:
            prog.reduced_P.cache(keep_zeros=False)
            self._P_tensor = sp.csr_array(prog.reduced_P.reduced_mat)
            self._P_map, self._P_pattern = _upper_triangle(prog.reduced_P.problem_data_index)
        else:
            self._P_tensor, self._P_map = None, None
            self._P_pattern = sp.csc_array((self.n, self.n))
        self._cones = dims_to_solver_cones(prog.cone_dims)
        self._columns = {var.id: (int(prog.var_id_to_col[var.id]), var.shape) for var in prog.variables}
        missing = [var.name() for var in self._read if var.id not in self._columns]
        if missing:
            raise ValueError(f"variables {missing} are not in cvxpy's compiled program (a variable with attributes "
                             "such as nonneg=True is replaced there by a new one)")
        self._check_against(data)
        # again at random values of every parameter (a map read wrongly where the values set now are zero
        # would pass the check above), then the values set now are restored
        saved = [(param, param.value) for param, _, _ in self._slots]
        rng = np.random.default_rng(CHECK_SEED)
        try:
            for param, _ in saved:
                param.value = rng.standard_normal(param.shape)
            self._check_against(self.problem.get_problem_data("CLARABEL", enforce_dpp=True)[0])
        finally:
            for param, value in saved:
                param.value = value

    def _check_against(self, data) -> None:
        """The data evaluated here equals cvxpy's own (see the module docstring, point 1)."""
        import cvxpy.settings as cps

        P, q, A, b = self._data()
        theirs = {"P": sp.triu(data[cps.P]).toarray() if cps.P in data else np.zeros((self.n, self.n)),
                  "q": np.asarray(data[cps.C], float), "A": data[cps.A].toarray(), "b": np.asarray(data[cps.B], float)}
        ours = {"P": _csc(self._P_pattern, P).toarray(), "q": q, "A": _csc(self._A_pattern, A).toarray(), "b": b}
        for name in ("P", "q", "A", "b"):
            if ours[name].shape != theirs[name].shape:
                raise ValueError(f"{name} has shape {ours[name].shape}, cvxpy's {theirs[name].shape}")
            scale = max(1.0, float(np.max(np.abs(theirs[name]), initial=0.0)))
            gap = float(np.max(np.abs(ours[name] - theirs[name]), initial=0.0))
            if gap > DATA_MATCH_TOL * scale:
                raise ValueError(f"{name} differs from cvxpy's get_problem_data by {gap:.3g}")

    # -- per solve ----------------------------------------------------------------------------------
    def _data(self) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, np.ndarray]:
        """(values of P's upper triangle, q, values of A, b) for the parameters' current values."""
        vec = self._param_vec
        for param, col, size in self._slots:
            vec[col:col + size] = np.ravel(param.value, order="F")
        q = (self._q_tensor @ vec)[:self.n]
        flat = self._A_tensor @ vec
        A = -flat[self._A_map]          # cvxpy's ConicSolver.apply: data[A] = −A, so A y + s = b
        b = np.zeros(self._m)
        b[self._b_rows] = flat[self._b_map]
        P = (self._P_tensor @ vec)[self._P_map] if self._P_tensor is not None else None
        return P, q, A, b

    def solve(self):
        """Clarabel's solution (``status``, ``x``, ``solve_time``, ...) for the current parameter values."""
        import clarabel

        P, q, A, b = self._data()
        if self._solver is not None and self._solver.is_data_update_allowed():
            # P and A by the entries that changed ((positions, values): on Example 1 a full update of A
            # took 0.19 ms, of its ~60 entries that depend on θ̂_k 0.01 ms); q and b whole
            update = {"q": q, "b": b}
            for name, new, old in (("A", A, self._last[1]), ("P", P, self._last[0])):
                if new is not None:
                    changed = np.flatnonzero(new != old)
                    if changed.size:
                        update[name] = (changed, new[changed])
            self._solver.update(**update)
        else:
            settings = clarabel.DefaultSettings()
            for name, value in self.settings.items():
                setattr(settings, name, value)
            settings.verbose = False
            self._solver = clarabel.DefaultSolver(_csc(self._P_pattern, P), q, _csc(self._A_pattern, A), b,
                                                  self._cones, settings)
        self._last = (P, A)
        return self._solver.solve()

    def forget_solver(self) -> None:
        """The next :meth:`solve` builds a new Clarabel solver (after a step without an answer)."""
        self._solver = None

    def value(self, variable, x) -> np.ndarray:
        """``variable``'s value in Clarabel's primal vector ``x`` (cvxpy's column offset, column-major)."""
        if variable.id not in self._columns:
            raise KeyError(f"variable {variable.name()!r} is not in cvxpy's compiled program (a variable with "
                           "attributes such as nonneg=True is replaced there by a new one)")
        col, shape = self._columns[variable.id]
        size = int(np.prod(shape, dtype=int))
        return np.reshape(np.asarray(x, float)[col:col + size], shape, order="F")


def _csc(pattern: sp.csc_array, values: np.ndarray | None) -> sp.csc_array:
    """``pattern`` (a CSC matrix of markers) with ``values`` in its stored entries."""
    if values is None:
        return sp.csc_array(pattern.shape)
    return sp.csc_array((values, pattern.indices, pattern.indptr), shape=pattern.shape)


def _markers(index) -> sp.csc_array:
    """The CSC matrix of cvxpy's ``problem_data_index`` (indices, indptr, shape) whose stored entries
    are 1, 2, ...: entry value − 1 is the position in the tensor product that fills it."""
    indices, indptr, shape = index
    marks = sp.csc_array((np.ones(len(indices)), indices, indptr), shape=shape)
    if not marks.has_canonical_format:  # duplicate or unsorted entries would merge markers
        raise ValueError("cvxpy's problem data index is not in canonical CSC form")
    return sp.csc_array((np.arange(1, len(indices) + 1, dtype=float), indices, indptr), shape=shape)


def _split_offset(index) -> tuple[np.ndarray, sp.csc_array, np.ndarray, np.ndarray]:
    """cvxpy's [A | b] (last column the offset, as ``get_matrix_from_tensor`` reads it): positions of
    A's stored entries in the product, A's pattern, and b's rows with their positions."""
    marks = _markers(index)
    A = sp.csc_array(marks[:, :-1])
    A.sort_indices()
    b = sp.csc_array(marks[:, [-1]])
    b.sort_indices()
    return A.data.astype(int) - 1, A, b.indices.copy(), b.data.astype(int) - 1


def _upper_triangle(index) -> tuple[np.ndarray, sp.csc_array]:
    """The upper triangle of cvxpy's P (``CLARABEL.solve_via_data`` passes ``sp.triu(P)``): positions of
    its stored entries in the product, and its pattern."""
    P = sp.csc_array(sp.triu(_markers(index), format="csc"))
    P.sort_indices()
    return P.data.astype(int) - 1, P
