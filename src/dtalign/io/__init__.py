"""Files in and out: images and model polylines (:mod:`dtalign.io.files`),
and the Cassini summary PNGs (:mod:`dtalign.io.cassini`, which builds on
:mod:`dtalign.io.files`; nothing here imports it).

The file functions are re-exported here: ``dtalign.io.load_image`` is
``dtalign.io.files.load_image``.
"""

from . import files
from .files import *  # noqa: F403 (exactly the names in files.__all__)

#: The re-exported names: :mod:`dtalign.io.files` lists them, once.
__all__ = files.__all__
