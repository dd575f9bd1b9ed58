"""The features of a gesture clip, each synthesized by its own Markov chain.

Ju & Lee (2008) animate the stochastic features of a face separately (sec. 5:
"other terms R̃(t), T̃(t), D̃_j(t) can be computed similarly"; sec. 6: "the
eyebrows can imitate the gestures of subject A, while the head motion is
simulating the style of subject B"). Here the features are:

- ``weights``: the blend weights c(t) of the expression shapes;
- ``blinks`` and ``brows``: the blend weights of the eyelid and brow shapes,
  taken out of c(t) so that each follows its own chain. Blinks are short,
  fast events of one or two shapes among ~50: matched together with the
  whole expression, a chain cuts and merges them (``bench/bench_gestures.py``
  compares the blink and brow rates of both settings with the reference's);
- ``head``: the rigid head motion R(t), T(t);
- the detail groups D_j(t) (:data:`fit.gestures.analysis.DETAIL_GROUPS`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from fit.gestures.analysis import DETAIL_GROUPS
from mocap.errors import InputError

__all__ = ["FEATURES", "WEIGHT_FEATURES", "DETAIL_FEATURES", "WEIGHT_PATTERNS",
           "weight_columns"]

#: Features made of blend-weight columns; ``weights`` holds the columns no other takes.
WEIGHT_FEATURES = ("weights", "blinks", "brows")
#: Features made of the residuals of a detail marker group, mm.
DETAIL_FEATURES = DETAIL_GROUPS
#: Every feature, in the order they are synthesized (and timeline keys).
FEATURES = (*WEIGHT_FEATURES, "head", *DETAIL_FEATURES)
#: Default shape-name substrings (case-insensitive) of the split weight features:
#: ARKit ``EyeBlinkLeft``, ``BrowInnerUp``; ICT ``eyeBlink_L``, ``browDown_R``.
WEIGHT_PATTERNS = {"blinks": ("blink",), "brows": ("brow",)}


def weight_columns(names, groups: Mapping | None = None) -> dict:
    """Columns of the blend weights that make up each weight feature.

    Parameters
    ----------
    names : sequence of str
        Shape names of the weights, in column order.
    groups : mapping of str to sequence of str, optional
        ``{"blinks": [...], "brows": [...]}``: the shapes each split feature
        takes (either key may be absent; ``{}`` keeps every column in
        ``weights``). Default: the shapes whose name contains a substring of
        :data:`WEIGHT_PATTERNS`.

    Returns
    -------
    dict of str to ndarray of int
        Feature (:data:`WEIGHT_FEATURES`) to column indices, ascending; ``weights``
        gets the columns no group takes. Features without columns are left out.

    Raises
    ------
    InputError
        An unknown feature, a shape not in `names`, a shape in two groups.
    """
    names = tuple(str(x) for x in names)
    if groups is None:
        groups = {f: [n for n in names if any(p in n.lower() for p in patterns)]
                  for f, patterns in WEIGHT_PATTERNS.items()}
    if not isinstance(groups, Mapping):
        raise InputError(f"weight groups must be a mapping of feature to shape names, got "
                         f"{type(groups).__name__}")
    taken, out = {}, {}
    for feature, members in groups.items():
        if feature not in WEIGHT_PATTERNS:
            raise InputError(f"unknown weight feature {feature!r}; expected one of "
                             f"{list(WEIGHT_PATTERNS)}")
        members = [members] if isinstance(members, str) else list(members)
        for name in members:
            if name not in names:
                raise InputError(f"weight feature {feature!r}: no shape {name!r} among the "
                                 f"clip's {len(names)} shapes")
            if name in taken:
                raise InputError(f"shape {name!r} is in both {taken[name]!r} and {feature!r}")
            taken[name] = feature
        if members:
            out[feature] = np.array(sorted(names.index(n) for n in members), dtype=np.int64)
    rest = [i for i, n in enumerate(names) if n not in taken]
    if rest:
        out["weights"] = np.array(rest, dtype=np.int64)
    return {f: out[f] for f in WEIGHT_FEATURES if f in out}
