"""The one module of argument checks (``dtalign.api.checks``), for the callers
beyond the drop-in functions: the search window in its three forms (the API's
tuple, the command line's text, the manifest's field), the batch functions'
own arguments and the manifest's fields. Each message names the argument as
its caller passes the name, without a rewrite afterwards.

The drop-in functions' messages are pinned in ``tests/spec/test_spec_errors.py``.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from dtalign.api import checks

# --------------------------------------------------------------------------- the window


@pytest.mark.parametrize(("value", "expected"), [
    ((3, 4), (3, 4)), ([0, 7], (0, 7)), ((np.int64(2), 5), (2, 5)),
])
def test_window_argument_form(value, expected):
    assert checks.search_window(value) == expected


def test_window_argument_form_names_the_argument_given():
    with pytest.raises(ValueError, match=re.escape("win must be a length-2 sequence of ints; got 5")):
        checks.search_window(5, "win")
    with pytest.raises(TypeError, match=re.escape("win[1] must be int; got float")):
        checks.search_window((1, 2.0), "win")
    with pytest.raises(ValueError, match=re.escape("win must be non-negative; got (1, -2)")):
        checks.search_window((1, -2), "win")
    with pytest.raises(ValueError, match=re.escape("search_window_vu must be a length-2")):
        checks.search_window("8,6")  # text is the option's and the field's form, not the API's


@pytest.mark.parametrize(("text", "expected"), [
    ("8", (8, 8)), ("8,6", (8, 6)), (" 8 , 6 ", (8, 6)), ("0,3", (0, 3)),
])
def test_window_option_form(text, expected):
    assert checks.search_window(text, "--window", form="option") == expected


@pytest.mark.parametrize(("text", "message"), [
    ("1,2,3", "--window takes one or two ints (N or V,U), got '1,2,3'"),
    ("x", "--window takes ints (N or V,U), got 'x'"),
    ("8,x", "--window takes ints (N or V,U), got '8,x'"),
    ("", "--window takes ints (N or V,U), got ''"),
    ("-1", "--window must be non-negative, got -1"),
    ("3,-1", "--window must be non-negative, got 3,-1"),
])
def test_window_option_form_errors(text, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        checks.search_window(text, "--window", form="option")


@pytest.mark.parametrize(("value", "expected"), [
    (5, (5, 5)), ([5], (5, 5)), ([3, 4], (3, 4)), ((3, 4), (3, 4)),
    ("30", (30, 30)), ("30 20", (30, 20)), ("30,20", (30, 20)), ("30, 20", (30, 20)),
])
def test_window_field_form(value, expected):
    assert checks.search_window(value, "window", form="field") == expected


@pytest.mark.parametrize(("value", "message"), [
    ([1, 2, 3], "w: window must be an int or a list of two ints, got [1, 2, 3]"),
    ("1,2,3", "w: window must be an int or a list of two ints, got '1,2,3'"),
    (True, "w: window must be an int or a list of two ints, got True"),
    ([1.5, 2], "w: window must be an int or a list of two ints, got [1.5, 2]"),
    ("x", "w: window takes one int or two separated by a comma or a space, got 'x'"),
    (-1, "w: window must be non-negative, got -1"),
    ([2, -1], "w: window must be non-negative, got [2, -1]"),
])
def test_window_field_form_errors(value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        checks.search_window(value, "w: window", form="field")


def test_window_form_is_checked():
    with pytest.raises(ValueError, match="form must be one of"):
        checks.search_window((1, 1), form="text")


# --------------------------------------------------------------------------- the batch's arguments


def test_workers():
    assert checks.workers(2) == 2 and checks.workers(np.int32(1)) == 1
    with pytest.raises(TypeError, match="workers must be an int >= 1, got bool"):
        checks.workers(True)
    with pytest.raises(TypeError, match="workers must be an int >= 1, got float"):
        checks.workers(2.0)
    with pytest.raises(ValueError, match="workers must be >= 1, got 0"):
        checks.workers(0)


def test_collect_errors_and_progress():
    assert checks.collect_errors("collect") is True and checks.collect_errors("raise") is False
    with pytest.raises(ValueError, match=re.escape("errors must be one of ('raise', 'collect')")):
        checks.collect_errors("ignore")
    assert checks.progress_callback(None) is None and checks.progress_callback(True) is True
    assert checks.progress_callback(print) is print
    with pytest.raises(TypeError, match="progress must be a callable progress"):
        checks.progress_callback(3)


def test_the_batch_uses_these_checks():
    from dtalign.pipeline import batch

    with pytest.raises(ValueError, match="workers must be >= 1"):
        batch.map_ordered(abs, [1], workers=0)


# --------------------------------------------------------------------------- a record's fields


def test_known_names():
    checks.known_names({"a": 1}, ("a", "b"), "field")
    with pytest.raises(ValueError, match=re.escape(
            "line 3: unknown field(s) 'c', 'd'; accepted: a, b")):
        checks.known_names(["d", "a", "c"], ("a", "b"), "field", "line 3")
    with pytest.raises(ValueError, match=re.escape("unknown fit option(s) 'z'; accepted: a")):
        checks.known_names(["z"], ("a",), "fit option")


def test_paths_and_labels():
    assert checks.path_text("  a.npy ", "image") == "a.npy"
    with pytest.raises(ValueError, match="image must be a non-empty path"):
        checks.path_text(" ", "image")
    assert checks.path_list("a.csv; b.csv", "polylines", ";") == ("a.csv", "b.csv")
    assert checks.path_list(["a.csv"], "polylines", ";") == ("a.csv",)
    with pytest.raises(ValueError, match="polylines is missing"):
        checks.path_list(None, "polylines", ";")
    with pytest.raises(ValueError, match="polylines must be a path or a list of paths"):
        checks.path_list(3, "polylines", ";")
    with pytest.raises(ValueError, match="polylines must hold one or more non-empty paths"):
        checks.path_list(["a.csv", ""], "polylines", ";")
    assert checks.label(None, "id", "a.npy") == "a.npy" and checks.label(7, "id", "x") == "7"
    with pytest.raises(ValueError, match="id must be a string, got bool"):
        checks.label(True, "id", "x")


def test_numbers_and_json():
    assert checks.optional_nonnegative("", "noise_sigma") is None
    assert checks.optional_nonnegative("2.5", "noise_sigma") == 2.5
    with pytest.raises(ValueError, match="noise_sigma must be a number, got 'x'"):
        checks.optional_nonnegative("x", "noise_sigma")
    with pytest.raises(ValueError, match="noise_sigma must be finite and >= 0, got -1"):
        checks.optional_nonnegative(-1, "noise_sigma")
    assert checks.json_object('{"a": 1}', "options") == {"a": 1}
    assert checks.json_object(None, "options") == {}
    with pytest.raises(ValueError, match="options is not a JSON object"):
        checks.json_object("{", "options")
    with pytest.raises(ValueError, match="options must be an object, got list"):
        checks.json_object([1], "options")
    assert checks.json_list("[null, {}]", 2, "spheres", "polyline") == [None, {}]
    with pytest.raises(ValueError, match=re.escape(
            "spheres must be a list of 2 entries (one per polyline, null for none)")):
        checks.json_list([None], 2, "spheres", "polyline")
    assert checks.keywords({"a": 1}, "s[0]", ("a", "b"), ("a",)) == {"a": 1}
    with pytest.raises(ValueError, match=re.escape("s[0]: unknown key(s) 'c'; missing a; keys: a, b")):
        checks.keywords({"c": 1}, "s[0]", ("a", "b"), ("a",))


def test_check_image_names_the_argument():
    with pytest.raises(TypeError, match="^image must be 2-D; got ndim=1$"):
        checks.check_image(np.ones(3), "image")
    with pytest.raises(TypeError, match="^image_ext must be 2-D"):
        checks.check_image(np.ones(3))


def test_noise_sigma_and_campaign_counts_name_the_argument():
    with pytest.raises(ValueError, match="^noise_sigma must be finite and >= 0; got -1.0$"):
        checks.check_noise_sigma(-1.0, "noise_sigma")
    with pytest.raises(ValueError, match="^image_noise_sigma must be finite and >= 0; got 'x'$"):
        checks.check_noise_sigma("x")
    assert checks.int_at_least(3, "frames") == 3 and checks.int_at_least(128, "size", 128) == 128
    for bad in (0, True, 2.0, "3"):
        with pytest.raises(ValueError, match=re.escape(f"frames must be an int >= 1, got {bad!r}")):
            checks.int_at_least(bad, "frames")
