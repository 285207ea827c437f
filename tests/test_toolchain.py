"""The start-up check that refuses a drifted test toolchain (tests/conftest.py)."""

from __future__ import annotations

from importlib import metadata

from packaging.requirements import Requirement

from tests.conftest import pinned_test_requirements, toolchain_mismatches


def test_pins_include_the_pair_that_broke():
    names = {r.name: r for r in pinned_test_requirements()}
    assert str(names["pytest"].specifier) == "==9.1.1"
    assert "schemathesis" in names


def test_a_drifted_version_is_named_with_its_pin():
    fake = {"pytest": "9.2.0"}
    msgs = toolchain_mismatches([Requirement("pytest==9.1.1")], version_of=fake.__getitem__)
    assert msgs == ["pytest 9.2.0 is installed but pyproject.toml pins pytest==9.1.1"]


def test_a_missing_package_is_named():
    def version_of(name):
        raise metadata.PackageNotFoundError(name)

    msgs = toolchain_mismatches([Requirement("schemathesis==4.32.5")], version_of=version_of)
    assert msgs == ["schemathesis is not installed (pyproject.toml asks for schemathesis==4.32.5)"]


def test_the_installed_toolchain_matches_its_pins():
    assert toolchain_mismatches(pinned_test_requirements()) == []
