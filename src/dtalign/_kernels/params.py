"""The number of pose parameters: the one place it is written.

``register_jitable`` makes :func:`n_params` an ordinary Python function
that compiled code can call too (it is compiled into its caller), so the
kernels, the pipeline and the result read the same definition. The plain
NumPy specification (:mod:`dtalign.reference`) keeps its own: it shares no
code with what it checks.
"""

from numba.extending import register_jitable


@register_jitable
def n_params(fit_rotation):
    """2 (``dv``, ``du``), or 3 with the rotation fitted."""
    return 3 if fit_rotation else 2
