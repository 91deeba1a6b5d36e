"""The linear solves of the static path: a sparse direct factorization where it fits, else
conjugate gradients preconditioned by algebraic multigrid.

Each Newton step of :mod:`rackstress.engines.static` solves K·Δp = f with K the bindings'
tangent stiffness (symmetric; indefinite where a binding is compressed beyond its geometric
stiffness). Two ways:

* **direct**: Intel MKL PARDISO through ``pypardiso`` (symmetric indefinite LDLᵀ, METIS
  ordering, ``mtype = -2``), analysed first (:meth:`Pardiso.analyse`: its own estimate of the
  factor's memory and floating-point work), then each Newton step's tangent factorized on
  that analysis (:meth:`Pardiso.refactor`; docs/calibration.md "Static analysis"). It resolves every mode of K whatever its conditioning — a wall one particle
  thick, a long slender arm — where an iterative solve stalls on the near-singular ones.
  Without ``pypardiso`` (a platform MKL has no wheel for) SciPy's SuperLU serves, slower.
* **AMG-CG**: smoothed-aggregation multigrid (pyamg) with the six rigid-body modes as near-null
  space, for parts whose factorization would not fit in memory or would take longer than
  :data:`DIRECT_FLOPS` (measured crossover: docs/benchmarks/static.md).

Example
-------
>>> import numpy as np, scipy.sparse as sp
>>> K = sp.csr_matrix(np.array([[4.0, 1.0], [1.0, 3.0]]))
>>> f = factorize(K)
>>> np.round(f.solve(np.array([1.0, 2.0])), 6).tolist()
[0.090909, 0.636364]
"""
from __future__ import annotations

import time

import numpy as np

#: floating-point work (flop) of one factorization up to which the direct solve is chosen:
#: about 20 s on one core at the ~10 Gflop/s PARDISO reaches here; above, AMG-CG. AMG-CG is
#: fast on solid parts but slow on thin walls: the SO-100 base at 93,236 particles (1.8e11 flop,
#: 1.4 GB) took 164 CG iterations a solve, 5× the time of factorizing each Newton step's tangent
#: (docs/benchmarks/parts-100k); the crossover was 6e10 on the solid blocks
DIRECT_FLOPS = 3e11
#: ... and up to which it is still taken where AMG-CG does not converge within
#: :data:`AMG_PATIENCE` steps (the static path's :class:`rackstress.engines.static._Linear`):
#: about 100 s at the ~20 Gflop/s PARDISO reached here. The SO-100 base at 155,392 particles
#: (1 mm, its 2 mm walls two particles across: 465,216 unknowns) had not finished one Newton
#: step by AMG-CG after 5 minutes; its factorization is 5.1e11 flop, 2.8 GB, 23 s: factorized
#: from the start it settled in 56 s, after AMG-CG's 100 steps in 102 s (measured while
#: building this)
DIRECT_FLOPS_FALLBACK = 2e12
#: the conjugate-gradient steps AMG-CG takes before a direct factorization that fits
#: (:data:`DIRECT_FLOPS_FALLBACK`) replaces it: a solid part converges in tens; the SO-100
#: base at 93,236 particles took 164 a solve, five times the time of factorizing
#: (docs/calibration.md "Static analysis"), and at 155,392 250 steps took 100 s
AMG_PATIENCE = 100
#: share of the available memory a factorization may take
DIRECT_MEMORY_SHARE = 0.5
#: unknowns beyond which the factorization is not even analysed (its ordering alone takes
#: seconds and a GB): AMG-CG
DIRECT_MAX_DOFS = 600_000
#: SuperLU (the fallback) up to this many unknowns: it fills ~6× more than PARDISO's METIS
SUPERLU_MAX_DOFS = 60_000


def _pardiso_prototype():
    """A pypardiso solver whose MKL is loaded, or None when the package or MKL cannot be
    loaded. Each factorization copies it (pypardiso looks for MKL by searching the whole
    environment's tree: 1.2 s a solver)."""
    import glob
    import os
    import sys

    if "PYPARDISO_MKL_RT" not in os.environ:        # where the mkl wheel puts it
        found = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt.so*")), key=len)
        if found:
            os.environ["PYPARDISO_MKL_RT"] = found[0]
    try:
        import pypardiso
        return pypardiso.PyPardisoSolver(mtype=-2)
    except Exception:  # noqa: BLE001 - any failure to load means: use the fallback
        return None


_PARDISO: list = []


def _mkl_threads():
    """MKL on one thread for PARDISO unless ``MKL_NUM_THREADS`` says otherwise: the speed
    targets are per core, batch jobs run one solve per core, and MKL's threads in a process
    where LAMMPS and VTK have loaded their own OpenMP runtime crashed PARDISO's analysis
    (a segmentation fault in ``phase 11``, reproduced by a LAMMPS run and a render before a
    static solve in one process; none on one thread)."""
    import contextlib
    import os

    if os.environ.get("MKL_NUM_THREADS"):
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def backend() -> str:
    """The direct solver this installation has: ``"pardiso"`` or ``"superlu"`` (fallback)."""
    if not _PARDISO:
        _PARDISO.append(_pardiso_prototype())
    return "pardiso" if _PARDISO[0] is not None else "superlu"


class Pardiso:
    """One LDLᵀ factorization of a symmetric matrix by MKL PARDISO (``mtype = -2``).

    ``analyse`` (phase 11) gives the solver's own estimate of the factor's memory
    (:attr:`bytes`) and work (:attr:`flops`); ``factor`` (phase 22) factorizes; ``solve`` (phase
    33) solves with the factor, for any right-hand side, as often as asked.
    """

    kind = "pardiso"

    def __init__(self, K):
        import scipy.sparse as sp

        import copy

        backend()
        self.A = sp.triu(K, format="csr")
        self.A.sort_indices()
        self.n = K.shape[0]
        self.ps = copy.copy(_PARDISO[0])
        self.ps.pt = np.zeros_like(self.ps.pt)           # a handle of its own
        self.ps.iparm = ip = np.zeros(64, dtype=np.int32)
        ip[0] = 1          # iparm(1): these settings, not the defaults
        ip[1] = 2          # METIS nested dissection
        ip[7] = 2          # up to two steps of iterative refinement
        ip[9] = 13         # pivots below 1e-13·‖A‖ perturbed (the default 1e-8 would hide
        #                    the slender modes the static path must resolve)
        ip[10] = 0         # no scaling / matching: K is symmetric with a strong diagonal
        ip[12] = 0
        ip[17] = -1        # report the factor's non-zeros
        ip[18] = -1        # report the factorization's Mflop
        ip[20] = 1         # Bunch–Kaufman pivoting (indefinite)
        ip[34] = 0         # one-based indices (pypardiso passes them so)
        self.bytes, self.flops, self.factored = 0, 0.0, False

    def _call(self, phase: int, b=None):
        self.ps.set_phase(phase)
        rhs = np.zeros((self.n, 1)) if b is None else np.asfortranarray(b, dtype=float)
        with _mkl_threads():
            return self.ps._call_pardiso(self.A, rhs)

    def analyse(self) -> "Pardiso":
        """Ordering and symbolic factorization; sets :attr:`bytes` and :attr:`flops`."""
        self._call(11)
        ip = self.ps.iparm
        # iparm(15): peak of the analysis; (16) permanent; (17) the factorization's own (KB)
        self.bytes = int(max(ip[14], ip[15] + ip[16])) * 1024
        self.flops = float(ip[18]) * 1e6
        return self

    def preconditioner(self) -> "Pardiso":
        """Solves without iterative refinement (each step of it one more solve and product
        with A): an approximate inverse for conjugate gradients, which refine anyway."""
        self.ps.iparm[7] = 0
        return self

    def factor(self) -> "Pardiso":
        self._call(22)
        self.factored = True
        ip = self.ps.iparm
        self.inertia = (int(ip[21]), int(ip[22]))    # positive, negative pivots
        self.perturbed = int(ip[13])
        return self

    def refactor(self, K) -> bool:
        """Factorize ``K`` (a later tangent) on this one's ordering, when its sparsity is the
        same (the bindings do not change between Newton steps); False if it is not."""
        import scipy.sparse as sp

        A = sp.triu(K, format="csr")
        A.sort_indices()
        if not (np.array_equal(A.indptr, self.A.indptr)
                and np.array_equal(A.indices, self.A.indices)):
            # fewer entries (some summed to zero and dropped): their values on the analysed
            # pattern, if every one of them is in it
            old = self._keys(self.A)
            new = self._keys(A)
            at = np.minimum(np.searchsorted(old, new), len(old) - 1)
            if not (len(old) and np.array_equal(old[at], new)):
                return False
            data = np.zeros(len(old))
            data[at] = A.data
            A = sp.csr_matrix((data, self.A.indices, self.A.indptr), shape=self.A.shape)
        self.A = A
        self.factor()
        return True

    @staticmethod
    def _keys(A) -> np.ndarray:
        """Each stored entry of CSR ``A`` (sorted indices) as row·n + column, ascending."""
        rows = np.repeat(np.arange(A.shape[0], dtype=np.int64), np.diff(A.indptr))
        return rows * A.shape[1] + A.indices.astype(np.int64)

    def solve(self, b: np.ndarray) -> np.ndarray:
        return np.asarray(self._call(33, b)).reshape(-1)

    def solve_many(self, B: np.ndarray) -> np.ndarray:
        """The solves of the columns of ``B`` (n, k) with the factor, in one call."""
        B = np.asarray(B, dtype=float)
        return np.asarray(self._call(33, B)).reshape(B.shape)

    def free(self) -> None:
        try:
            self.ps.set_phase(-1)
            self.ps._call_pardiso(self.A, np.zeros((self.n, 1)))
        except Exception:  # noqa: BLE001 - freeing is best effort
            pass


class SuperLU:
    """The fallback: SciPy's SuperLU with the symmetric ordering (MMD on Kᵀ + K)."""

    kind = "superlu"

    def __init__(self, K):
        self.K = K.tocsc()
        self.n = K.shape[0]
        # a measured ~6× PARDISO's fill on the lattice (the cantilever at 1 mm: 58 M non-zeros)
        self.bytes = int(16 * 6 * 300 * self.n)
        self.flops = 0.0
        self.factored = False

    def analyse(self) -> "SuperLU":
        return self

    def factor(self) -> "SuperLU":
        import scipy.sparse.linalg as spla

        self.lu = spla.splu(self.K, permc_spec="MMD_AT_PLUS_A",
                            options={"SymmetricMode": True})
        self.factored = True
        return self

    def refactor(self, K) -> bool:
        self.K = K.tocsc()
        self.factor()
        return True

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self.lu.solve(np.asarray(b, dtype=float))

    def solve_many(self, B: np.ndarray) -> np.ndarray:
        """The solves of the columns of ``B`` (n, k) with the factor, in one call."""
        return self.lu.solve(np.asarray(B, dtype=float))

    def free(self) -> None:
        self.lu = None


def plan_direct(K, available: int | None = None, flops: float | None = None):
    """The analysed direct factorization of ``K`` when it fits (module doc), else None: AMG-CG.

    The choice: at most :data:`DIRECT_MAX_DOFS` unknowns, the factor's memory (the solver's own
    estimate) at most :data:`DIRECT_MEMORY_SHARE` of the available memory, its work at most
    ``flops`` (:data:`DIRECT_FLOPS`; :data:`DIRECT_FLOPS_FALLBACK` where AMG-CG stalled)."""
    from rackstress.lib.resources import available_memory

    n = K.shape[0]
    if n > DIRECT_MAX_DOFS:
        return None
    have = available if available is not None else available_memory()
    if backend() == "pardiso":
        f = Pardiso(K).analyse()
        if f.bytes <= DIRECT_MEMORY_SHARE * have and f.flops <= (flops or DIRECT_FLOPS):
            return f
        f.free()
        return None
    if n > SUPERLU_MAX_DOFS:
        return None
    f = SuperLU(K)
    return f if f.bytes <= DIRECT_MEMORY_SHARE * have else None


def factorize(K):
    """``K`` factorized by the direct solver (no size check: :func:`plan_direct` has one)."""
    f = Pardiso(K) if backend() == "pardiso" else SuperLU(K)
    return f.analyse().factor()


class AMG:
    """Conjugate gradients preconditioned by smoothed-aggregation AMG, the hierarchy built once
    for a tangent and kept for the Newton steps after it (the tangent changes little)."""

    kind = "amg-cg"

    def __init__(self, K, B: np.ndarray):
        import pyamg

        self.K = K
        t0 = time.process_time()
        ml = pyamg.smoothed_aggregation_solver(K, B=B, symmetry="symmetric",
                                               strength=("symmetric", {"theta": 0.0}),
                                               max_coarse=500, coarse_solver="splu")
        # splu: the coarsest level factorized once; pyamg's default (a pseudo-inverse by SVD of
        # a dense ~1,500² matrix) took 90 % of the bracket's solve (7 s against 0.7 s CPU)
        self.M = ml.aspreconditioner(cycle="V")
        self.setup_s = time.process_time() - t0
        self.converged = True

    #: the most conjugate-gradient steps of a solve
    MAXITER = 2000

    def solve(self, b: np.ndarray, rtol: float = 1e-8, K=None, maxiter: int | None = None,
              x0=None) -> np.ndarray:
        import scipy.sparse.linalg as spla

        x, info = spla.cg(self.K if K is None else K, b, x0=x0, rtol=rtol,
                          maxiter=maxiter or self.MAXITER, M=self.M)
        self.converged = info == 0
        return x

    def free(self) -> None:
        self.M = None
