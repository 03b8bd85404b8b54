"""Mapping methods behind one interface; see :class:`Mapper` and :func:`make_mapper`.

Adding a method is adding one module here with a :func:`register`-ed subclass of
:class:`Mapper`, and importing it below.
"""

from . import counting, inverse
from ._base import MAPPERS, Mapper, NotFittedError, make_mapper, parse_params, register
from .counting import CountingMapper
from .inverse import InverseMapper

__all__ = [
    "MAPPERS",
    "CountingMapper",
    "InverseMapper",
    "Mapper",
    "NotFittedError",
    "counting",
    "inverse",
    "make_mapper",
    "parse_params",
    "register",
]
