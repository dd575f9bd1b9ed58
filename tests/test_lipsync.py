"""Talking faces: Praat prosody, PocketSphinx phones, visemes, the lip region, the video.

Oracles: the level of a sine in dB SPL and its fundamental (Praat), the model's own phone
set (every phone has a viseme), a loop over frames of Cohen & Massaro's dominance formula,
the lip gap measured on the ICT mesh, the blend formula evaluated per vertex, and the
shipped PocketSphinx alignments of the real recordings (made by the same family of
aligner: a reference, not an independent truth).
"""

from __future__ import annotations

import re
import sys

import numpy as np
import pygltflib
import pytest
import scipy.io.wavfile
from tolerances import (
    ALIGN_MEDIAN_S,
    EXACT_FLOAT64,
    LIP_CLOSED_MM,
    LIP_OPEN_MM,
    LOOP_ORACLE,
    PRAAT_PITCH_HZ,
    PRAAT_TONE_DB,
    RECOGNIZED_VISEME_AGREEMENT,
)

from basis.artist import ArtistBasis
from fit.cli.main import main
from fit.gestures.lipsync import lip_region, talking_face
from fit.gestures.phones import (
    PhoneSegments,
    phones_from_wav,
    read_phones_csv,
    read_sphinx_alignment,
    read_transcript,
    write_phones_csv,
)
from fit.gestures.prosody import praat_prosody, speech_prosody
from fit.gestures.talking import analyze_speech
from fit.gestures.viseme_basis import (
    ARKIT_VISEMES,
    load_viseme_basis,
    viseme_basis_from_shapes,
)
from fit.gestures.visemes import (
    DOMINANCE,
    PHONE_VISEMES,
    VISEMES,
    phone_visemes,
    viseme_curves,
)
from mocap.errors import FileFormatError, InputError, MissingDependencyError
from mocap.mesh.mesh import save_obj

RATE = 16000
#: ICT inner-lip midpoints (iBUG 62 upper, 66 lower): the lip gap.
UPPER_LIP, LOWER_LIP = 5533, 5517
RECORDINGS = ("0870", "0880", "0890", "0920", "0930")


def _lip_gap_mm(vertices):
    """Signed vertical gap of the ICT mouth's midpoints, mm (negative: pressed)."""
    return 10.0 * (vertices[..., UPPER_LIP, 1] - vertices[..., LOWER_LIP, 1])


def _recording(shared_data, key):
    stem = shared_data / "speech" / f"sense_and_sensibility_01_austen_64kb-{key}"
    return stem.with_suffix(".wav"), stem.with_suffix(".txt"), \
        stem.parent / f"{stem.name}.phone.json"


# ---------------------------------------------------------------- Praat, the extra

def test_praat_reads_a_sine_at_its_sound_pressure_level_and_pitch():
    t = np.arange(2 * RATE) / RATE
    amplitude, f0 = 0.3, 150.0
    harmonic = amplitude * (np.sin(2 * np.pi * f0 * t) + 0.5 * np.sin(4 * np.pi * f0 * t))
    p = praat_prosody(harmonic, RATE, frame_rate=30.0)
    assert p.n_frames == 60 and p.method == "praat"
    steady = slice(3, 57)
    level = 20 * np.log10(amplitude * np.sqrt((1 + 0.25) / 2) / 2e-5)
    np.testing.assert_allclose(p.intensity[steady], level, atol=PRAAT_TONE_DB)
    np.testing.assert_allclose(p.pitch[steady], f0, atol=PRAAT_PITCH_HZ)


def test_praat_finds_noise_unvoiced():
    noise = 0.1 * np.random.default_rng(0).standard_normal(RATE)
    assert np.isnan(praat_prosody(noise, RATE, frame_rate=30.0).pitch[3:-3]).mean() > 0.9


def test_praat_refuses_a_signal_shorter_than_its_window():
    with pytest.raises(InputError, match="shorter than Praat's intensity window"):
        praat_prosody(np.zeros(100), RATE, frame_rate=30.0)


@pytest.fixture
def without_speech_extra(monkeypatch):
    """The speech extra uninstalled: its modules cannot be imported."""
    for name in ("parselmouth", "pocketsphinx", "av"):
        monkeypatch.setitem(sys.modules, name, None)


def _tone_wav(path, seconds=1.0):
    t = np.arange(int(seconds * RATE)) / RATE
    scipy.io.wavfile.write(path, RATE, (0.3 * np.sin(2 * np.pi * 200 * t)).astype(np.float32))
    return path


def test_a_missing_extra_is_named(without_speech_extra):
    with pytest.raises(MissingDependencyError,
                       match=re.escape("needs praat-parselmouth, which is not installed: "
                                       "pip install 'mocap2mesh[speech]'")):
        praat_prosody(np.zeros(RATE), RATE, frame_rate=30.0)


def test_auto_falls_back_to_the_rms_level_without_the_extra(without_speech_extra, tmp_path):
    wav = _tone_wav(tmp_path / "tone.wav")
    with pytest.warns(UserWarning, match="S\\(t\\) is the RMS level"):
        p = speech_prosody(wav, frame_rate=30.0)
    assert p.method == "rms" and p.pitch is None
    np.testing.assert_allclose(p.intensity[3:-3], 20 * np.log10(0.3 / np.sqrt(2)),
                               atol=PRAAT_TONE_DB)


def test_the_cli_says_which_extra_is_missing_in_one_line(without_speech_extra, tmp_path,
                                                         capsys):
    wav = _tone_wav(tmp_path / "tone.wav")
    assert main(["gestures", "phones", str(wav), "-o", str(tmp_path / "p.csv")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'mocap2mesh[speech]'" in err, err
    assert not (tmp_path / "p.csv").exists()


def test_the_core_install_imports_none_of_the_extra():
    """In a fresh interpreter where the extra cannot be imported, the package and the
    command line still load."""
    import subprocess

    code = ("import sys\n"
            "for m in ('parselmouth', 'pocketsphinx', 'av'): sys.modules[m] = None\n"
            "import fit.gestures, fit.gestures.video, fit.gestures.page\n"
            "from fit.cli.main import full_parser\n"
            "full_parser()\n"
            "print('ok')\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.stdout.strip() == "ok", done.stderr


# ---------------------------------------------------------------- phones

def test_every_phone_of_the_model_has_a_viseme():
    """The oracle: the phone set in PocketSphinx's acoustic model definition (mdef)."""
    import pocketsphinx

    mdef = open(pocketsphinx.get_model_path("en-us/en-us/mdef"), "rb").read()
    start = mdef.index(b"+NSN+\x00")
    phones = mdef[start:mdef.index(b"\x00\x00", start)].decode().split("\x00")
    assert "ZH" in phones and "SIL" in phones and len(phones) == 42
    for phone in phones:
        assert set(phone_visemes(phone)) <= set(VISEMES)
    assert set(PHONE_VISEMES) == {p for p in phones if not p.startswith("+")}


@pytest.mark.parametrize("key", RECORDINGS)
def test_forced_alignment_agrees_with_the_shipped_alignment(shared_data, key):
    wav, txt, ref = _recording(shared_data, key)
    ours, theirs = phones_from_wav(wav, transcript=txt), read_sphinx_alignment(ref)
    words = [p for p in theirs.phone if p != "SIL"]
    assert [p for p in ours.phone if p != "SIL"] == words
    b = theirs.boundaries()
    dist = np.abs(b[:, None] - ours.boundaries()[None]).min(axis=1)
    assert np.median(dist) <= ALIGN_MEDIAN_S
    assert ours.start[0] == 0 and abs(ours.end[-1] - theirs.end[-1]) < 0.05


def test_recognition_without_a_transcript_finds_the_lip_shapes(shared_data):
    wav, _, ref = _recording(shared_data, "0890")
    ours, theirs = phones_from_wav(wav, recognizer="phones"), read_sphinx_alignment(ref)
    rate = 100.0
    n = int(theirs.end[-1] * rate)
    a, b = (viseme_curves(s, rate=rate, n_frames=n).weights.argmax(axis=1)
            for s in (ours, theirs))
    assert np.mean(a == b) > RECOGNIZED_VISEME_AGREEMENT
    assert "allphone" in ours.source


def test_a_transcript_word_the_dictionary_lacks_is_named(shared_data):
    wav, _, _ = _recording(shared_data, "0880")
    with pytest.raises(InputError, match=r"\['zxqvb'\] are not in PocketSphinx's pronouncing"):
        phones_from_wav(wav, transcript="he was zxqvb")


def test_transcripts_from_text_or_file(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("Had he married\na more amiable woman?\n", encoding="utf-8")
    assert read_transcript(path) == "had he married a more amiable woman"
    with pytest.raises(InputError, match="holds no words"):
        read_transcript("?!")


def test_phones_csv_round_trip(tmp_path):
    segs = PhoneSegments([0.0, 0.2, 0.31], [0.2, 0.31, 0.5], ["SIL", "AE", "N"],
                         [0.99, 0.5, 0.25], "test")
    write_phones_csv(tmp_path / "p.csv", segs)
    back = read_phones_csv(tmp_path / "p.csv")
    assert back.phone == segs.phone
    np.testing.assert_allclose(back.start, segs.start)
    np.testing.assert_allclose(back.end, segs.end)
    np.testing.assert_allclose(back.confidence, segs.confidence)


@pytest.mark.parametrize("text, match", [
    ("start,end,phone\n0,1,AA\n", r"columns .* \['confidence'\] are missing"),
    ("start,end,phone,confidence\n0,x,AA,1\n", "at line 2: expected start,end,phone"),
    ("start,end,phone,confidence\n0,1,AA,1\n0.5,2,M,1\n", "overlap or are out of order"),
    ("start,end,phone,confidence\n0,0,AA,1\n", "not after its start"),
    ("start,end,phone,confidence\n", "has no segments"),
])
def test_bad_phones_csv_is_named(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(FileFormatError, match=match):
        read_phones_csv(path)


def test_a_bad_alignment_json_is_named(tmp_path):
    path = tmp_path / "a.json"
    path.write_text('{"w": [{"t": "x"}]}', encoding="utf-8")
    with pytest.raises(FileFormatError, match="not a PocketSphinx alignment"):
        read_sphinx_alignment(path)


# ---------------------------------------------------------------- visemes

def _dominance_loop(segs, rate, n):
    """Cohen & Massaro's blend by a loop over frames and segments (no closure)."""
    out = np.zeros((n, len(VISEMES)))
    for k in range(n):
        t = k / rate
        for a, b, p in zip(segs.start, segs.end, segs.phone):
            classes = phone_visemes(p)
            cuts = np.linspace(a, b, len(classes) + 1)
            for j, c in enumerate(classes):
                alpha, theta = DOMINANCE[c]
                gap = max(cuts[j] - t, 0.0, t - cuts[j + 1])
                if gap <= 1.2:
                    out[k, VISEMES.index(c)] += alpha * np.exp(-theta * gap)
    return out / out.sum(axis=1, keepdims=True)


def test_viseme_weights_are_the_dominance_blend_with_closure():
    rng = np.random.default_rng(4)
    phones = rng.choice(sorted(PHONE_VISEMES), 60)
    edges = np.concatenate([[0.0], np.cumsum(rng.uniform(0.02, 0.2, 60))])
    segs = PhoneSegments(edges[:-1], edges[1:], phones, np.ones(60))
    d = viseme_curves(segs, rate=30.0)
    want = _dominance_loop(segs, 30.0, d.n_frames)
    free = ~d.closed
    np.testing.assert_allclose(d.weights[free], want[free], atol=LOOP_ORACLE)
    np.testing.assert_allclose(d.weights.sum(axis=1), 1.0, atol=EXACT_FLOAT64)
    assert (d.weights[d.closed, VISEMES.index("closed")] == 1).all()
    # every bilabial closes a frame: inside it, or the nearest frame to a short one
    for a, b, p in zip(segs.start, segs.end, segs.phone):
        if p in ("P", "B", "M"):
            assert d.closed[int(round((a + b) / 2 * 30.0))]


def test_a_diphthong_moves_from_its_first_to_its_second_viseme():
    segs = PhoneSegments([0.0], [0.6], ["AY"], [1.0])
    d = viseme_curves(segs, rate=100.0, n_frames=60)
    a, i = VISEMES.index("a"), VISEMES.index("i")
    assert d.weights[5, a] > 0.9 and d.weights[55, i] > 0.9


def test_unknown_phones_and_dominance_are_refused():
    with pytest.raises(InputError, match="unknown phone 'Q'"):
        phone_visemes("Q")
    segs = PhoneSegments([0.0], [0.5], ["AA"], [1.0])
    with pytest.raises(InputError, match="dominance: unknown viseme 'x'"):
        viseme_curves(segs, rate=30.0, dominance={"x": (1, 1)})
    with pytest.raises(InputError, match="alpha and theta must be positive"):
        viseme_curves(segs, rate=30.0, dominance={"a": (0, 1)})


# ---------------------------------------------------------------- the viseme basis, the blend

@pytest.fixture(scope="module")
def ict_visemes(ict_basis):
    return viseme_basis_from_shapes(ict_basis)


def test_ict_visemes_close_and_open_the_mouth(ict_basis, ict_visemes):
    vertices = ict_basis.neutral.vertices + ict_visemes.displacements
    gap = dict(zip(ict_visemes.names, _lip_gap_mm(vertices)))
    assert gap["closed"] < LIP_CLOSED_MM
    for vowel in ("a", "e", "o", "eo"):
        assert gap[vowel] > 3 * LIP_OPEN_MM
    assert gap["a"] > gap["e"] > gap["i"]


def test_live_link_names_give_the_same_visemes(ict_basis, ict_visemes):
    def live_link(name):
        name = re.sub(r"_L$", "Left", re.sub(r"_R$", "Right", name))
        return name[0].upper() + name[1:]

    renamed = ArtistBasis(tuple(live_link(n) for n in ict_basis.names), ict_basis.neutral,
                          ict_basis.displacements)
    np.testing.assert_array_equal(viseme_basis_from_shapes(renamed).displacements,
                                  ict_visemes.displacements)


def test_a_basis_without_the_recipe_shapes_is_refused(ict_basis):
    few = ArtistBasis(ict_basis.names[:5], ict_basis.neutral, ict_basis.displacements[:5])
    with pytest.raises(InputError, match="viseme 'a' needs the shape 'jawOpen'"):
        viseme_basis_from_shapes(few)
    with pytest.raises(InputError, match="missing \\['u'\\]"):
        viseme_basis_from_shapes(ict_basis, {k: v for k, v in ARKIT_VISEMES.items()
                                             if k != "u"})


def test_viseme_objs_load_as_sculpted(ict_basis, ict_visemes, tmp_path):
    for name, field in zip(ict_visemes.names[:-1], ict_visemes.displacements[:-1]):
        save_obj(ict_basis.neutral.with_vertices(ict_basis.neutral.vertices + field),
                 tmp_path / f"{name}.obj")
    loaded = load_viseme_basis(ict_basis.neutral, tmp_path)
    np.testing.assert_allclose(loaded.displacements, ict_visemes.displacements, atol=1e-5)
    (tmp_path / "u.obj").unlink()
    with pytest.raises(FileFormatError, match="missing \\['u'\\]"):
        load_viseme_basis(ict_basis.neutral, tmp_path)


def test_lips_from_visemes_rest_from_the_mrf(ict_basis, ict_visemes, ict_landmarks):
    region = lip_region(ict_visemes)
    assert region[UPPER_LIP] == 1 and region[LOWER_LIP] == 1
    assert region[ict_landmarks["brow_inner_left"]] == 0
    assert 0 <= region.min() and region.max() <= 1 and ((region > 0) & (region < 1)).any()
    rng = np.random.default_rng(1)
    c = rng.uniform(0, 0.5, (7, ict_basis.n_shapes))
    segs = PhoneSegments([0.0, 0.1], [0.1, 0.25], ["M", "AA"], [1.0, 1.0])
    curves = viseme_curves(segs, rate=30.0, n_frames=7)
    face = talking_face(ict_basis, c, ict_visemes, curves)
    got = face.vertices(ict_basis.neutral.vertices)
    mrf = np.einsum("ti,ivc->tvc", c, ict_basis.displacements)
    lips = np.einsum("tl,lvc->tvc", curves.weights, ict_visemes.displacements)
    want = ict_basis.neutral.vertices + (1 - region)[:, None] * mrf + region[:, None] * lips
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert (_lip_gap_mm(got[curves.closed]) < LIP_CLOSED_MM).all()    # the MRF opens no /m/


# ---------------------------------------------------------------- the command, the video

def test_synthesize_a_talking_face_with_its_video(shared_data, ict_neutral_path,
                                                  ict_expressions_dir, arkit_performance_path,
                                                  tmp_path):
    import av

    from fit.exports import read_mesh_sequence

    wav, txt, _ = _recording(shared_data, "0880")
    out = tmp_path / "out"
    out.mkdir()
    with pytest.warns(UserWarning, match="match no shape"):     # ARKit's TongueOut
        assert main(["gestures", "synthesize", str(wav), "--palette",
                     str(arkit_performance_path), "-o", str(out), "--mesh",
                     str(ict_neutral_path), "--shapes", str(ict_expressions_dir), "--units",
                     "cm", "--transcript", str(txt), "--video", "--video-size", "96", "96"]) == 0
    for name in ("weights.csv", "prosody.csv", "phones.csv", "visemes.csv", "mesh.npz",
                 "gestures.glb", "talking.webm", "speech.png", "index.html"):
        assert (out / name).is_file(), name
    phones = read_phones_csv(out / "phones.csv")
    seq = read_mesh_sequence(out / "mesh.npz")
    assert "viseme:closed" in seq.names
    gap = _lip_gap_mm(seq.vertices())
    times = np.arange(seq.n_frames) / 30.0
    inside = phones.at(times)
    bilabial = np.isin(np.array(phones.phone + ("",))[inside], ["P", "B", "M"])
    assert bilabial.any() and (gap[bilabial] < LIP_CLOSED_MM).all()
    with av.open(str(out / "talking.webm")) as video:
        streams = {s.type: s.codec_context.name for s in video.streams}
        frames = sum(1 for _ in video.decode(video.streams.video[0]))
    with av.open(str(out / "talking.webm")) as video:
        samples = sum(f.samples for f in video.decode(video.streams.audio[0]))
    assert streams == {"video": "vp9", "audio": "opus"}
    assert frames == seq.n_frames
    rate, pcm = scipy.io.wavfile.read(wav)
    assert abs(samples / 48000 - len(pcm) / rate) < 0.03
    gltf = pygltflib.GLTF2().load(str(out / "gestures.glb"))
    targets = gltf.meshes[0].extras["targetNames"]
    assert "viseme:closed" in targets and targets == list(seq.names)
    page = (out / "index.html").read_text(encoding="utf-8")
    assert "<video" in page and "talking.webm" in page


def test_phones_command_writes_the_segments(shared_data, tmp_path):
    wav, txt, _ = _recording(shared_data, "0930")
    assert main(["gestures", "phones", str(wav), "--transcript", str(txt), "-o",
                 str(tmp_path / "p.csv")]) == 0
    segs = read_phones_csv(tmp_path / "p.csv")
    assert "M" in segs.phone and segs.phone[0] == "SIL"


def test_analyze_speech_refuses_contradictions(tmp_path):
    wav = _tone_wav(tmp_path / "tone.wav")
    with pytest.raises(InputError, match="drop them or the no-lips option"):
        analyze_speech(wav, rate=30.0, lips=False, transcript="a")
    with pytest.raises(InputError, match="not both"):
        analyze_speech(wav, rate=30.0, transcript="a", phones=tmp_path / "p.csv")


def test_lips_from_a_phones_csv_need_no_extra(without_speech_extra, shared_data,
                                              arkit_performance_path, tmp_path):
    """The core install lip-syncs from given phone segments (the RMS level as S(t))."""
    import pandas as pd

    wav, _, ref = _recording(shared_data, "0930")
    phones = tmp_path / "p.csv"
    write_phones_csv(phones, read_sphinx_alignment(ref))
    out = tmp_path / "out"
    out.mkdir()
    with pytest.warns(UserWarning, match="praat-parselmouth is not installed"):
        assert main(["gestures", "synthesize", str(wav), "--palette",
                     str(arkit_performance_path), "-o", str(out), "--phones",
                     str(phones)]) == 0
    table = pd.read_csv(out / "visemes.csv")
    want = viseme_curves(read_phones_csv(phones), rate=30.0, n_frames=len(table))
    np.testing.assert_allclose(table[list(VISEMES)].to_numpy(), want.weights, atol=1e-5)
    assert pd.read_csv(out / "prosody.csv")["pitch_hz"].isna().all()
