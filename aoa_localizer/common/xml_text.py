"""Text an XML document can hold (KML, CoT): an id or a channel name may carry characters XML 1.0 forbids even
escaped (control characters, lone surrogates, U+FFFE/U+FFFF), which make the whole document unparsable."""
from __future__ import annotations

import re

_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def xml_text(value) -> str:
    """`value` as text XML can hold: each character XML forbids becomes U+FFFD."""
    return _NOT_XML.sub("\ufffd", str(value))
