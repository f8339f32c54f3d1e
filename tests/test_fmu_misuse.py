"""The misuse matrix (tests/misuse_matrix.py) on every shipped FMU, one test per FMU and class of misuse: each
case's status, its logged message, and an instance that is unchanged (refused calls) or terminated (discarded
steps) as the FMI 2.0 standard says."""
from __future__ import annotations

from pathlib import Path

import pytest

import misuse_matrix
from cedra.models.controller import CONTROLLERS
from cedra.models.scene import shipped
from fmu_harness import shipped_fmu

FMUS = shipped() + list(CONTROLLERS)       # every shipped plant and the drive controllers


def fmu_path(name, tmp_path_factory) -> Path:
    return shipped_fmu(name, tmp_path_factory)


CLASSES = ["call order", "NULL arguments", "unknown references and wrong types",
           "NaN, infinite and out-of-range values", "all-or-nothing setters", "step arguments and budgets",
           "setup experiment", "FMU states", "unsupported functions and kinds", "instantiation"]


def test_the_matrix_has_every_class_and_at_least_150_cases(tmp_path_factory):
    for scene in FMUS:
        path = fmu_path(scene, tmp_path_factory)
        assert misuse_matrix.classes(path) == CLASSES or set(misuse_matrix.classes(path)) == set(CLASSES)
        md = misuse_matrix.read_model_description(str(path))
        assert len(misuse_matrix.cases(md)) >= 150, scene


@pytest.mark.parametrize("cls", CLASSES)
@pytest.mark.parametrize("scene", FMUS)
def test_misuse_is_answered_as_the_standard_says(scene, cls, tmp_path_factory):
    results = misuse_matrix.run_all(fmu_path(scene, tmp_path_factory), only_cls=cls)
    assert results, f"no cases in class {cls}"
    problems = [f"{case.name}: {why}" for case, why in results if why]
    assert not problems, f"{scene}, {cls}: {len(problems)} of {len(results)} cases wrong:\n" + "\n".join(problems)
