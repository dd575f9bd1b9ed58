"""The shapes' compiled OBJ vertex parser (:mod:`mocap.mesh._obj_kernel`) against ``float``
and :func:`numpy.loadtxt`, number by number, bit for bit."""

from __future__ import annotations

import io

import numpy as np
import pytest

import mocap.mesh.mesh as mesh_module
from basis.artist import load_artist_basis
from mocap.mesh._obj_kernel import vertex_rows  # the speed extra, which the tests install


def _parse(text: bytes, n: int):
    return mesh_module._compiled_vertices(vertex_rows, np.empty((3 * n, 3), np.int64), text, n)


def _loadtxt(text: bytes) -> np.ndarray:
    return np.loadtxt(io.BytesIO(text), dtype=np.float64, delimiter=" ", usecols=(1, 2, 3),
                      comments=None, ndmin=2)


def _writings(rng, n: int) -> list[bytes]:
    """`n` numbers written as exporters and people write them: repr (up to 17 digits),
    fixed and scientific with 1–20 digits, up to 38 digits, exponents far past ±22
    (subnormals, overflow to inf), signs, leading zeros, no digit before or after the
    point, upper-case E."""
    values = rng.standard_normal(n) * 10.0 ** rng.integers(-40, 40, n)
    values[rng.random(n) < 0.05] = 0.0
    subnormal = rng.random(n) < 0.02
    values[subnormal] = 5e-324 * rng.integers(1, 1000, np.count_nonzero(subnormal))
    out = []
    for value, kind, digits in zip(values.tolist(), rng.integers(0, 9, n).tolist(),
                                   rng.integers(1, 21, n).tolist()):
        if kind == 0:
            text = repr(value)
        elif kind == 1:
            text = f"{value:.{digits}g}"
        elif kind == 2:
            text = f"{value:.{digits}e}".replace("e", "E")
        elif kind == 3:
            text = f"{value:.{min(digits, 12)}f}"
        elif kind == 4:
            text = f"{value:+.6g}"
        elif kind == 5:
            text = "00" + f"{abs(value):.8g}" if "e" not in f"{abs(value):.8g}" else repr(value)
        elif kind == 6:
            text = f"{value:.0f}."                              # no digit after the point
        elif kind == 7:
            text = f"{abs(value) % 1:.9f}"[1:]                  # no digit before it
        else:
            text = (f"{rng.integers(1, 10**18):d}{int(rng.random() * 10**digits):0{digits}d}"
                    f"e{rng.integers(-340, 310)}")                # 19–38 digits, far
        out.append(text.encode())
    return out


@pytest.mark.parametrize("seed", range(4))
def test_every_number_is_floats_and_loadtxts_bit_for_bit(seed, monkeypatch):
    monkeypatch.setattr(mesh_module, "_loadtxt_vertices", None)     # the loop takes them all
    rng = np.random.default_rng(seed)
    n = 3000
    numbers = _writings(rng, 3 * n)
    ends = [b"\n", b"\r\n", b" 1.0\n", b" \n"]
    lines = [b"v " + b" ".join(numbers[3 * i:3 * i + 3]) + ends[i % len(ends)]
             for i in range(n)]
    text = b"".join(lines)
    got = _parse(text, n)
    expected = np.array([float(x) for x in numbers]).reshape(n, 3)
    slow = np.empty((3 * n, 3), np.int64)
    rows, n_slow = vertex_rows(np.frombuffer(text, np.uint8), np.empty((n, 3)), slow)
    assert rows == n and 0 < n_slow < 3 * n // 2     # both ways of converting are tried
    assert np.isinf(expected).any() and (expected == 0).any()
    np.testing.assert_array_equal(got.view(np.int64), expected.view(np.int64))
    np.testing.assert_array_equal(got.view(np.int64), _loadtxt(text).view(np.int64))
    magnitude = np.abs(expected)
    assert ((magnitude > 0) & (magnitude < 2.2e-308)).any()      # subnormals
    assert ((expected == 0) & (expected.view(np.int64) < 0)).any()  # -0.0
    # the last line may end with the text
    np.testing.assert_array_equal(_parse(text.rstrip(b"\n"), n), got)


def _converted_here(numbers: list[bytes]) -> tuple[np.ndarray, int]:
    """The loop's values of `numbers` (three a line) and how many it left to ``float``."""
    n = len(numbers) // 3
    text = b"".join(b"v " + b" ".join(numbers[3 * i:3 * i + 3]) + b"\n" for i in range(n))
    out, slow = np.empty((n, 3)), np.empty((3 * n, 3), np.int64)
    rows, n_slow = vertex_rows(np.frombuffer(text, np.uint8), out, slow)
    assert rows == n
    flat = out.reshape(-1)
    for index, first, end in slow[:n_slow].tolist():
        flat[index] = float(text[first:end])
    return flat, n_slow


def test_significands_of_17_to_19_digits_are_rounded_by_the_loop_as_float_rounds_them():
    """``repr`` (17 digits), ``numpy.savetxt``'s default ``%.18e`` (19) and random 16-19
    digit decimals, powers of ten across the 128-bit table and past it: the loop converts
    nearly all of them itself, each to ``float``'s bits; what it leaves (ties, exact
    products, powers past the table) ``float`` converts."""
    rng = np.random.default_rng(7)
    values = rng.standard_normal(30_000) * 10.0 ** rng.integers(-50, 50, 30_000)
    digits = ["".join(map(str, rng.integers(0, 10, k))) for k in rng.integers(16, 20, 30_000)]
    for numbers, most_left in (
            ([repr(v).encode() for v in values.tolist()], 0.05),
            ([b"%.18e" % v for v in values.tolist()], 0.10),
            ([f"9{d[1:]}e{q}".encode() for d, q in zip(digits,
                                                       rng.integers(-90, 90, 30_000))], 0.5)):
        got, left = _converted_here(numbers)
        expected = np.array([float(x) for x in numbers])
        np.testing.assert_array_equal(got.view(np.int64), expected.view(np.int64))
        assert 0 < left < most_left * len(numbers)


def test_ties_and_carries_the_128_bit_product_cannot_settle_are_left_to_float():
    """Decimals exactly halfway between two doubles (an odd 54-bit integer over a power of
    two, written exactly in up to 19 digits) and exactly representable ones whose
    truncated product lands just under them: ``float`` breaks the tie to even."""
    rng = np.random.default_rng(8)
    ties = []
    for odd, k in zip((2 * rng.integers(2 ** 52, 2 ** 53, 3000) + 1).tolist(),
                      rng.integers(0, 3, 3000).tolist()):
        text = str(odd * 5 ** k)                        # odd / 2^k = odd·5^k / 10^k
        ties.append((text[:-k] + "." + text[-k:] if k else text).encode())
    got, left = _converted_here(ties)
    assert left == len(ties)
    np.testing.assert_array_equal(got, [float(x) for x in ties])
    exact = [repr(v).encode() for v in (rng.integers(2 ** 51, 2 ** 52, 3000) + 0.5).tolist()]
    got, _ = _converted_here(exact)
    np.testing.assert_array_equal(got, [float(x) for x in exact])


def test_the_ict_shapes_parse_as_loadtxt_parses_them(ict_basis, ict_expressions_dir,
                                                        monkeypatch):
    monkeypatch.setattr(mesh_module, "_OBJ_BYTES_WORTH_COMPILING", 0)
    monkeypatch.setattr(mesh_module, "_loadtxt_vertices", None)     # the loop takes them all
    compiled = load_artist_basis(ict_basis.neutral, ict_expressions_dir)
    monkeypatch.undo()
    monkeypatch.setattr(mesh_module, "_compiled_vertex_rows", lambda: None)
    by_numpy = load_artist_basis(ict_basis.neutral, ict_expressions_dir)
    np.testing.assert_array_equal(compiled.displacements.view(np.int64),
                                  by_numpy.displacements.view(np.int64))


@pytest.mark.parametrize("text", [
    b"v 1 2\n",                     # a coordinate short
    b"v  1 2 3\n",                  # two spaces
    b"v 1\t2 3\n",                  # a tab
    b"v 1 2 nan\n",                 # words float() reads
    b"v inf 2 3\n",
    b"v 1 2 3\nv 4 5 6\n",          # more lines than vertices
    b"v 1 2 3\rv 4 5 6\n",          # an old Mac line end
    b"v 1e 2 3\n",                  # an exponent without digits
    b"v . 2 3\n",
    b"v 1.2.3 2 3\n",
])
def test_lines_the_loop_does_not_take_are_left_to_loadtxt(text, monkeypatch):
    calls = []
    original = mesh_module._loadtxt_vertices
    monkeypatch.setattr(mesh_module, "_loadtxt_vertices",
                        lambda t, n: calls.append(t) or original(t, n))
    got = _parse(text, 1)
    assert calls == [text]
    expected = original(text, 1)
    if expected is None:
        assert got is None
    else:
        np.testing.assert_array_equal(got, expected)
