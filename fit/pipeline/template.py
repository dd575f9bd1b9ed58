"""A complete ``run.toml``: every key of every table, with its default and a one-line comment.

Generated from the configuration's own definitions, so that a key added to a
stage's options appears here without anyone editing a template: the tables
and their options classes (:data:`fit.pipeline.config.STAGE_TABLES`), each
field's default, the first sentence of its entry in the class's numpy-style
``Attributes`` section, the chain's own defaults
(:data:`fit.pipeline.config.CHAIN_DEFAULTS`) and the ``[inputs]``,
``[output]`` and ``[run]`` keys (:data:`fit.pipeline.config.INPUT_KEYS`,
``OUTPUT_KEYS``, ``RUN_KEYS``).
"""

from __future__ import annotations

import dataclasses
import math
import re

from fit.pipeline.config import CHAIN_DEFAULTS, INPUT_KEYS, OUTPUT_KEYS, RUN_KEYS, STAGE_TABLES
from mocap.errors import InputError

__all__ = ["field_docs", "toml_value", "run_config_text", "option_rows"]

_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")
_ENTRY = re.compile(r"^    (\w+(?:\s*,\s*\w+)*)\s*:(.*)$")
#: Longest comment kept whole, characters.
_LONGEST = 150


def field_docs(cls) -> dict:
    """Field name -> the first sentence of its entry in `cls`'s ``Attributes`` section.

    Parameters
    ----------
    cls : type
        A dataclass with a numpy-style docstring (``name : type`` lines, the
        description indented below; ``a, b : int`` documents both).

    Returns
    -------
    dict of str to str
        One line each (roles such as ``:func:`x``` reduced to ``x``); the type
        stands in for a description that is missing.

    Examples
    --------
    >>> from fit.pipeline.options import FitOptions
    >>> field_docs(FitOptions)["space"]
    'One of SPACES.'
    """
    doc = (cls.__doc__ or "").splitlines()
    try:
        start = next(i for i, line in enumerate(doc) if line.strip() == "Attributes") + 2
    except StopIteration:
        return {}
    entries, current = {}, None
    for line in doc[start:]:
        if line.strip() and not line.startswith("    "):
            break
        match = _ENTRY.match(line)
        if match:
            current = [n.strip() for n in match.group(1).split(",")]
            for name in current:
                entries[name] = [match.group(2).strip()]
        elif current and line.startswith("        "):
            for name in current:
                entries[name].append(line.strip())
        elif line.strip() and not line.startswith("        "):
            break
    return {name: _sentence(parts) for name, parts in entries.items()}


def _sentence(parts: list) -> str:
    kind, text = parts[0], " ".join(parts[1:])
    text = _ROLE.sub(lambda m: m.group(1).rsplit(".", 1)[-1], text).replace("``", "")
    text = re.sub(r"\s+", " ", text).strip()
    if not text:
        return f"({kind})"
    end = re.search(r"(?<=\.)\s+(?=[A-Z(])", text)
    text = text[:end.start()] if end else text
    if len(text) > _LONGEST:                       # one line: cut at a clause, else a word
        cut = max(text.rfind("; ", 0, _LONGEST), text.rfind(", ", 0, _LONGEST))
        cut = cut if cut > _LONGEST // 2 else text.rfind(" ", 0, _LONGEST)
        text = text[:cut].rstrip(";, ") + " ..."
    return text


def toml_value(value) -> str | None:
    """A TOML literal of an option's value; None for None (no TOML literal: the key is unset).

    Examples
    --------
    >>> toml_value(True), toml_value(0.995), toml_value("auto"), toml_value(("a", "b"))
    ('true', '0.995', '"auto"', '["a", "b"]')
    """
    if value is None:
        return None
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise InputError(f"{value!r} has no TOML literal in a run configuration")
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise InputError(f"no TOML literal for {type(value).__name__} {value!r}")


def _line(key: str, value, comment: str) -> str:
    literal = toml_value(value)
    if literal is None:
        return f"# {key} =   # unset by default: {comment}"
    return f"{key} = {literal}   # {comment}"


def run_config_text(inputs: dict, *, options: dict | None = None, reasons: dict | None = None,
                    output: dict | None = None, run: dict | None = None,
                    questions: dict | None = None, header: str = "") -> str:
    """The text of a complete run configuration.

    Parameters
    ----------
    inputs : dict
        ``[inputs]`` values (paths as strings, relative to the file). Keys
        left out are written commented, with their meaning.
    options : dict of str to dict, optional
        Stage table -> key -> value set instead of the default.
    reasons : dict of str to str, optional
        ``"table.key"`` -> why it is set so (added to the key's comment).
    output, run : dict, optional
        ``[output]`` and ``[run]`` values (default: the defaults, commented).
    questions : dict of str to str, optional
        Open questions: written as ``[open_questions]``, which makes ``run``
        refuse the file until they are answered and deleted.
    header : str
        Comment lines at the top.

    Returns
    -------
    str

    Raises
    ------
    InputError
        An option that is not a key of its table.
    """
    options = options or {}
    for table, values in options.items():
        known = {f.name for f in dataclasses.fields(STAGE_TABLES[table])}
        unknown = set(values) - known
        if unknown:
            raise InputError(f"[{table}] has no key {sorted(unknown)[0]!r}")
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += ["# Every key is here with its default; paths are relative to this file.",
              "# Keys written as comments are unset (their default is computed or none).", ""]
    lines.append("[inputs]")
    for key, meaning in INPUT_KEYS.items():
        if key in inputs:
            lines.append(f"{key} = {toml_value(inputs[key])}   # {meaning}")
        else:
            lines.append(f"# {key} =   # {meaning}")
    for name, keys, given in (("output", OUTPUT_KEYS, output), ("run", RUN_KEYS, run)):
        lines += ["", f"[{name}]"]
        for key, meaning in keys.items():
            if given and key in given:
                lines.append(f"{key} = {toml_value(given[key])}   # {meaning}")
            else:
                lines.append(f"# {key} =   # {meaning}")
    for table, cls in STAGE_TABLES.items():
        docs = field_docs(cls)
        lines += ["", f"[{table}]   # {cls.__module__}.{cls.__name__}"]
        chain = CHAIN_DEFAULTS.get(table, {})
        for f in dataclasses.fields(cls):
            comment = docs.get(f.name, "(undocumented)")
            why = (reasons or {}).get(f"{table}.{f.name}")
            if why:
                comment += f" -- {why}"
            value = options.get(table, {}).get(f.name, chain.get(f.name, f.default))
            lines.append(_line(f.name, value, comment))
    if questions:
        lines += ["", "# OPEN QUESTIONS: what `mocap2mesh init` could not decide. Answer each "
                      "above, then", "# delete its line: `run` refuses this file until the "
                                    "table is empty.", "[open_questions]"]
        lines += [f"{key} = {toml_value(text)}" for key, text in questions.items()]
    return "\n".join(lines) + "\n"


def option_rows() -> list:
    """The stage options as Markdown table rows: ``| `table.key` | default | what |``.

    The same defaults and one-line comments as :func:`run_config_text` writes
    (the README's run-configuration table is these rows).

    Examples
    --------
    >>> option_rows()[0].split(" | ")[0]
    '| `ingest.fix_swaps`'
    """
    rows = []
    for table, cls in STAGE_TABLES.items():
        docs, chain = field_docs(cls), CHAIN_DEFAULTS.get(table, {})
        for f in dataclasses.fields(cls):
            literal = toml_value(chain.get(f.name, f.default))
            default = "unset" if literal is None else f"`{literal}`"
            what = docs.get(f.name, "(undocumented)").replace("|", "\\|")
            rows.append(f"| `{table}.{f.name}` | {default} | {what} |")
    return rows
