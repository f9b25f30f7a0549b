"""What an answer's error text must not contain (PROTOCOL.md 1: plain words and JSON values,
never the server's internals): used over the fuzzers' answers (tests/fuzz_inputs.py, the
campaign) and by the conformance tests."""

from __future__ import annotations

import re

#: What only a Python repr writes: bytes literals, quoting with ', numpy scalars, Python's
#: constants, a class.
_REPR = re.compile(
    r"""\bb['"]|(?:^|[\s(\[{,:=])'[^']*'|\bnp\.\w+\(|\bnumpy\.|\b(?:None|True|False)\b|<class """
)
#: A module path or a traceback.
_INTERNALS = re.compile(r"\.py\b|\bsphrender\.|Traceback|File \"")
#: Fragments of the exception texts of the libraries on the decode paths (json, zipfile, zlib,
#: numpy, the stdlib HTTP server, Python itself): none may reach a client.
LIBRARY_FRAGMENTS = (
    "Expecting value",
    "Expecting property name",
    "Expecting ',' delimiter",
    "Extra data",
    "Unterminated string",
    "Invalid control character",
    "Invalid \\escape",
    "File name in directory",
    "Bad magic number",
    "Truncated file header",
    "Bad CRC-32",
    "Error -3 while decompressing",
    "invalid distance",
    "invalid stored block",
    "Compressed file ended",
    "is not a zip file",
    "Bad request version",
    "Bad request syntax",
    "Bad HTTP/0.9",
    "Unsupported method",
    "Invalid HTTP version",
    "Line too long",
    "got more than 100 headers",
    "allow_pickle",
    "cannot reshape array",
    "buffer is smaller",
    "could not convert",
    "invalid literal for",
    "unhashable type",
    "has no attribute",
    "object is not",
    "positional argument",
    "Exceeds the limit",
    "maximum recursion depth",
    "unsupported operand",
    "codec can't",
    "Errno",
)


def text_faults(text: object) -> list[str]:
    """What is wrong with an answer's error text (PROTOCOL.md 1: plain words and JSON values,
    never the server's internals): a Python repr, a module path, a library's message."""
    if not isinstance(text, str) or not text:
        return ["not a non-empty string"]
    faults = [f"repr {m.group(0)!r}" for m in _REPR.finditer(text)]
    faults += [f"internals {m.group(0)!r}" for m in _INTERNALS.finditer(text)]
    faults += [f"library {f!r}" for f in LIBRARY_FRAGMENTS if f in text]
    return faults
