"""Reading untrusted description files: bounded sizes, bytes decoded by the format's own
rules, and messages that quote a value without ever expanding it."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any
from xml.parsers import expat

from ..errors import ModelError

# The largest shared URDF (Tiago) is 0.12 MB and a 50-body model file is about 20 kB;
# the bounds keep a hostile file to seconds of parsing.
MAX_FILE_BYTES = 16 * 2**20  # URDF: expat reads this in a fraction of a second
MAX_MODEL_FILE_BYTES = 2**20  # YAML/JSON: PyYAML builds Python objects for every node
MAX_BODIES = 500
MAX_NAME_LENGTH = 200
_QUOTE_LENGTH = 60


def read_description(path: str | Path, what: str, limit: int | None = None) -> bytes:
    """The raw bytes of a description file, refused before reading if it is too large.

    The bytes go to the format's own decoder (YAML and JSON detect UTF-8/16/32, XML obeys
    its encoding declaration), so a correctly declared Latin-1 or UTF-16 file reads fine.
    """
    path = Path(path)
    source = str(path)
    limit = MAX_FILE_BYTES if limit is None else limit
    too_large = f"gagen reads {what}s of at most {limit:,} bytes"
    try:
        if path.stat().st_size > limit:
            raise ModelError(source, "", f"the {what} has {path.stat().st_size:,} bytes; {too_large}")
        with path.open("rb") as handle:
            data = handle.read(limit + 1)
    except OSError as exc:
        raise ModelError(source, "", f"cannot read {what}: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise ModelError(source, "", f"the {what} grew while it was read; {too_large}")
    return data


def check_body_count(count: int, source: str, element: str) -> None:
    """Refuse descriptions with more bodies than gagen builds in reasonable time."""
    if count > MAX_BODIES:
        raise ModelError(source, element, f"{count} bodies; gagen builds robots of at most "
                         f"{MAX_BODIES} bodies")


def describe(value: Any) -> str:
    """A short, bounded description of a value for an error message.

    Containers are described by kind and size, never printed: a YAML alias bomb is a
    small document whose `str()` is exponentially large.
    """
    if isinstance(value, dict):
        return f"a mapping of {len(value)} entries"
    if isinstance(value, (list, tuple, set)):
        return f"a list of {len(value)} entries"
    if isinstance(value, str):
        return quote(value)
    if isinstance(value, (bool, float)) or value is None:
        return repr(value)
    if isinstance(value, int):
        return repr(value) if value.bit_length() < 64 else f"an integer of {value.bit_length()} bits"
    return f"a value of type {type(value).__name__}"


def quote(text: str) -> str:
    """`text` in quotes, cut short and with control characters escaped."""
    shown = text if len(text) <= _QUOTE_LENGTH else text[:_QUOTE_LENGTH] + "..."
    return repr(shown)


def name_field(value: Any, source: str, element: str) -> str:
    """A name from a description: a non-empty string (or an integer) of bounded length."""
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise ModelError(source, element, f"expected a name, got {describe(value)}")
    if isinstance(value, int):
        if value.bit_length() > 64:
            raise ModelError(source, element, f"expected a name, got {describe(value)}")
        value = str(value)
    if not value.strip():
        raise ModelError(source, element, "the name is empty")
    if len(value) > MAX_NAME_LENGTH:
        raise ModelError(source, element, f"the name {quote(value)} has {len(value)} "
                         f"characters; at most {MAX_NAME_LENGTH} are allowed")
    return value


def parse_untrusted_xml(text: str | bytes, source: str, what: str) -> ET.Element:
    """The element tree of an XML description (`what`: "a URDF", "an MJCF file"), refusing
    any DTD; malformed XML is a ModelError naming the line and column."""
    try:
        return _tree_from_expat(text)
    except expat.ExpatError as exc:
        raise ModelError(source, f"line {exc.lineno}, column {exc.offset + 1}",
                         f"malformed XML: {expat.ErrorString(exc.code)}") from None
    except _DoctypeRefused:
        raise ModelError(source, "<!DOCTYPE>",
                         f"{what} must not declare a DTD or entities") from None
    except (LookupError, ValueError, RecursionError, MemoryError) as exc:
        raise ModelError(source, "", f"unreadable XML: {type(exc).__name__}") from None


class _DoctypeRefused(Exception):
    pass


def _refuse_doctype(*_args) -> None:
    raise _DoctypeRefused


def _tree_from_expat(text: str | bytes) -> ET.Element:
    """An ElementTree from expat, refusing any DTD.

    A robot description never needs one, and refusing it refuses entity expansion
    ("billion laughs") and external entities whatever expat's own protections are.
    ElementTree's C parser does not expose these handlers, so the tree is built here from
    expat's events.
    """
    parser = expat.ParserCreate()
    builder = ET.TreeBuilder()
    parser.StartDoctypeDeclHandler = _refuse_doctype
    parser.EntityDeclHandler = _refuse_doctype
    parser.ExternalEntityRefHandler = _refuse_doctype
    parser.buffer_text = True
    parser.ordered_attributes = False
    parser.StartElementHandler = builder.start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    parser.Parse(text, True)
    return builder.close()
