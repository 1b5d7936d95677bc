"""What the benchmark scripts share: replacing their section of BENCHMARKS.md."""
from __future__ import annotations

import re
from pathlib import Path


def replace_section(path, heading: str, section: str) -> None:
    """Write ``section`` (which starts with ``## heading``) into ``path`` in place of the old one
    of that heading, or at the end; the other sections are kept as they are."""
    out = Path(path)
    text = out.read_text() if out.exists() else "# Benchmarks\n\n"
    text = re.sub(rf"\n## {re.escape(heading)}\n.*?(?=\n## |\Z)", "", text, flags=re.S).rstrip("\n")
    out.write_text(text + "\n\n" + section)
