"""The page of a gestures synthesis: the talking video, the speech analysis, the outputs.

``index.html`` in the output directory of ``mocap2mesh gestures synthesize
--video``: the video with its sound, a figure of the driving speech (Praat's
intensity and pitch, the phone segments, the viseme weights on one time axis)
and the files written, with what made them.
"""

from __future__ import annotations

import html
from pathlib import Path

from fit.gestures.talking import SpeechAnalysis
from mocap.errors import InputError
from mocap.util.atomic import atomic_path
from mocap.viz.figures import distinct_colours, new_figure, save_figure

__all__ = ["write_speech_figure", "write_synthesis_page"]


def write_speech_figure(path, speech: SpeechAnalysis) -> None:
    """PNG of S̃(t), F0(t), the phone segments and d̃_l(t) against time."""
    if not isinstance(speech, SpeechAnalysis):
        raise InputError(f"speech must be a SpeechAnalysis, got {type(speech).__name__}")
    p = speech.prosody
    t = [k / p.rate for k in range(p.n_frames)]
    rows = 3 if speech.visemes is not None else 1
    fig = new_figure(11, 2.2 * rows + 0.6)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)
    ax = axes[0, 0]
    ax.plot(t, p.intensity, color="0.2", lw=1)
    ax.set_ylabel("intensity, dB")
    ax.set_title(p.source)
    if p.pitch is not None:
        twin = ax.twinx()
        twin.plot(t, p.pitch, color="tab:orange", lw=1.2)
        twin.set_ylabel("F0, Hz", color="tab:orange")
    if speech.visemes is not None:
        seg = speech.phones
        ax = axes[1, 0]
        for k, (a, b, ph) in enumerate(zip(seg.start, seg.end, seg.phone)):
            ax.axvspan(a, b, color="0.85" if k % 2 else "0.7", lw=0)
            ax.text((a + b) / 2, 0.5, ph, ha="center", va="center", fontsize=6, rotation=90)
        ax.set_yticks([])
        ax.set_ylabel("phones")
        ax.set_title(seg.source, fontsize=9)
        ax = axes[2, 0]
        v = speech.visemes
        for j, (name, colour) in enumerate(zip(v.names, distinct_colours(len(v.names)))):
            ax.plot(t, v.weights[:, j], lw=1, label=name, color=colour)
        ax.set_ylabel("viseme weight")
        ax.legend(ncol=6, fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time, s")
    save_figure(fig, path, dpi=90)


def write_synthesis_page(directory, *, speech_name: str, summary: list, video: str | None,
                         figure: str | None, files: list, inputs=()) -> Path:
    """Write ``index.html`` of a synthesis into `directory`.

    Parameters
    ----------
    directory : path
    speech_name : str
        The driving WAV's name (the title).
    summary : list of str
        Sentences of what was done (speech analysis, MRF, lips).
    video, figure : str, optional
        File names in `directory` of the talking video and the speech figure.
    files : list of str
        The other outputs, linked.

    Returns
    -------
    Path
        The page.
    """
    directory = Path(directory)
    esc = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>gestures synthesis: "
             f"{esc(speech_name)}</title><style>body{{font-family:sans-serif;max-width:1000px;"
             "margin:2em auto}}video,img{{max-width:100%}}li{{margin:.2em 0}}</style></head>"
             f"<body><h1>Gestures synthesis: {esc(speech_name)}</h1>"]
    if video:
        parts.append(f"<video controls preload='metadata' src='{esc(video)}'></video>"
                     "<p>The synthesized face (Ju &amp; Lee 2008): lips from the visemes of "
                     "the speech's phones, the rest of the face from the Markov random field; "
                     "the speech is the sound track.</p>")
    parts.append("<ul>" + "".join(f"<li>{esc(s)}</li>" for s in summary) + "</ul>")
    if figure:
        parts.append(f"<h2>Driving speech</h2><img src='{esc(figure)}' alt='speech analysis'>")
    parts.append("<h2>Files</h2><ul>" + "".join(f"<li><a href='{esc(f)}'>{esc(f)}</a></li>"
                                              for f in files) + "</ul></body></html>")
    page = directory / "index.html"
    with atomic_path(page, inputs=inputs) as tmp:
        Path(tmp).write_text("".join(parts), encoding="utf-8")
    return page
