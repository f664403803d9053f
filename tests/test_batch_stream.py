"""``fit_images(..., on_image=...)`` hands each image on in input order, and an
item may be a loader called in the image's task (issue 29: the command line's
batch runs through :func:`~dtalign.pipeline.batch.fit_images`)."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

import _batch_scene
from _batch_scene import WINDOW
from dtalign.benchmarking.compare import results_equal
from dtalign.pipeline.batch import fit_images

nav = _batch_scene.nav  # the shared scene (a module-scoped fixture)


class Handed:
    """An ``on_image`` callback that records ``(i, result, thread)``."""

    def __init__(self, raise_at=None):
        self.calls = []
        self.raise_at = raise_at

    def __call__(self, i, result):
        self.calls.append((i, result, threading.get_ident()))
        if i == self.raise_at:
            raise RuntimeError("stop")


def _items(nav):
    return [nav, (nav.image, 2.0, nav.polylines[:1]), (nav.image, None, nav.polylines[1:]),
            (nav.image, nav.noise_sigma, nav.polylines[2:])]


@pytest.mark.parametrize(("executor", "workers"), [("thread", 1), ("thread", 2), ("pool", 2)])
def test_on_image_hands_each_image_in_order_from_the_calling_thread(nav, executor, workers):
    items = _items(nav)
    expected = fit_images(items, search_window_vu=WINDOW, workers=1)
    handed = Handed()
    if executor == "pool":
        with ThreadPoolExecutor(max_workers=workers) as pool:
            got = fit_images(items, search_window_vu=WINDOW, executor=pool, on_image=handed)
    else:
        got = fit_images(items, search_window_vu=WINDOW, workers=workers, on_image=handed)
    assert [i for i, _, _ in handed.calls] == list(range(len(items)))
    assert {t for _, _, t in handed.calls} == {threading.get_ident()}
    assert all(r is got[i] for i, r, _ in handed.calls)  # what the returned list holds
    assert results_equal(got, expected)


def test_a_loader_item_is_called_in_the_task_and_its_error_is_the_images(nav):
    calls = []

    def loader(k):
        def load():
            calls.append(threading.get_ident())
            if k == 1:
                raise OSError("frame 1 is unreadable")
            return _items(nav)[k]
        return load

    items = [loader(k) for k in range(3)]
    expected = fit_images([_items(nav)[0], _items(nav)[2]], search_window_vu=WINDOW, workers=1)
    handed = Handed()
    got = fit_images(items, search_window_vu=WINDOW, workers=2, errors="collect",
                     on_image=handed)
    assert len(calls) == 3 and threading.get_ident() not in calls  # in the tasks
    assert results_equal([got[0], got[2]], expected)
    assert isinstance(got[1], OSError) and got[1].index == 1
    assert str(got[1]) == "frame 1 is unreadable" and got[1].__notes__ == ["images[1]"]
    assert [i for i, _, _ in handed.calls] == [0, 1, 2] and handed.calls[1][1] is got[1]
    with pytest.raises(OSError, match=r"^frame 1") as info:
        fit_images(items, search_window_vu=WINDOW, workers=2, on_image=(raising := Handed()))
    assert info.value.__notes__ == ["images[1]"]
    assert [i for i, _, _ in raising.calls] == [0]  # the images before the failure only
    with pytest.raises(TypeError, match=r"^items\[0\] must be") as info:
        fit_images([lambda: "no item"], search_window_vu=WINDOW, workers=1)
    assert info.value.__notes__ == ["images[0]"]


def test_a_raising_on_image_stops_the_batch_and_keeps_what_was_handed(nav):
    items = _items(nav) * 3
    before = threading.active_count()
    handed = Handed(raise_at=1)
    with pytest.raises(RuntimeError, match="^stop$"):
        fit_images(items, search_window_vu=WINDOW, workers=2, on_image=handed)
    assert [i for i, _, _ in handed.calls] == [0, 1]
    assert threading.active_count() == before


def test_images_handed_on_are_not_logged(nav, caplog):
    bad = (nav.image, 2.0, [(p.vertices_vu, -p.normals_vu, p.sigmas) for p in nav.polylines[:1]])
    with caplog.at_level("WARNING", logger="dtalign"):
        fit_images([bad], search_window_vu=WINDOW, workers=1)
    assert caplog.records  # logged by fit_images
    caplog.clear()
    with caplog.at_level("WARNING", logger="dtalign"):
        fit_images([bad], search_window_vu=WINDOW, workers=1, on_image=Handed())
    assert not caplog.records  # the callback's to report
