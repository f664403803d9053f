"""Hostile files give one-line loader errors naming the file.

Every failure of :func:`dtalign.io.load_image` / :func:`load_polyline_csv`
is a ValueError (or FileNotFoundError / ImportError) whose message is one
line and contains the path, whatever the underlying library raised
(EOFError, DecompressionBombError, ``_csv.Error``...), so the command line
prints it and a batch of files goes on. Image modes other than grey and
RGB(A) are converted (CMYK, YCbCr, palette, LA, 1, I;16, I, F) or refused
by name (LAB), never read as if their channels were R, G, B.
"""

from __future__ import annotations

import io as _stdio
import json
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest

from dtalign import io

PIL = pytest.importorskip("PIL")
from PIL import Image  # noqa: E402

LUMA = np.array([0.299, 0.587, 0.114])


def assert_one_line_naming(exc: BaseException, path: Path) -> None:
    msg = str(exc)
    assert "\n" not in msg, msg
    assert str(path) in msg, msg


def _rgb_image() -> np.ndarray:
    rng = np.random.default_rng(18)
    return rng.integers(0, 256, size=(12, 10, 3)).astype(np.uint8)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _bomb_png(path: Path, side: int = 30000) -> None:
    """A 100-byte PNG whose header claims ``side x side`` grey pixels."""
    ihdr = struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\0" * 64)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr)
                     + _png_chunk(b"IDAT", idat) + _png_chunk(b"IEND", b""))


# ---------------------------------------------------------------------------
# Files that cannot be read: one line naming the file
# ---------------------------------------------------------------------------


def test_empty_npy(tmp_path: Path) -> None:
    p = tmp_path / "empty.npy"
    p.write_bytes(b"")
    with pytest.raises(ValueError, match="cannot read image") as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


def test_npy_header_claiming_more_than_the_file_holds(tmp_path: Path) -> None:
    p = tmp_path / "claims.npy"
    with open(p, "wb") as fh:
        np.lib.format.write_array_header_1_0(
            fh, {"descr": "<f8", "fortran_order": False, "shape": (100_000, 100_000)}
        )
        fh.write(b"\0" * 64)  # 80 GB claimed, 64 bytes present
    with pytest.raises(ValueError, match="cannot read image") as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


@pytest.mark.parametrize("payload", [b"\x93NUMPY\x01\x00", b"not an array at all", b"\x93NUMPY" + b"\xff" * 200])
def test_truncated_or_garbage_npy(tmp_path: Path, payload: bytes) -> None:
    p = tmp_path / "bad.npy"
    p.write_bytes(payload)
    with pytest.raises(ValueError) as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


def test_npy_of_pickled_objects_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "objects.npy"
    np.save(p, np.array([[{"a": 1}]], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError) as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


def test_npy_result_is_an_ordinary_writable_array(tmp_path: Path) -> None:
    p = tmp_path / "ok.npy"
    np.save(p, np.arange(6, dtype=np.int16).reshape(2, 3))
    out = io.load_image(p)
    assert type(out) is np.ndarray and out.dtype == np.float64 and out.flags.writeable
    np.testing.assert_array_equal(out, np.arange(6.0).reshape(2, 3))


def test_png_decompression_bomb(tmp_path: Path) -> None:
    p = tmp_path / "bomb.png"
    _bomb_png(p)
    with pytest.raises(ValueError, match="cannot read image .*DecompressionBomb") as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


@pytest.mark.parametrize("cut", [0, 8, 40, 0.5])
def test_truncated_png(tmp_path: Path, cut: float) -> None:
    buf = _stdio.BytesIO()
    Image.fromarray(_rgb_image()).save(buf, format="PNG")
    raw = buf.getvalue()
    p = tmp_path / "cut.png"
    p.write_bytes(raw[: int(len(raw) * cut) if isinstance(cut, float) else cut])
    with pytest.raises(ValueError) as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


@pytest.mark.parametrize("warnings_as", ["error", "ignore"])
def test_garbage_fits(tmp_path: Path, warnings_as: str) -> None:
    pytest.importorskip("astropy")
    p = tmp_path / "bad.fits"
    p.write_bytes(b"SIMPLE  =                    T" + b"\xff" * 3000)
    with warnings.catch_warnings():
        warnings.simplefilter(warnings_as)  # astropy warns about the header first
        with pytest.raises(ValueError) as info:
            io.load_image(p)
    assert_one_line_naming(info.value, p)


def test_csv_cell_over_the_field_limit(tmp_path: Path) -> None:
    p = tmp_path / "huge_cell.csv"
    p.write_text("v,u,nv,nu,sigma\n1,2,1,0,1\n" + "1" * (200 * 1024) + ",2,1,0,1\n")
    with pytest.raises(ValueError, match="line 3") as info:
        io.load_polyline_csv(p)
    assert_one_line_naming(info.value, p)


def test_csv_unterminated_quote_over_the_field_limit(tmp_path: Path) -> None:
    p = tmp_path / "quote.csv"
    p.write_text('v,u,nv,nu,sigma\n"' + "x\n" * 70_000)
    with pytest.raises(ValueError) as info:
        io.load_polyline_csv(p)
    assert_one_line_naming(info.value, p)


def test_csv_not_utf8(tmp_path: Path) -> None:
    p = tmp_path / "latin.csv"
    p.write_bytes(b"v,u,nv,nu,sigma\n\xff\xfe1,2,1,0,1\n")
    with pytest.raises(ValueError) as info:
        io.load_polyline_csv(p)
    assert_one_line_naming(info.value, p)


# ---------------------------------------------------------------------------
# Image modes
# ---------------------------------------------------------------------------


def _save(tmp_path: Path, img: Image.Image, name: str) -> Path:
    p = tmp_path / name
    img.save(p)
    with Image.open(p) as check:
        assert check.mode == img.mode, (check.mode, img.mode)
    return p


def test_cmyk_is_converted_not_read_as_rgb(tmp_path: Path) -> None:
    rgb = _rgb_image()
    p = _save(tmp_path, Image.fromarray(rgb).convert("CMYK"), "cmyk.tif")
    np.testing.assert_allclose(io.load_image(p), rgb.astype(np.float64) @ LUMA, rtol=0, atol=1e-9)


def test_ycbcr_is_converted(tmp_path: Path) -> None:
    rgb = _rgb_image()
    p = _save(tmp_path, Image.fromarray(rgb).convert("YCbCr"), "ycc.tif")
    # YCbCr holds 8-bit rounded values: the round trip is within a few DN.
    np.testing.assert_allclose(io.load_image(p), rgb.astype(np.float64) @ LUMA, atol=3.0)


def test_palette_image_gives_the_palette_colours(tmp_path: Path) -> None:
    rgb = _rgb_image()
    pal = Image.fromarray(rgb).quantize(colors=16)
    p = _save(tmp_path, pal, "pal.png")
    expected = np.asarray(pal.convert("RGB")).astype(np.float64) @ LUMA
    np.testing.assert_allclose(io.load_image(p), expected, rtol=0, atol=1e-9)


def test_grey_with_alpha_gives_the_grey(tmp_path: Path) -> None:
    grey = _rgb_image()[..., 0]
    la = Image.fromarray(np.dstack([grey, np.full_like(grey, 7)]), mode="LA")
    p = _save(tmp_path, la, "la.png")
    np.testing.assert_array_equal(io.load_image(p), grey.astype(np.float64))


def test_bilevel_image(tmp_path: Path) -> None:
    bits = _rgb_image()[..., 0] > 127
    p = _save(tmp_path, Image.fromarray(bits), "bits.png")
    np.testing.assert_array_equal(io.load_image(p), np.where(bits, 255.0, 0.0))


@pytest.mark.parametrize(
    "dtype, mode, name",
    [(np.uint16, "I;16", "grey16.png"), (np.int32, "I", "grey32.tif"), (np.float32, "F", "float.tif")],
)
def test_wide_grey_modes_keep_their_values(tmp_path: Path, dtype, mode: str, name: str) -> None:
    values = (np.arange(120).reshape(12, 10) * 517 + 3).astype(dtype)
    img = Image.fromarray(values)
    assert img.mode == mode
    p = _save(tmp_path, img, name)
    np.testing.assert_array_equal(io.load_image(p), values.astype(np.float64))


def test_lab_is_refused_by_name(tmp_path: Path) -> None:
    p = _save(tmp_path, Image.fromarray(_rgb_image()).convert("LAB"), "lab.tif")
    with pytest.raises(ValueError, match="mode 'LAB'") as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


def test_multi_frame_image_is_refused(tmp_path: Path) -> None:
    frames = [Image.fromarray(np.full((4, 5), v, dtype=np.uint8)) for v in (10, 200)]
    p = tmp_path / "stack.tif"
    frames[0].save(p, save_all=True, append_images=frames[1:])
    with pytest.raises(ValueError, match="2 frames") as info:
        io.load_image(p)
    assert_one_line_naming(info.value, p)


# ---------------------------------------------------------------------------
# The command line: one line per bad file, and the batch goes on
# ---------------------------------------------------------------------------


def _good_pair(tmp_path: Path) -> tuple[Path, Path]:
    from dtalign import scenes

    scene = scenes.disc_scene()
    image = tmp_path / "good.npy"
    np.save(image, scene.image)
    poly = io.save_polyline_csv(tmp_path / "good.csv", scene.polyline)
    return image, poly


def test_cli_reports_an_empty_npy_in_one_line(tmp_path: Path, capsys) -> None:
    from dtalign import cli

    _, poly = _good_pair(tmp_path)
    bad = tmp_path / "empty.npy"
    bad.write_bytes(b"")
    code = cli.main(["fit", str(bad), str(poly)])
    err = capsys.readouterr().err
    assert code != 0
    assert "Traceback" not in err
    (line,) = err.strip().splitlines()
    assert str(bad) in line


def test_cli_batch_goes_on_past_hostile_files(tmp_path: Path, capsys) -> None:
    from dtalign import cli

    image, poly = _good_pair(tmp_path)
    empty = tmp_path / "empty.npy"
    empty.write_bytes(b"")
    bomb = tmp_path / "bomb.png"
    _bomb_png(bomb)
    huge = tmp_path / "huge.csv"
    huge.write_text("v,u,nv,nu,sigma\n" + "1" * (200 * 1024) + ",2,1,0,1\n")
    pairs = [str(empty), str(poly), str(bomb), str(poly), str(image), str(huge), str(image), str(poly)]
    code = cli.main(["fit", *pairs, "--json", "--no-progress"])
    captured = capsys.readouterr()
    assert code == 1
    assert "Traceback" not in captured.err
    results = json.loads(captured.out)
    assert [("error" in r) for r in results] == [True, True, True, False]
    for r, named in zip(results[:3], (empty, bomb, huge), strict=True):
        assert str(named) in r["error"] and "\n" not in r["error"]
    assert results[3]["n_vertices"] > 0
