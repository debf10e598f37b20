"""The names in a LAMMPS deck that write_lammps writes: file names and the
text of the terms' LAMMPS forms, checked before anything is written (a name
the deck cannot hold, two files of one name, a potential file copied onto
another)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["DECK_SPECIAL", "deck_file_name", "deck_text", "check_names", "same_file"]


#: Characters a file name in the deck may not hold: LAMMPS substitutes a
#: variable at ``$``, continues a line at ``&``, starts a comment at ``#`` and
#: quotes at ``'`` and ``"``; a shell substitutes at a backquote and escapes at
#: a backslash; ``*`` and ``%`` in a dump name make one file per step or per
#: processor.
DECK_SPECIAL = "$&#'\"`\\*%"


def deck_file_name(name, what):
    """``name`` if it is a plain file name that the deck can hold and that stays
    in the deck's directory: no path separator, not ``.`` or ``..``, no
    whitespace or control character (a newline would add a line to the deck,
    such as ``shell rm ...``), none of :data:`DECK_SPECIAL`. Else a
    ValueError naming ``what`` and the character."""
    if isinstance(name, os.PathLike):
        name = os.fspath(name)
    if not isinstance(name, str):
        raise TypeError(f"write_lammps: {what} must be a file name (str), got {name!r:.80}")
    problem = None
    if name in ("", ".", ".."):
        problem = "is not a file name"
    else:
        for ch in name:
            if ch == "/" or ch == os.sep:
                problem = (f"holds the path separator {ch!r}: the deck's files stay in its "
                           "directory (give a plain name)")
            elif ch.isspace() or not ch.isprintable():
                problem = (f"holds the whitespace or control character {ch!r}, which would "
                           "split the deck's line or add one")
            elif ch in DECK_SPECIAL:
                problem = f"holds the character {ch!r}, which LAMMPS or a shell reads specially"
            if problem:
                break
    if problem:
        raise ValueError(f"write_lammps: {what} {name!r} {problem}; nothing was written")
    return name


def deck_text(text, what):
    """Text of a term's LAMMPS form (arguments, element names from a potential
    file): one line's worth, nothing LAMMPS substitutes or comments out."""
    text = str(text)
    for ch in text:
        if (ch != " " and (ch.isspace() or not ch.isprintable())) or ch in "$&#'\"`":
            raise ValueError(f"write_lammps: {what} {text!r:.80} holds the character {ch!r}, "
                             "which the deck cannot hold (a new line, a LAMMPS variable, "
                             "comment or quote); nothing was written")
    return text


def check_names(names, parts):
    """The deck's file names (``names``: what -> name) as plain names; refused,
    before anything is written: a name or a term's text that the deck cannot
    hold (:func:`deck_file_name`), two files of one name, and potential files
    of one name from different places."""
    names = {what: deck_file_name(name, what) for what, name in names.items()}
    taken = {}
    for what, name in names.items():
        if name in taken:
            raise ValueError(f"write_lammps: {taken[name]} and {what} are both {name!r}: "
                             "one would overwrite the other; nothing was written")
        taken[name] = what
    sources = {}
    for term, form in parts:
        for item in form:
            for f in getattr(item, "files", ()):
                base = deck_file_name(Path(f).name, f"the potential file {str(f)!r}: its name")
                if base in taken:
                    raise ValueError(f"write_lammps: the potential file {str(f)!r} would be "
                                     f"copied onto the {taken[base]} {base!r}: choose another "
                                     f"{taken[base]}; nothing was written")
                if base in sources and not same_file(sources[base], f):
                    raise ValueError(f"write_lammps: the potential files {str(sources[base])!r}"
                                     f" and {str(f)!r} have one name, {base!r}, in the deck's "
                                     "directory: rename one; nothing was written")
                sources[base] = f
            texts = ([item.style, item.args] + [a for _, _, a in getattr(item, "coeffs", ())]
                     + list(getattr(item, "modify", ())) + [getattr(item, "group", "")])
            for text in texts:
                deck_text(text, f"the LAMMPS form of the {term} term,")
    return names


def same_file(a, b):
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False
