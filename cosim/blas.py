"""BLAS on one thread, for the numbers a run must reproduce on any machine.

OpenBLAS (and MKL) split a large product among their threads, one per core by default, and the split
changes its last bits; an LMI solver, an adaptive quadrature or a discretization turns those into
designs apart by far more (the vessel diagnosis's observers and rotating-frame gains, its residual
frames with them, differed between one BLAS thread and two). So a run's plan (the model's
linearization, the designs) and every estimator or controller a node or an FMU builds are computed
on one thread (``one_thread``): the same numbers whatever the core count. So is the run itself
(``Run.execute``, a campaign's batch; a node's or an FMU host's process from its start,
``ONE_THREAD_ENV``): a step's products are then split alike on any machine too, and the processes
of a campaign do not each start a thread per core.
"""

from __future__ import annotations

from threadpoolctl import threadpool_limits

#: The environment of a process the run starts (a node, an FMU's host): its BLAS on one thread from
#: the start, whatever it loads later.
ONE_THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def one_thread() -> threadpool_limits:
    """A context in which BLAS computes on one thread. threadpoolctl limits the libraries loaded
    when it is entered, so NumPy's and SciPy's are loaded first (SciPy's is loaded by its first
    ``scipy.linalg`` import, which a node may make only while it builds its estimator); a library
    loaded inside the context (a solver's own BLAS) is not limited."""
    import scipy.linalg  # noqa: F401 (loads SciPy's OpenBLAS, so that it is limited too)

    return threadpool_limits(limits=1, user_api="blas")
