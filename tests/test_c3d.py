"""C3D reader and writer: against ezc3d, a brute-force struct decoder and known facts."""

from __future__ import annotations

import math
import struct
import warnings

import ezc3d
import numpy as np
import pytest
import threadpoolctl
from tolerances import C3D_ANALOG_FLOOR, C3D_VS_EZC3D_MM, EXACT_FLOAT64, FLOAT32_REL

from mocap import Take
from mocap.errors import FileFormatError, InputError
from mocap.io._c3d_numbers import BYTE_ORDERS
from mocap.io.c3d import read_c3d, read_c3d_parameters, write_c3d
from mocap.take import Analog
from mocap.units import mm_per_unit
from mocap.util.blas import worker_threads

# Files ezc3d 1.7.2 opens with their points (it fails on the MIPS files,
# Dance.c3d, facial-sing.c3d and bad_parameter_section.c3d; it segfaults on the
# latter with ignore_bad_formatting; it opens phasespace_sample.c3d with 0 points).
EZC3D_FILES = [f"c3d-samples/sample_01/Eb015{k}.c3d" for k in ("pi", "pr", "vi", "vr")] + \
    [f"c3d-samples/sample_02/{k}.c3d" for k in ("dec_int", "dec_real", "pc_int", "pc_real")] + \
    [f"c3d-samples/sample_08/{k}.c3d" for k in ("EB015PI", "TESTAPI", "TESTBPI", "TESTCPI",
                                                 "TESTDPI")] + \
    ["c3d-samples/sample_16/basketball.c3d", "c3d-samples/sample_33/bigparlove.c3d",
     "vicon-nexus/markers.c3d"]
# Files ezc3d cannot give us the points of: checked against the brute-force decoder.
OTHER_FILES = [f"c3d-samples/sample_01/Eb015{k}.c3d" for k in ("si", "sr")] + \
    [f"c3d-samples/sample_02/{k}.c3d" for k in ("sgi_int", "sgi_real")] + \
    ["c3d-samples/sample_06/MACsample.c3d", "c3d-samples/sample_13/Dance.c3d",
     "c3d-samples/sample_18/bad_parameter_section.c3d",
     "c3d-samples/sample_20/phasespace_sample.c3d", "captures/facial-sing.c3d"]


def _quiet_read(path) -> Take:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return read_c3d(path)


def brute_force_points(path):
    """Independent oracle: header-driven decoding, one struct.unpack per value.

    Returns positions (n_frames, n_points, 3) in file units with NaN where the
    residual is negative. DEC floats are decoded by swapping words and dividing
    by 4 (not the bit-level method of the reader).
    """
    buf = path.read_bytes()
    proc = buf[(buf[0] - 1) * 512 + 3]
    end = ">" if proc == 86 else "<"

    def f32(raw):
        if proc == 85:
            return struct.unpack("<f", raw[2:4] + raw[0:2])[0] / 4
        return struct.unpack(end + "f", raw)[0]

    n_points, analog_words, first, last = struct.unpack(end + "4H", buf[2:10])
    scale = f32(buf[12:16])
    offset = (struct.unpack(end + "H", buf[16:18])[0] - 1) * 512
    size = 4 if scale < 0 else 2
    frame = (4 * n_points + analog_words) * size
    n_frames = min(last - first + 1, (len(buf) - offset) // frame)
    out = np.full((n_frames, n_points, 3), np.nan)
    for t in range(n_frames):
        for m in range(n_points):
            at = offset + t * frame + m * 4 * size
            if scale < 0:
                x, y, z, r = (f32(buf[at + 4 * i:at + 4 * i + 4]) for i in range(4))
            else:
                x, y, z, r = (v * abs(scale) if i < 3 else v for i, v in
                              enumerate(struct.unpack(end + "4h", buf[at:at + 8])))
            if r >= 0:
                out[t, m] = x, y, z
    return out


# -- every file ---------------------------------------------------------------
def test_reads_every_corpus_file(shared_data):
    files = sorted((shared_data / "c3d-samples").rglob("*.c3d")) + \
        [shared_data / "captures/facial-sing.c3d", shared_data / "vicon-nexus/markers.c3d"]
    assert len(files) >= 24
    for path in files:
        take = _quiet_read(path)
        assert take.n_frames > 0 and take.n_markers > 0, path
        assert take.source.format == "c3d" and take.source.path == str(path)
        assert take.source.byte_order in BYTE_ORDERS
        assert take.source.storage in ("float", "integer")
        assert len(set(take.labels)) == take.n_markers


@pytest.mark.parametrize("name", EZC3D_FILES)
def test_agrees_with_ezc3d(shared_data, name):
    path = shared_data / name
    take = _quiet_read(path)
    ez = ezc3d.c3d(str(path))
    points = ez["data"]["points"][:3].transpose(2, 1, 0) * mm_per_unit(take.source.units)
    assert points.shape == take.positions.shape
    np.testing.assert_array_equal(np.isnan(points[:, :, 0]), take.missing)
    np.testing.assert_allclose(take.positions, points, atol=C3D_VS_EZC3D_MM, rtol=0)
    assert take.rate == pytest.approx(float(ez["parameters"]["POINT"]["RATE"]["value"][0]))
    assert take.first_frame == ez["header"]["points"]["first_frame"] + 1
    ez_labels = [s.strip() for s in ez["parameters"]["POINT"]["LABELS"]["value"]][:take.n_markers]
    same = [i for i, s in enumerate(ez_labels) if s and ez_labels.count(s) == 1]
    assert [take.labels[i] for i in same] == [ez_labels[i] for i in same]
    analogs = ez["data"]["analogs"][0].T
    if analogs.size:
        np.testing.assert_allclose(take.analog.values, analogs, rtol=FLOAT32_REL,
                                   atol=C3D_ANALOG_FLOOR)
    else:
        assert take.analog is None


@pytest.mark.parametrize("name", OTHER_FILES)
def test_agrees_with_brute_force_decoder(shared_data, name):
    path = shared_data / name
    take = _quiet_read(path)
    expected = brute_force_points(path) * mm_per_unit(take.source.units)
    np.testing.assert_array_equal(np.isnan(expected[:, :, 0]), take.missing)
    np.testing.assert_allclose(take.positions, expected, rtol=EXACT_FLOAT64, atol=0)


@pytest.mark.parametrize("encoding", ["pr", "si", "sr", "vi", "vr"])
def test_sample_01_encodings_decode_identically(shared_data, encoding):
    ref = read_c3d(shared_data / "c3d-samples/sample_01/Eb015pi.c3d")
    take = read_c3d(shared_data / f"c3d-samples/sample_01/Eb015{encoding}.c3d")
    assert take.labels == ref.labels and take.rate == ref.rate
    np.testing.assert_array_equal(take.missing, ref.missing)
    # integer files hold int16 x scale; float files the same numbers rounded to float32
    np.testing.assert_allclose(take.positions, ref.positions, rtol=FLOAT32_REL, atol=0)
    np.testing.assert_allclose(take.analog.values, ref.analog.values, rtol=0, atol=0)


@pytest.mark.parametrize("machine", ["pc", "dec", "sgi"])
def test_sample_02_integer_and_float_differ_by_one_scale_unit(shared_data, machine):
    folder = shared_data / "c3d-samples/sample_02"
    integer = read_c3d(folder / f"{machine}_int.c3d")
    real = read_c3d(folder / f"{machine}_real.c3d")
    scale = float(read_c3d_parameters(folder / f"{machine}_int.c3d")["POINT"]["SCALE"])
    assert (integer.source.storage, real.source.storage) == ("integer", "float")
    np.testing.assert_array_equal(integer.missing, real.missing)
    diff = np.abs(integer.positions - real.positions)[~integer.missing]
    assert diff.max() <= scale * (1 + FLOAT32_REL)


def test_facial_sing_facts(shared_data):
    take = read_c3d(shared_data / "captures/facial-sing.c3d")
    assert (take.n_markers, take.n_frames, take.rate) == (38, 3000, 100.0)
    assert (take.source.byte_order, take.source.storage, take.source.units) == \
        ("intel", "float", "mm")
    assert take.analog is None                      # no ANALOG group in this file
    face = [i for i, s in enumerate(take.labels) if s.startswith("section")]
    missing = take.missing[:, face]
    assert missing.sum() == 751 and np.count_nonzero(missing.any(axis=0)) == 6
    longest = 0
    for column in missing.T:                          # brute-force run lengths
        run = 0
        for gone in column:
            run = run + 1 if gone else 0
            longest = max(longest, run)
    assert longest == 192
    assert take.missing[:, take.index("Unlabeled1")].sum() == 2965
    assert not (take.positions == 0).all(axis=2).any()  # residual -1 with xyz 0 is NaN


def test_vicon_nexus_facts(vicon_nexus_take):
    take = vicon_nexus_take
    assert (take.n_markers, take.n_frames, int(take.missing.sum())) == (51, 580, 305)
    assert take.analog.values.shape == (580 * 20, 38) and take.analog.rate == 2000.0
    assert take.source.producer.startswith("Vicon Nexus")


def test_duplicate_labels_made_unique_with_warning_at_caller(shared_data):
    with pytest.warns(UserWarning) as record:
        take = read_c3d(shared_data / "c3d-samples/sample_06/MACsample.c3d")
    dup = [w for w in record if "duplicate point labels made unique" in str(w.message)]
    assert len(dup) == 1 and dup[0].filename == __file__
    assert "RTHI_2" in take.labels and len(set(take.labels)) == take.n_markers


def test_header_scale_wins_over_a_conflicting_point_scale(shared_data):
    # MACsample's POINT:SCALE (0.0215) disagrees with the header (0.0551); only the
    # header's gives an adult shoulder-to-hip distance (~0.4-0.6 m).
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        take = read_c3d(shared_data / "c3d-samples/sample_06/MACsample.c3d")
    assert any("differs from POINT:SCALE" in str(w.message) for w in record)
    trunk = np.linalg.norm(take.marker("RSHO") - take.marker("RHIP"), axis=1)
    assert 400 < np.nanmedian(trunk) < 600


def test_header_only_file_gets_fallback_labels(shared_data):
    with pytest.warns(UserWarning, match="no POINT:UNITS; assuming mm"):
        take = read_c3d(shared_data / "c3d-samples/sample_20/phasespace_sample.c3d")
    assert take.labels[:2] == ("point1", "point2") and take.n_markers == 40


# -- synthetic files through the writer ---------------------------------------
def _take(n_frames=30, n_markers=3, *, analog=True, first_frame=5, seed=0) -> Take:
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-900, 900, size=(n_frames, n_markers, 3))
    positions[3:7, -1] = np.nan
    positions[-1, 0] = np.nan
    channels = None
    if analog:
        values = rng.normal(size=(4 * n_frames, 2))
        channels = Analog(values, 400.0, ("mic", "emg"), ("V", "mV"))
    return Take([f"m{i}" for i in range(n_markers)], positions, 100.0,
                first_frame=first_frame, analog=channels)


def _f32(a):
    return a.astype(np.float32).astype(np.float64)


@pytest.mark.parametrize("n_markers", [3, 300])
def test_writer_output_read_back_by_ezc3d_and_us(tmp_path, n_markers):
    take = _take(n_markers=n_markers)
    path = tmp_path / "out.c3d"
    write_c3d(take, path)
    ez = ezc3d.c3d(str(path))
    points = ez["data"]["points"][:3].transpose(2, 1, 0)
    np.testing.assert_array_equal(points, _f32(take.positions))      # NaN where missing
    labels = list(ez["parameters"]["POINT"]["LABELS"]["value"])
    if n_markers > 255:
        labels += list(ez["parameters"]["POINT"]["LABELS2"]["value"])
    assert tuple(labels) == take.labels
    assert float(ez["parameters"]["POINT"]["RATE"]["value"][0]) == take.rate
    assert ez["header"]["points"]["first_frame"] + 1 == take.first_frame
    np.testing.assert_array_equal(ez["data"]["analogs"][0].T, _f32(take.analog.values))
    back = read_c3d(path)
    np.testing.assert_array_equal(back.positions, _f32(take.positions))
    assert (back.labels, back.rate, back.first_frame) == (take.labels, take.rate,
                                                          take.first_frame)
    assert back.analog.labels == take.analog.labels and back.analog.units == take.analog.units
    np.testing.assert_array_equal(back.analog.values, _f32(take.analog.values))
    assert (back.source.byte_order, back.source.storage) == ("intel", "float")


def test_writer_parts_make_the_bytes_of_one_piece(tmp_path, monkeypatch):
    """Frames encoded a part at a time on the worker threads (parts of a few frames here)
    hold what ezc3d reads, gaps across the parts' ends; an overflow in a late part leaves
    no file."""
    import mocap.io._c3d_write as c3d_write
    monkeypatch.setattr(c3d_write, "PART_BYTES", 700)
    take = _take(n_frames=203, n_markers=7)
    positions = take.positions.copy()
    positions[40:90, 2] = np.nan                    # a gap over several parts
    take = take.replace(positions=positions)
    assert len(c3d_write.encode_c3d(take)) > 50
    write_c3d(take, tmp_path / "out.c3d")
    ez = ezc3d.c3d(str(tmp_path / "out.c3d"))
    np.testing.assert_array_equal(ez["data"]["points"][:3].transpose(2, 1, 0),
                                  _f32(take.positions))
    np.testing.assert_array_equal(ez["data"]["analogs"][0].T, _f32(take.analog.values))
    positions[-1, 1, 1] = 1e39
    with pytest.raises(InputError, match="positions exceed the float32 range"):
        write_c3d(take.replace(positions=positions), tmp_path / "late.c3d")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.c3d"]


def test_writer_stores_missing_as_residual_minus_one_and_zeros(tmp_path):
    take = _take(analog=False)
    write_c3d(take, tmp_path / "out.c3d")
    raw = brute_force_points(tmp_path / "out.c3d")         # NaN from residual < 0 only
    np.testing.assert_array_equal(np.isnan(raw[:, :, 0]), take.missing)
    buf = (tmp_path / "out.c3d").read_bytes()
    offset = (struct.unpack("<H", buf[16:18])[0] - 1) * 512
    words = np.frombuffer(buf, "<f4", count=take.n_frames * take.n_markers * 4,
                          offset=offset).reshape(take.n_frames, take.n_markers, 4)
    assert (words[take.missing] == [0, 0, 0, -1]).all()


def test_long_take_frame_count_from_trial(tmp_path):
    take = _take(n_frames=70_000, n_markers=1, analog=False, first_frame=7)
    write_c3d(take, tmp_path / "long.c3d")
    back = read_c3d(tmp_path / "long.c3d")
    assert (back.n_frames, back.first_frame) == (70_000, 7)
    assert ezc3d.c3d(str(tmp_path / "long.c3d"))["data"]["points"].shape[2] == 70_000


def _patched(tmp_path, take, old: bytes, new: bytes):
    path = tmp_path / "in.c3d"
    write_c3d(take, path)
    buf = path.read_bytes()
    assert buf.count(old) == 1
    path.write_bytes(buf.replace(old, new))
    return path


@pytest.mark.parametrize("unit, factor", [("cm", 10.0), ("m ", 1000.0), ("mm", 1.0)])
def test_units_converted_to_mm(tmp_path, unit, factor):
    take = _take(analog=False)
    path = _patched(tmp_path, take, b"UNITS\x08\x00\xff\x01\x02mm", b"UNITS\x08\x00\xff\x01\x02"
                    + unit.encode())
    back = read_c3d(path)
    assert back.source.units == unit.strip()
    np.testing.assert_allclose(back.positions, _f32(take.positions) * factor, rtol=EXACT_FLOAT64)


def test_header_data_pointer_wrong_uses_point_data_start(tmp_path):
    take = _take()
    path = tmp_path / "in.c3d"
    write_c3d(take, path)
    buf = bytearray(path.read_bytes())
    buf[16:18] = struct.pack("<H", 60000)
    path.write_bytes(bytes(buf))
    with pytest.warns(UserWarning, match="using POINT:DATA_START"):
        back = read_c3d(path)
    np.testing.assert_array_equal(back.positions, _f32(take.positions))


def test_unknown_parameter_type_is_skipped(tmp_path):
    take = _take()
    path = _patched(tmp_path, take, b"GEN_SCALE\t\x00\x04\x00", b"GEN_SCALE\t\x00\x03\x00")
    with pytest.warns(UserWarning, match="unknown type 3; skipped"):
        back = read_c3d(path)
    np.testing.assert_array_equal(back.positions, _f32(take.positions))


def test_truncated_data_reads_complete_frames_with_warning(tmp_path):
    take = _take(analog=False)
    path = tmp_path / "in.c3d"
    write_c3d(take, path)
    buf = path.read_bytes()
    frame = take.n_markers * 16
    offset = (struct.unpack("<H", buf[16:18])[0] - 1) * 512
    path.write_bytes(buf[:offset + 10 * frame + 7])
    with pytest.warns(UserWarning, match="data section is truncated: 10 complete frames"):
        back = read_c3d(path)
    np.testing.assert_array_equal(back.positions, _f32(take.positions[:10]))


# -- errors -----------------------------------------------------------------------
def _corrupt(tmp_path, edit):
    path = tmp_path / "bad.c3d"
    write_c3d(_take(), path)
    buf = bytearray(path.read_bytes())
    path.write_bytes(bytes(edit(buf)))
    return path


def _set(buf, at, raw):
    buf[at:at + len(raw)] = raw
    return buf


def _set_point(buf, name, raw):
    """Overwrite the value of scalar parameter POINT:`name` as our writer lays it out."""
    key = bytes([len(name), 1]) + name.encode()
    return _set(buf, buf.index(key) + len(key) + 4, raw)


@pytest.mark.parametrize("edit, match, offset", [
    (lambda b: b"", "file is empty", 0),
    (lambda b: b[:100], "ends inside the 512-byte header", 100),
    (lambda b: _set(b, 1, b"\x51"), "not a C3D file: byte 1 is 81", 1),
    (lambda b: _set(b, 0, b"\xc8"), "bad parameter-section pointer", 0),
    (lambda b: _set(b, 0, b"\x01"), "bad parameter-section pointer", 0),
    (lambda b: _set(b, 515, b"\x57"), "unknown processor type 87", 515),
    (lambda b: _set_point(_set(b, 16, b"\x00\x00"), "DATA_START", b"\x00\x00"),
     "bad data-section pointer", 16),
    (lambda b: b[:(b[16] - 1) * 512 + 20], "holds no complete frame", None),
    (lambda b: _set(b, 2, bytes(4)), "frames hold no point and no analog value", 2),
    (lambda b: _set_point(_set(b, 12, struct.pack("<f", 0.0)), "SCALE", bytes(4)),
     "cannot tell float from integer", 12),
    (lambda b: _set_point(_set(b, 20, struct.pack("<f", -1.0)), "RATE", bytes(4)),
     "no frame rate", 20),
    (lambda b: b.replace(b"\xff\x01\x02mm", b"\xff\x01\x02kg"), "not a length unit", None),
])
def test_corrupt_files_raise_with_offset(tmp_path, edit, match, offset):
    path = _corrupt(tmp_path, edit)
    with pytest.raises(FileFormatError, match=match) as info:
        read_c3d(path)
    assert info.value.path == str(path)
    if offset is not None:
        assert info.value.offset == offset
    elif match == "holds no complete frame":
        assert info.value.offset == path.stat().st_size


def test_unreadable_path(tmp_path):
    with pytest.raises(FileFormatError, match="cannot read C3D file: no such file"):
        read_c3d(tmp_path / "absent.c3d")
    with pytest.raises(InputError, match="path must be a str or os.PathLike"):
        read_c3d(3)


@pytest.mark.parametrize("take, match", [
    (Take(("a",), np.zeros((0, 1, 3)), 100.0), "no frames"),
    (Take(("a",), np.zeros((2, 1, 3)), 100.0, first_frame=-1), "first_frame must be >= 0"),
    (Take(("a" * 300,), np.zeros((2, 1, 3)), 100.0), "longer than 255 bytes"),
    (Take(("a",), np.zeros((2, 1, 3)), 100.0,
          analog=Analog(np.zeros((5, 1)), 250.0, ("x",), ("V",))), "whole number of samples"),
    *((Take(("a", "b"), np.array([[[0.0, big, 0.0], [np.nan] * 3], [[0.0] * 3] * 2]), 100.0),
       "positions exceed the float32 range") for big in (1e39, -1e39)),
])
def test_writer_rejects_what_c3d_cannot_hold(tmp_path, take, match):
    with pytest.raises(InputError, match=match):
        write_c3d(take, tmp_path / "out.c3d")
    assert not list(tmp_path.iterdir())                   # nothing left behind


def test_writer_never_overwrites_an_input(tmp_path):
    path = tmp_path / "in.c3d"
    write_c3d(_take(), path)
    before = path.read_bytes()
    with pytest.raises(InputError, match="refusing to overwrite an input"):
        write_c3d(_take(seed=1), path, inputs=[path])
    assert path.read_bytes() == before
    with pytest.raises(InputError, match="take must be a mocap.Take"):
        write_c3d("not a take", tmp_path / "x.c3d")


def test_read_c3d_parameters(shared_data):
    params = read_c3d_parameters(shared_data / "c3d-samples/sample_33/bigparlove.c3d")
    assert params["MANUFACTURER"]["COMPANY"] == "Vicon"
    assert int(params["POINT"]["DATA_START"]) == 188
    ez = ezc3d.c3d(str(shared_data / "c3d-samples/sample_33/bigparlove.c3d"))
    assert list(params["POINT"]["LABELS"]) == list(ez["parameters"]["POINT"]["LABELS"]["value"])


# -- files of any size: chunks, saturated counts, many labels -----------------------
@pytest.fixture(params=[1, 4099], ids=["one-frame-chunks", "odd-chunks"])
def tiny_chunks(request, monkeypatch):
    """Decode `param` bytes of frames at a time (at least one frame): runs of missing
    samples and analog blocks then cross many chunk boundaries."""
    monkeypatch.setattr("mocap.io._c3d_data.CHUNK_BYTES", request.param)


@pytest.mark.parametrize("unit", ["mm", "m "])
def test_a_coordinate_not_finite_makes_its_sample_missing(tmp_path, tiny_chunks, unit):
    """Coordinate words NaN or infinite under a residual that says valid, residuals
    negative, -0.0 or NaN, coordinates near float32's largest (whose sums must not be
    taken for non-finite ones): every sample against the rule, a residual below 0 or a
    coordinate not finite."""
    take = _take(n_frames=40, n_markers=5, analog=False)
    path = _patched(tmp_path, take, b"UNITS\x08\x00\xff\x01\x02mm",
                    b"UNITS\x08\x00\xff\x01\x02" + unit.encode())
    buf = bytearray(path.read_bytes())
    offset = (struct.unpack("<H", buf[16:18])[0] - 1) * 512
    shape = (take.n_frames, take.n_markers, 4)
    words = np.frombuffer(buf, "<f4", count=math.prod(shape), offset=offset).reshape(shape)
    words = words.copy()
    rng = np.random.default_rng(3)
    pick = rng.random(shape) < 0.15
    words[pick] = rng.choice(np.array([np.nan, np.inf, -np.inf, 3.4e38, -3.4e38, -0.0],
                                      dtype=np.float32), size=pick.sum())
    buf[offset:offset + words.nbytes] = words.tobytes()
    path.write_bytes(bytes(buf))
    back = _quiet_read(path)
    with np.errstate(invalid="ignore"):
        missing = (words[:, :, 3] < 0) | ~np.isfinite(words[:, :, :3]).all(axis=2)
    assert 0 < missing.sum() < missing.size
    np.testing.assert_array_equal(back.missing, missing)
    # the take trusts the decoder's samples: NaN in all three coordinates or finite
    assert np.isnan(back.positions[missing]).all()
    assert np.isfinite(back.positions[~missing]).all()
    np.testing.assert_array_equal(back.positions[~missing],
                                  words[:, :, :3][~missing].astype(float)
                                  * mm_per_unit(unit.strip()))


@pytest.mark.parametrize("name", ["c3d-samples/sample_01/Eb015pi.c3d",
                                  "c3d-samples/sample_02/dec_real.c3d",
                                  "vicon-nexus/markers.c3d"])
def test_chunked_reading_agrees_with_ezc3d(shared_data, name, tiny_chunks):
    path = shared_data / name
    take = _quiet_read(path)
    ez = ezc3d.c3d(str(path))
    points = ez["data"]["points"][:3].transpose(2, 1, 0) * mm_per_unit(take.source.units)
    np.testing.assert_array_equal(np.isnan(points[:, :, 0]), take.missing)
    np.testing.assert_allclose(take.positions, points, atol=C3D_VS_EZC3D_MM, rtol=0)
    analogs = ez["data"]["analogs"][0].T
    if analogs.size:
        np.testing.assert_allclose(take.analog.values, analogs, rtol=FLOAT32_REL,
                                   atol=C3D_ANALOG_FLOOR)


@pytest.mark.parametrize("name", ["c3d-samples/sample_02/dec_real.c3d",
                                  "c3d-samples/sample_16/basketball.c3d",
                                  "captures/facial-sing.c3d", "vicon-nexus/markers.c3d"])
def test_chunks_decoded_on_two_threads_give_what_one_thread_gives(shared_data, name,
                                                                 tiny_chunks):
    """The chunks shared among two worker threads (each writing its rows, each releasing
    its pages, a page another still reads among them): the same take, bit for bit."""
    path = shared_data / name
    takes = []
    for threads in (1, 2):
        with threadpoolctl.threadpool_limits(threads, user_api="blas"):
            assert worker_threads() == threads
            takes.append(_quiet_read(path))
    one, two = takes
    np.testing.assert_array_equal(two.positions, one.positions)
    np.testing.assert_array_equal(two.missing, one.missing)
    if one.analog is not None:
        np.testing.assert_array_equal(two.analog.values, one.analog.values)


def test_summary_streams_the_gaps_of_every_corpus_file(shared_data, tiny_chunks):
    from mocap.gaps import find_gaps
    from mocap.io.c3d import summarize_c3d
    for path in [shared_data / n for n in EZC3D_FILES + OTHER_FILES]:
        take = _quiet_read(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            summary = summarize_c3d(path)
        assert (summary.labels, summary.n_frames, summary.first_frame, summary.rate) == \
            (take.labels, take.n_frames, take.first_frame, take.rate), path
        np.testing.assert_array_equal(summary.missing, take.missing.sum(axis=0))
        np.testing.assert_array_equal(summary.longest_gap,
                                      find_gaps(take.missing).longest(take.n_markers))


def test_summary_of_facial_sing_matches_its_published_facts(shared_data):
    from mocap.io.c3d import summarize_c3d
    summary = summarize_c3d(shared_data / "captures/facial-sing.c3d")
    face = [i for i, s in enumerate(summary.labels) if s.startswith("section")]
    assert int(summary.missing[face].sum()) == 751 and int(summary.longest_gap.max()) >= 192
    assert int(summary.longest_gap[face].max()) == 192
    assert (summary.missing[face] > 0).sum() == 6


def test_summary_does_not_load_the_data(tmp_path):
    import tracemalloc

    from mocap.io._c3d_data import CHUNK_BYTES
    from mocap.io.c3d import summarize_c3d
    n_frames, n_markers = 300_000, 20
    positions = np.zeros((n_frames, n_markers, 3))
    positions[1000:1500, 3] = np.nan
    write_c3d(Take([f"m{i}" for i in range(n_markers)], positions, 100.0), tmp_path / "big.c3d")
    positions_bytes = positions.nbytes
    del positions
    tracemalloc.start()
    summary = summarize_c3d(tmp_path / "big.c3d")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert summary.n_frames == n_frames and summary.longest_gap[3] == 500
    assert positions_bytes > 30 * CHUNK_BYTES
    assert peak < 8 * CHUNK_BYTES           # a few chunks, whatever the size of the file


def _without_trial(path):
    """Rename the TRIAL group (to TRIAX) so that only the 16-bit counts remain."""
    buf = bytearray(path.read_bytes())
    at = buf.index(b"TRIAL", 512)
    buf[at:at + 5] = b"TRIAX"
    path.write_bytes(bytes(buf))


def test_frame_count_saturated_at_65535_is_read_from_the_data_size(tmp_path):
    take = _take(n_frames=70_000, n_markers=2, analog=False, first_frame=1)
    path = tmp_path / "vicon-long.c3d"
    write_c3d(take, path)
    _without_trial(path)
    assert read_c3d_parameters(path)["POINT"]["FRAMES"] == -1          # 65535 as int16
    with pytest.warns(UserWarning, match=r"frame count is saturated at 65535 .*reading the "
                                         r"70000 frames the data section holds"):
        back = read_c3d(path)
    assert back.n_frames == 70_000
    np.testing.assert_array_equal(back.positions, _f32(take.positions))


def test_labels_with_colons_past_255_agree_with_ezc3d(tmp_path):
    take = _take(n_markers=300, analog=False)
    labels = [f"Subject:{s}" for s in take.labels[:-1]] + ["Rig:Head:Top"]
    path = tmp_path / "labels.c3d"
    write_c3d(take.replace(labels=tuple(labels)), path)
    ez = ezc3d.c3d(str(path))["parameters"]["POINT"]
    assert list(ez["LABELS"]["value"]) + list(ez["LABELS2"]["value"]) == labels
    assert read_c3d(path).labels == tuple(labels)
