"""Which scenes tune the methods and which judge them.

Parameters are chosen on *training* scenes; every table and claim is measured on
*held-out* scenes the tuning never saw: other scene families (floor plans drawn by
other rules) **and** other seeds. A sweep refuses held-out scenes; experiments and
claim tests use them.

==============  ===============================================  ==============
split           families                                         seeds
==============  ===============================================  ==============
training        ``doorways``, ``passages``, ``room-turn``,        0 to 999
                ``boxes``, ``hall``, ``suite``
held-out        ``gaps``, ``corridor``, ``office``                1000 and above
==============  ===============================================  ==============

The held-out families are generated from their seed (gap widths in shuffled order,
wall thicknesses and lengths, positions off the cell boundaries, rooms and furniture),
so no two held-out scenes are alike.
"""

from __future__ import annotations

from .errors import ConfigError

__all__ = [
    "HELD_OUT_FAMILIES",
    "HELD_OUT_SEED",
    "TRAINING_FAMILIES",
    "check_training",
    "held_out_seeds",
]

TRAINING_FAMILIES = ("doorways", "passages", "room-turn", "boxes", "hall", "suite")
HELD_OUT_FAMILIES = ("gaps", "corridor", "office")
#: Seeds from this one on are held out.
HELD_OUT_SEED = 1000


def held_out_seeds(n: int, first: int = HELD_OUT_SEED) -> list[int]:
    """``n`` held-out seeds from ``first``.

    Examples
    --------
    >>> held_out_seeds(3)
    [1000, 1001, 1002]
    """
    if first < HELD_OUT_SEED:
        raise ConfigError(f"held-out seeds start at {HELD_OUT_SEED}, got {first}")
    return list(range(first, first + n))


def check_training(family: str, seed: int, *, where: str = "") -> None:
    """Refuse a held-out family or seed where only training scenes belong.

    Examples
    --------
    >>> check_training("passages", 3)
    >>> check_training("passages", 1000)
    Traceback (most recent call last):
    ...
    sonarmap.errors.ConfigError: seed 1000 is held out for testing; training seeds are 0 to 999
    """
    at = f"{where}: " if where else ""
    if family not in TRAINING_FAMILIES:
        raise ConfigError(
            f"{at}scene family '{family}' is held out for testing; train on "
            f"{', '.join(TRAINING_FAMILIES)}"
        )
    if seed >= HELD_OUT_SEED:
        raise ConfigError(
            f"{at}seed {seed} is held out for testing; training seeds are 0 to {HELD_OUT_SEED - 1}"
        )
