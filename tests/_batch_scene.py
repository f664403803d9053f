"""The small navigation scene the batch tests share, as module-scoped fixtures.

A test module imports ``nav`` and ``products`` from here (pytest finds a
fixture by its name in the module) and builds its own polylines from them.
"""

import pytest

from dtalign import scenes
from dtalign.pipeline import prepare_image

#: The coarse search window of every batch test: the scene's offset is
#: (3.4, -2.2) px, well inside it.
WINDOW = (12, 12)


@pytest.fixture(scope="module")
def nav():
    """A small navigation scene: limb, terminator and straight ring edge."""
    return scenes.navigation_scene(shape=(256, 256), radius=60.0, n_vertices=80,
                                   offset_vu=(3.4, -2.2), search_window=12)


@pytest.fixture(scope="module")
def products(nav):
    return prepare_image(nav.image, nav.noise_sigma)
