"""Speech intensity S(t): tone bursts against the analytic RMS, WAV encodings, analog channels."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io.wavfile
from tolerances import SPEECH_EXACT_DB, SPEECH_TONE_DB, WAV_DB, WAV_UINT8_DB

from fit.gestures.speech import (
    FLOOR_DB,
    analog_intensity,
    opening_intensity,
    read_wav,
    speech_intensity,
    wav_intensity,
)
from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.take import Analog, Take

RATE, FPS, WINDOW = 16000, 30.0, 0.05
AMPLITUDE, FREQ, ONSET, OFFSET = 0.5, 440.0, 0.51, 1.49


def _burst(n_seconds=2.0):
    t = np.arange(int(n_seconds * RATE)) / RATE
    on = (t >= ONSET) & (t < OFFSET)
    return np.where(on, AMPLITUDE * np.sin(2 * np.pi * FREQ * t), 0.0)


def _loop_oracle(x, n_frames):
    """RMS dB per frame by an explicit loop over frames (independent of the cumsum)."""
    out = []
    for k in range(n_frames):
        t = k / FPS
        a = int(np.clip(np.round((t - WINDOW / 2) * RATE), 0, len(x)))
        b = int(np.clip(np.round((t + WINDOW / 2) * RATE), 0, len(x)))
        power = np.mean(x[a:b] ** 2) if b > a else 0.0
        out.append(10 * np.log10(max(power, 10 ** (FLOOR_DB / 10))))
    return np.array(out)


def test_tone_burst_level_matches_the_analytic_rms():
    s = speech_intensity(_burst(), RATE, frame_rate=FPS, window=WINDOW)
    assert len(s) == 60
    times = np.arange(len(s)) / FPS
    inside = (times - WINDOW / 2 >= ONSET) & (times + WINDOW / 2 <= OFFSET)
    outside = (times + WINDOW / 2 < ONSET) | (times - WINDOW / 2 > OFFSET)
    expected = 20 * np.log10(AMPLITUDE / np.sqrt(2))
    np.testing.assert_allclose(s[inside], expected, atol=SPEECH_TONE_DB)
    np.testing.assert_array_equal(s[outside], FLOOR_DB)


def test_tone_burst_onset_is_the_first_frame_at_or_after_it():
    s = speech_intensity(_burst(), RATE, frame_rate=FPS, window=WINDOW)
    half_power = 20 * np.log10(AMPLITUDE / np.sqrt(2)) - 10 * np.log10(2)
    assert int(np.argmax(s > half_power)) == int(np.ceil(ONSET * FPS))


def test_intensity_matches_a_loop_over_frames():
    rng = np.random.default_rng(3)
    x = _burst() * (1 + 0.3 * rng.standard_normal(2 * RATE))
    np.testing.assert_allclose(speech_intensity(x, RATE, frame_rate=FPS, window=WINDOW,
                                                n_frames=70),
                               _loop_oracle(x, 70), atol=SPEECH_EXACT_DB)


@pytest.mark.parametrize("dtype", ["int16", "int32", "float32", "uint8"])
def test_wav_encodings_and_stereo_give_the_same_intensity(tmp_path, dtype):
    x = _burst()
    scale = {"int16": 2 ** 15, "int32": 2 ** 31, "float32": 1.0, "uint8": 128}[dtype]
    data = np.round(x * (scale - 1)) if dtype != "float32" else x
    if dtype == "uint8":
        data = data + 128
    stereo = np.stack([data, data], axis=1).astype(dtype)
    path = tmp_path / "speech.wav"
    scipy.io.wavfile.write(path, RATE, stereo)
    samples, rate = read_wav(path)
    assert rate == RATE and samples.shape == x.shape
    got = wav_intensity(path, frame_rate=FPS, window=WINDOW)
    want = speech_intensity(x, RATE, frame_rate=FPS, window=WINDOW)
    loud = want > -20
    tol = WAV_UINT8_DB if dtype == "uint8" else WAV_DB
    np.testing.assert_allclose(got[loud], want[loud], atol=tol)


def test_analog_channel_is_sampled_at_the_take_frames():
    x = _burst()
    analog = Analog(np.stack([np.zeros_like(x), x], axis=1), RATE, ("emg", "mic"), ("V", "V"))
    take = Take(("a",), np.zeros((60, 1, 3)), rate=FPS, analog=analog)
    np.testing.assert_allclose(analog_intensity(take, "mic", window=WINDOW),
                               speech_intensity(x, RATE, frame_rate=FPS, window=WINDOW,
                                                n_frames=60))


def test_missing_wav_names_the_file(tmp_path):
    with pytest.raises(FileFormatError, match=r"nope\.wav: no such file"):
        read_wav(tmp_path / "nope.wav")


def test_not_a_wav_is_a_format_error(tmp_path):
    path = tmp_path / "bad.wav"
    path.write_bytes(b"hello, not RIFF")
    with pytest.raises(FileFormatError, match="cannot read WAV"):
        read_wav(path)


def test_take_without_analog_is_rejected():
    take = Take(("a",), np.zeros((3, 1, 3)), rate=FPS)
    with pytest.raises(InputError, match="no analog channels"):
        analog_intensity(take, "mic")


def test_empty_signal_is_rejected():
    with pytest.raises(InputError, match="n_samples > 0"):
        speech_intensity(np.zeros(0), RATE, frame_rate=FPS)


def _mouth_take(open_mm=6.0, hidden=()):
    """Lip markers 20 mm apart, opened by `open_mm` during frames 30-89 of 120 at 30 Hz."""
    n = 120
    pos = np.zeros((n, 3, 3))
    pos[:, 0] = [0.0, 0.0, 20.0]
    pos[30:90, 1, 2] = -open_mm
    pos[:, 2] = [50.0, 0.0, 0.0]
    pos[list(hidden), 1] = np.nan
    return Take(("upper", "lower", "ear"), pos, rate=FPS)


def test_mouth_opening_reads_as_the_loudness_of_a_constant_opening():
    s = opening_intensity(_mouth_take(6.0), "upper", "lower", window=0.2)
    half = int(np.round(0.1 * FPS))
    np.testing.assert_allclose(s[30 + half:90 - half], 20 * np.log10(6.0), atol=SPEECH_EXACT_DB)
    np.testing.assert_array_equal(s[:30 - half], FLOOR_DB)
    np.testing.assert_array_equal(s[90 + half:], FLOOR_DB)


def test_missing_lip_frames_count_as_closed():
    hidden = range(50, 70)
    s = opening_intensity(_mouth_take(6.0, hidden), "upper", "lower", window=1.5 / FPS)
    np.testing.assert_array_equal(s[51:70], FLOOR_DB)     # frames k-1 and k both hidden
    np.testing.assert_allclose(s[[40, 80]], 20 * np.log10(6.0), atol=SPEECH_EXACT_DB)


def test_mouth_opening_names_a_missing_marker():
    with pytest.raises(MarkerError, match="'chin'"):
        opening_intensity(_mouth_take(), "upper", "chin")


def test_lips_never_seen_together_are_rejected():
    with pytest.raises(InputError, match="never visible together"):
        opening_intensity(_mouth_take(hidden=range(120)), "upper", "lower")
