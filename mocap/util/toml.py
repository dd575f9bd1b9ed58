"""Reading the project's small TOML files (marker sets, layouts, landmarks, configs)."""

from __future__ import annotations

import sys
from collections.abc import Mapping

from mocap.errors import FileFormatError
from mocap.util.files import read_input_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["read_toml", "check_open_questions"]


def read_toml(path, what: str) -> dict:
    """Parse a TOML file; errors name the file and say what it should have been.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file holds ("marker set", "layout", ...), for the error message.

    Raises
    ------
    FileFormatError
        The file cannot be read (see :func:`mocap.util.files.read_input_bytes`),
        is not UTF-8, is not valid TOML, or nests arrays or tables too deeply
        to parse.
    """
    text = read_input_text(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(path, f"{what} is not valid TOML: {exc}") from None
    except RecursionError:
        raise FileFormatError(path, f"{what} nests arrays or tables too deeply to "
                                    "parse") from None


def check_open_questions(doc: Mapping, path, what: str) -> None:
    """Refuse a file whose ``[open_questions]`` table still holds a question.

    Parameters
    ----------
    doc : mapping
        The parsed TOML document.
    path : str or os.PathLike
        The file, for the message.
    what : str
        What the file is ("marker set", "run configuration", ...).

    Raises
    ------
    FileFormatError
        ``[open_questions]`` is not a table of strings, or is not empty: the
        message names the first question and quotes it.

    Examples
    --------
    >>> check_open_questions({"open_questions": {}}, "ms.toml", "marker set")
    """
    questions = doc.get("open_questions", {})
    if not isinstance(questions, Mapping) or not all(isinstance(v, str)
                                                     for v in questions.values()):
        raise FileFormatError(path, "[open_questions] must be a table of name = \"question\"")
    if questions:
        name, text = next(iter(questions.items()))
        more = f" (and {len(questions) - 1} more)" if len(questions) > 1 else ""
        raise FileFormatError(path, f"open question {name!r} of this {what} is not answered"
                                    f"{more}: {text} -- answer it in the file, then delete its "
                                    "line from [open_questions]")
