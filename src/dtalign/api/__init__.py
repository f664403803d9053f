"""The drop-in contract: one module per stage of the specification.

:mod:`~dtalign.api.sampling`, :mod:`~dtalign.api.coarse`,
:mod:`~dtalign.api.weights`, :mod:`~dtalign.api.lm`,
:mod:`~dtalign.api.ridge`, :mod:`~dtalign.api.image`,
:mod:`~dtalign.api.basin` and :mod:`~dtalign.api.gates` each check their
arguments (:mod:`~dtalign.api.checks`), call the compiled kernels of
``dtalign._kernels`` and wrap what they return in the types of
:mod:`~dtalign.api.results`; the defaults live in
:mod:`~dtalign.api.constants`. The public names are re-exported by the
package root (``dtalign.lm_subpixel_refine``); this package imports nothing
itself, so importing a constant does not load Numba.
"""
