"""One unit-suffix dialect (issue 21): rates are ``_m_s`` and ``_rad_s`` (``_m_s2``, ``_rad_s2``), never ``_mps`` or
``_radps``, in every name of the project's code (identifiers, keyword arguments, fields)."""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OTHER_DIALECT = re.compile(r"_(mps|radps)2?$")


def names_in_other_dialect(source: str) -> list[str]:
    """Identifiers of ``source`` that end in ``_mps`` or ``_radps``."""
    tokens = tokenize.generate_tokens(io.StringIO(source).readline)
    return [t.string for t in tokens if t.type == tokenize.NAME and OTHER_DIALECT.search(t.string)]


def test_the_check_sees_the_other_dialect() -> None:
    assert names_in_other_dialect("v_mps = 1\nf(yaw_rate_radps=2, a_mps2=0, speed_m_s=3)\n") == [
        "v_mps",
        "yaw_rate_radps",
        "a_mps2",
    ]


def test_every_name_uses_one_dialect() -> None:
    found = {
        str(path.relative_to(ROOT)): hits
        for folder in ("messages", "onboard", "sim", "groundstation", "benchmarks", "tests")
        for path in (ROOT / folder).rglob("*.py")
        if (hits := names_in_other_dialect(path.read_text()))
    }
    assert found == {}
