"""The suite mirrors the packages: no test module at the root of tests/, none reaching into bench/ by sys.path."""

from __future__ import annotations

from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]


def test_no_test_module_lies_at_the_root_of_tests() -> None:
    assert sorted(p.name for p in TESTS.glob("test_*.py")) == []


def test_no_test_edits_sys_path() -> None:
    needle = "sys.path." + "insert"  # spelt apart so that this file does not match itself
    offenders = [str(p.relative_to(TESTS)) for p in TESTS.rglob("*.py") if needle in p.read_text()]
    assert offenders == []
