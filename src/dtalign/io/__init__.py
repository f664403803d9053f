"""Files in and out: images and model polylines (:mod:`dtalign.io.files`),
and the Cassini summary PNGs (:mod:`dtalign.io.cassini`, which builds on
:mod:`dtalign.io.files`; nothing here imports it).

The file functions are re-exported here: ``dtalign.io.load_image`` is
``dtalign.io.files.load_image``.
"""

from .files import (
    POLYLINE_COLUMNS,
    concatenate_polylines,
    load_image,
    load_polyline_csv,
    read_image,
    save_polyline_csv,
)

__all__ = [
    "POLYLINE_COLUMNS",
    "concatenate_polylines",
    "load_image",
    "load_polyline_csv",
    "read_image",
    "save_polyline_csv",
]
