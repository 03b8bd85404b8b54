"""Mapping methods behind one interface; see :class:`Mapper` and :func:`make_mapper`.

Adding a method is adding one module here with a :func:`register`-ed subclass of
:class:`Mapper`, and importing it below.
"""

from . import counting, em, em_thrun, gradient, inverse, stochastic
from ._base import (
    MAPPERS,
    Mapper,
    NotFittedError,
    check_ranges,
    make_mapper,
    parse_params,
    preset_params,
    register,
)
from ._forward import ForwardProblem
from ._stream import StreamEngine
from .counting import CountingMapper
from .em import EMMapper
from .em_thrun import ThrunEMMapper
from .gradient import GradientMapper
from .inverse import InverseMapper
from .stochastic import StochasticMapper

__all__ = [
    "MAPPERS",
    "CountingMapper",
    "EMMapper",
    "ForwardProblem",
    "GradientMapper",
    "InverseMapper",
    "Mapper",
    "NotFittedError",
    "StochasticMapper",
    "StreamEngine",
    "ThrunEMMapper",
    "check_ranges",
    "counting",
    "em",
    "em_thrun",
    "gradient",
    "inverse",
    "make_mapper",
    "parse_params",
    "preset_params",
    "register",
    "stochastic",
]
