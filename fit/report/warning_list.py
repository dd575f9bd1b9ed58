"""The report's list of warnings: what the run of a take warned about, in a section of its own.

Binding distances, unconverged frames, what gap filling did and left, markers
outside the marker set: the lines ``mocap2mesh run`` prints on stderr, kept
with the take's page so that they travel with it.
"""

from __future__ import annotations

import html

__all__ = ["warnings_section"]


def warnings_section(messages) -> str:
    """The HTML of the section: a heading and one list item per message (escaped).

    Parameters
    ----------
    messages : sequence of str

    Returns
    -------
    str
        ``<h2>Warnings</h2>`` and a ``<ul id="warnings">`` (or a line saying
        there were none).

    Examples
    --------
    >>> warnings_section(["marker 'a' is 4.0 mm off the skin"])
    '<h2>Warnings</h2><ul id="warnings"><li>marker &#x27;a&#x27; is 4.0 mm off the skin</li></ul>'
    >>> warnings_section([])
    '<h2>Warnings</h2><p id="warnings">None.</p>'
    """
    messages = [str(m) for m in messages]
    if not messages:
        return '<h2>Warnings</h2><p id="warnings">None.</p>'
    items = "".join(f"<li>{html.escape(m)}</li>" for m in messages)
    return f'<h2>Warnings</h2><ul id="warnings">{items}</ul>'
