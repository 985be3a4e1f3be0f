"""File names people dropped, as hostd shows them, and whose a sidecar is.

A name can hold characters that change how the text around them reads without being
seen: a right-to-left override (U+202E) makes ``photo<RLO>gnp.npy`` read as
``photoypn.png``. Wherever a name is shown (the page, the CLI, the log) such characters
appear escaped, as ``\\u202e``.
"""

import unicodedata

from pipeline.errors import InvalidSidecar

# Controls, format characters (the bidirectional overrides and isolates, zero-width
# characters, the byte-order mark) and line or paragraph separators.
_HIDDEN = ("Cc", "Cf", "Zl", "Zp")


def hidden(c):
    """Whether ``c`` changes or hides text instead of showing as itself."""
    return unicodedata.category(c) in _HIDDEN


def visible(text):
    """``text`` with every :func:`hidden` character written as an escape (``\\u202e``)."""
    if not any(hidden(c) for c in text):
        return text
    return "".join(("\\x%02x" % ord(c) if ord(c) < 0x100 else "\\u%04x" % ord(c)
                    if ord(c) < 0x10000 else "\\U%08x" % ord(c)) if hidden(c) else c
                   for c in text)


def one_owner(rel_path, others):
    """Refuse an input whose sidecar ``NAME.yaml`` also stands beside ``others`` (inputs of
    the same stem, such as ``t.npy`` beside ``t.png``): which file it describes is not
    known, and guessing would plan one of them at the wrong size."""
    if not others:
        return
    stem = rel_path.rsplit(".", 1)[0]
    raise InvalidSidecar("%s shares its sidecar %s.yaml with %s: it is not known which file "
                         "the sidecar is for" % (visible(rel_path), visible(stem),
                                                 " and ".join(map(visible, others))),
                         code="sidecar.ambiguous", file=stem + ".yaml",
                         fix="give each input its own name and sidecar (rename one of them "
                             "and copy the sidecar to its new name), then requeue them or "
                             "drop them again")
