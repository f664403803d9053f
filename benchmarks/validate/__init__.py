"""Validation of dtalign on renders this project did not write (issue 45, items 1-2).

Mitsuba 3 renders the bodies (:mod:`.render`), GalSim draws the PSFs and the
detector adds noise (:mod:`.optics`), :mod:`.families` draws the seeded scenes
of each family, :mod:`.checks` validates the renderer against closed forms,
:mod:`.fitting` fits each scene with dtalign's public API and scores it, and
:mod:`.tables` summarises the scores. ``python -m benchmarks.validate`` runs it
all; ``python -m benchmarks.validate.fixtures`` rewrites the test's fixtures.

:mod:`.fitting`, :mod:`.geometry` and :mod:`.tables` import only NumPy and
dtalign, so the test suite can use them on cached renders without Mitsuba or
GalSim installed.
"""
