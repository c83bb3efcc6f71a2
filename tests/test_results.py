"""One result vocabulary: every result type a user reads is a frozen dataclass deriving
:class:`microhom.results.Result` (``as_dict()`` for JSON, ``to_frame()`` for pandas).

The test walks every module of ``microhom`` and ``dem`` and finds the result types by name
(``...Result``, ``...Prediction``, ``...Report``, ``...Run``, ``...Estimate``, ``...Statistics``),
so a new one that forgets the rule fails here.
"""
import dataclasses
import importlib
import inspect
import pkgutil

import pytest

from microhom.results import Result

SUFFIXES = ("Result", "Prediction", "Report", "Run", "Estimate", "Statistics", "Moduli")


def _result_types():
    found = {}
    for package in ("microhom", "dem"):
        pkg = importlib.import_module(package)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=package + "."):
            if info.name.endswith("__main__"):
                continue
            mod = importlib.import_module(info.name)
            for name, obj in vars(mod).items():
                if (inspect.isclass(obj) and obj.__module__ == mod.__name__ and not name.startswith("_")
                        and name.endswith(SUFFIXES) and obj is not Result):
                    found[f"{mod.__name__}.{name}"] = obj
    return found


TYPES = _result_types()


def test_the_walk_finds_the_known_results():
    names = {k.rsplit(".", 1)[1] for k in TYPES}
    assert {"Prediction", "HierarchyResult", "StiffnessResult", "AnalysisResult",
            "NetworkStatistics", "ClosurePrediction"} <= names


@pytest.mark.parametrize("qualname", sorted(TYPES))
def test_result_types_are_frozen_results(qualname):
    cls = TYPES[qualname]
    assert dataclasses.is_dataclass(cls), f"{qualname} is not a dataclass"
    assert cls.__dataclass_params__.frozen, f"{qualname} is not frozen"
    assert issubclass(cls, Result), f"{qualname} does not derive microhom.results.Result"
