"""``dtalign.ridge`` is :mod:`dtalign.api.ridge`, the same module object.

The contract fixes this path (:ref:`contract-lm`):
:func:`dtalign.lm_subpixel_refine` looks up
``dtalign.ridge.gradient_ridge_refine`` at call time, so a caller (a test's
``monkeypatch.setattr(dtalign.ridge, ...)``) can replace the ridge stage.
Binding the name to the api module itself, rather than re-exporting its
function, keeps such a replacement effective: there is one attribute.
"""

import sys

from .api import ridge as _ridge

# :ref:`contract-changes`: the module object replaces this one in sys.modules, so
# ``import dtalign.ridge`` and the package attribute ``dtalign.ridge`` are it.
sys.modules[__name__] = _ridge
