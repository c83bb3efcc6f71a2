"""Options bundles: frozen, validated once when made, errors naming the field and its range.

A function with many settings takes one bundle and keyword overrides of its fields, as
``dem.analysis.analyse.analyse_file`` does with its ``AnalysisOptions``::

    relaxation_hierarchy(net, tol=1e-3, prestress=True)          # keywords: overrides of the defaults
    opts = HierarchyOptions(tol=1e-3, prestress=True)
    relaxation_hierarchy(net, opts)                               # the same run
    relaxation_hierarchy(net, opts, max_order=4)                  # a variant: opts with max_order=4

A subclass is a frozen dataclass deriving :class:`Options` whose class attribute ``RULES`` maps each
field to ``(allowed, check)``: ``allowed`` the range as text, ``check`` a predicate of the value.
``__post_init__`` checks every field and raises :class:`OptionError` (a ``ValueError``) naming the
first field outside its range. The bundles in use: :class:`microhom.hierarchy.HierarchyOptions`,
:class:`microhom.spectral.CertificateOptions`, and the disk engine's ``Guard`` and ``Loop``
(``dem.engine.integrate``).

This module imports numpy only.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .results import Result

__all__ = ["Options", "OptionError", "merged", "real", "finite_real", "flag", "integer"]


class OptionError(ValueError):
    """A field of an :class:`~microhom.options.Options` bundle outside its allowed range: ``name`` (the field),
    ``allowed`` (the range, as text) and ``value``; the message is
    ``"<name> must be <allowed>, got <value>"``."""

    def __init__(self, name, allowed, value):
        self.name, self.allowed, self.value = name, allowed, value
        super().__init__(f"{name} must be {allowed}, got {value!r}")


def real(v) -> bool:
    """A real number (int, float or numpy scalar), not a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def finite_real(v) -> bool:
    """A finite :func:`real`."""
    return real(v) and math.isfinite(v)


def flag(v) -> bool:
    """True or False (a numpy bool too)."""
    return isinstance(v, (bool, np.bool_))


def integer(v) -> bool:
    """An integer (Python or numpy), not a bool."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


@dataclasses.dataclass(frozen=True)
class Options(Result):
    """Base of the options bundles: validated when made, ``names()``, ``replace()``.

    A subclass's class attribute ``RULES`` maps each of its fields to ``(allowed, check)`` (the
    range as text, a predicate of the value). ``as_dict()`` (from
    :class:`microhom.results.Result`) records the values."""

    RULES = {}      # field -> (allowed range as text, predicate); every field of a subclass has one

    def __post_init__(self):
        for f in dataclasses.fields(self):
            allowed, ok = self.RULES[f.name]
            v = getattr(self, f.name)
            if not ok(v):
                raise OptionError(f.name, allowed, v)

    @classmethod
    def names(cls) -> tuple:
        """The option names, in order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    def replace(self, **changes):
        """A copy with ``changes`` (validated again); a TypeError names an unknown option."""
        unknown = sorted(set(changes) - set(self.names()))
        if unknown:
            raise TypeError(f"unknown {type(self).__name__} field {unknown[0]!r}; the fields are "
                            f"{', '.join(self.names())}")
        return dataclasses.replace(self, **changes)


def merged(cls, options, overrides, where):
    """``options`` (an instance of the bundle ``cls``, or None: its defaults) with the keyword
    ``overrides`` of its fields; ``where`` names the caller in the TypeError for anything else."""
    if options is None:
        options = cls()
    elif not isinstance(options, cls):
        raise TypeError(f"{where}'s options must be a {cls.__name__} or None, got "
                        f"{type(options).__name__}; give settings as keywords ({', '.join(cls.names())})")
    return options.replace(**overrides) if overrides else options
