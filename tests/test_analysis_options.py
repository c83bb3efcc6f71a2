"""``dem.analysis.analyse.AnalysisOptions``: the options of ``analyse_file`` as one frozen,
validated object (issue 23), and the callers that build it (the command line, keywords)."""
import dataclasses
import inspect
from pathlib import Path

import pytest

from dem.analysis import analyse as dan
from dem.analysis.analyse import AnalysisOptions, OptionError, analyse_file

DATA = Path(__file__).parent / "data"

#: (field, a bad value, the range the message must name): the ranges of the docstring
BAD = [
    ("format", "xyz", "one of lammps-data, lammps-dump, oval"),
    ("kn", -1.0, "finite and > 0"), ("kn", 0.0, "finite and > 0"),
    ("kn", float("nan"), "finite and > 0"), ("kn", "1", "finite and > 0"),
    ("kt", -0.5, "finite and >= 0"), ("kt", float("inf"), "finite and >= 0"),
    ("kt_ratio", -0.1, "finite and >= 0"),
    ("kn_convention", "dempla", "None, 'standard' or 'oval'"),
    ("branch_length", "centres", "'distance' or 'radii'"),
    ("alpha", 2.5, "in [0, 2]"), ("alpha", float("nan"), "in [0, 2]"),
    ("prestress", 1, "True or False"),
    ("min_contacts", 0, "an integer >= 1"), ("min_contacts", 2.5, "an integer >= 1"),
    ("frame", 1.0, "an integer"), ("frame", None, "an integer"),
    ("radius", 0.0, "finite and > 0"),
    ("exact", "yes", "True or False"), ("hierarchy", None, "True or False"),
    ("spin_arm", "centre", "None, 'contact' or 'radius'"),
    ("hierarchy_tol", 1.0, "(0, 1)"), ("hierarchy_tol", 0.0, "(0, 1)"),
    ("rho_neighbours", "far", "'near' or 'contacts'"),
]


@pytest.mark.parametrize("name, value, allowed", BAD)
def test_a_bad_value_names_the_field_and_its_range(name, value, allowed):
    with pytest.raises(OptionError) as info:
        AnalysisOptions(**{name: value})
    assert info.value.name == name and allowed in str(info.value)
    assert str(info.value).startswith(f"{name} must be ")
    assert isinstance(info.value, ValueError)


def test_every_field_is_checked():
    assert {b[0] for b in BAD} == set(AnalysisOptions.names())


def test_kt_and_kt_ratio_not_both():
    with pytest.raises(OptionError, match="not both"):
        AnalysisOptions(kt=1.0, kt_ratio=0.3)
    with pytest.raises(OptionError, match="not both"):
        AnalysisOptions(kt=1.0).replace(kt_ratio=0.3)


def test_defaults_are_the_functions_defaults():
    """The options' defaults are those of ``load_network`` and ``analyse`` (one default per
    option, not a second copy that drifts)."""
    opts = AnalysisOptions()
    for fn in (dan.load_network, dan.analyse):
        for p in inspect.signature(fn).parameters.values():
            if p.name in AnalysisOptions.names() and p.name != "spin_arm":
                assert getattr(opts, p.name) == p.default, (fn.__name__, p.name)
    assert opts.spin_arm is None          # analyse_file matches it to the file (its docstring)


def test_frozen_and_replace_validates():
    opts = AnalysisOptions(kn=2.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.kn = 3.0
    assert opts.replace(kt=1.0) == AnalysisOptions(kn=2.0, kt=1.0)
    with pytest.raises(OptionError, match="kn must be"):
        opts.replace(kn=-2.0)
    with pytest.raises(TypeError, match="unknown analysis option 'kappa'"):
        opts.replace(kappa=1.0)


def _same(a, b):
    """Two analyses equal but for the wall times."""
    da, db = a.as_dict(), b.as_dict()
    for d in (da, db):
        d["file"].pop("read_s"), d["file"].pop("analyse_s"), d["stiffness"].pop("time_s")
    return da == db


def test_keywords_options_and_overrides_agree():
    kw = dict(format="oval", kn=2.0, kn_convention="oval", hierarchy=False)
    by_kw = analyse_file(DATA / "D0001", **kw)
    by_opts = analyse_file(DATA / "D0001", AnalysisOptions(**kw))
    by_override = analyse_file(DATA / "D0001", AnalysisOptions(format="oval", kn=7.0,
                                                               hierarchy=False),
                               kn=2.0, kn_convention="oval")
    assert _same(by_kw, by_opts) and _same(by_kw, by_override)
    assert by_kw.network.kn_mean == 1.0               # OVAL's kn = 2 multiplies half the overlap
    other = analyse_file(DATA / "D0001", format="oval", kn=4.0, hierarchy=False)
    assert not _same(by_kw, other)                     # the comparison can fail


def test_bad_calls_are_named():
    with pytest.raises(TypeError, match="format='oval'"):
        analyse_file(DATA / "D0001", "oval")           # the old positional format
    with pytest.raises(TypeError, match="unknown analysis option 'kappa'"):
        analyse_file(DATA / "D0001", kappa=1.0)
    with pytest.raises(OptionError, match="hierarchy_tol must be"):
        analyse_file(DATA / "D0001", hierarchy_tol=2.0)


@pytest.mark.parametrize("argv, message", [
    # the messages of the command line before the options object (its own _check), verbatim
    (["--kn", "-1"], "--kn must be finite and > 0, got -1.0"),
    (["--kt", "nan"], "--kt must be finite and >= 0, got nan"),
    (["--kt-ratio", "-0.5"], "--kt-ratio must be finite and >= 0, got -0.5"),
    (["--alpha", "3"], "--alpha must be in [0, 2], got 3.0"),
    (["--radius", "0"], "--radius must be finite and > 0, got 0.0"),
    (["--min-contacts", "0"], "--min-contacts must be an integer >= 1, got 0"),
    (["--hierarchy-tol", "2"], "--hierarchy-tol must be a relative width in (0, 1), got 2.0"),
    (["--frame", "0"], "--frame counts from 1 (first) or from -1 (last); 0 is not a frame"),
])
def test_the_command_line_names_its_option(argv, message, capsys):
    from dem.__main__ import main
    rc = main(["analyse", str(DATA / "D0001"), *argv])
    err = capsys.readouterr().err
    assert rc == 2 and message in err, err
