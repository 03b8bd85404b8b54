"""Named settings of the team's exchange and store: ``team run --preset NAME``.

A preset sets some fields of :class:`~.exchange.ExchangeParams` and
:class:`~.store.StoreParams` and leaves the others to the caller; it says which fields it
sets, so that a caller can refuse a setting the preset would silently override.

:data:`DEFAULT_PRESET` (``lean``) is what ``team run`` gives a team of two or more robots
exchanging by a protocol: the setting that meets the team's bandwidth goal. ``classic``
is the thesis's exchange and store as the dataclasses' defaults have them (every pose
whole and exact, no fold, no merge at closures), which a single robot and the naive
baseline keep.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..errors import ConfigError, quote
from .exchange import LEAN, LEAN_MERGE_ON_CLOSURE, ExchangeParams
from .store import StoreParams

__all__ = [
    "DEFAULT_PRESET",
    "PRESETS",
    "PresetClashError",
    "TeamPreset",
    "check_preset",
    "default_mode",
    "team_settings",
]


@dataclass(frozen=True)
class TeamPreset:
    """Exchange and store settings applied together.

    Parameters
    ----------
    name : str
        The preset's name (``"lean"``).
    exchange : ExchangeParams
        The exchange the preset stands for; every field but ``keep`` is taken from it.
    keep : tuple of str
        Exchange fields left to the caller (the protocol, its cap and budget).
    store : mapping
        Store fields the preset sets, with their values.
    naive : bool
        Whether the preset may go with the naive baseline (which it then leaves as the
        caller's): False for a preset that thins what travels.
    """

    name: str
    exchange: ExchangeParams
    keep: tuple[str, ...] = ("mode", "cap_bytes", "budget")
    store: Mapping[str, Any] = field(default_factory=dict)
    naive: bool = False

    def sets(self) -> tuple[str, ...]:
        """Every field the preset sets: the exchange's (but ``keep``), then the store's."""
        own = tuple(f.name for f in fields(ExchangeParams) if f.name not in self.keep)
        return own + tuple(self.store)

    def conflicts(self, given: Iterable[str]) -> list[str]:
        """The fields of ``given`` (set explicitly by the caller) the preset would
        override, in ``given``'s order."""
        sets = set(self.sets())
        return [g for g in given if g in sets]

    def values(self, given: Collection[str] = ()) -> dict[str, dict[str, Any]]:
        """The preset's value of every field it sets but those in ``given``.

        Parameters
        ----------
        given : collection of str
            Fields the caller set explicitly, whose values stand.

        Returns
        -------
        dict
            ``{"exchange": {field: value}, "store": {field: value}}``, in :meth:`sets`'
            order.
        """
        own = [f for f in self.sets() if f not in self.store]
        return {
            "exchange": {f: getattr(self.exchange, f) for f in own if f not in given},
            "store": {f: v for f, v in self.store.items() if f not in given},
        }

    def apply(
        self, exchange: ExchangeParams, store: StoreParams
    ) -> tuple[ExchangeParams, StoreParams]:
        """The preset over ``exchange`` and ``store``.

        Parameters
        ----------
        exchange : ExchangeParams
            The caller's exchange; only its ``keep`` fields survive.
        store : StoreParams
            The caller's store; the preset's store fields replace its own.

        Returns
        -------
        (ExchangeParams, StoreParams)
            Both validated.

        Raises
        ------
        ConfigError
            For the naive baseline, which has nothing to thin out (``field="mode"``),
            unless the preset allows it (``naive``: then the caller's exchange stays).
        """
        if exchange.mode == "naive":
            if self.naive:
                return exchange, replace(store, **self.store)
            raise ConfigError(
                f"the {self.name} preset is for the protocols; the naive baseline sends every pose",
                field="mode",
            )
        kept = {k: getattr(exchange, k) for k in self.keep}
        return replace(self.exchange, **kept), replace(store, **self.store)


#: The presets by name. ``lean``: :data:`~.exchange.LEAN` with the store's ``fold`` and
#: :data:`~.exchange.LEAN_MERGE_ON_CLOSURE` (the measured lean exchange). ``classic``: the
#: thesis's exchange and store (the dataclasses' defaults).
PRESETS = {
    "lean": TeamPreset(
        "lean", LEAN, store={"fold": True, "merge_on_closure": LEAN_MERGE_ON_CLOSURE}
    ),
    "classic": TeamPreset(
        "classic", ExchangeParams(), store={"fold": False, "merge_on_closure": 0}, naive=True
    ),
}
#: The preset of a team that names none (two or more robots, a protocol, not the naive
#: baseline): the one that meets the team's goal (docs/results, the team pages).
DEFAULT_PRESET = "lean"


def check_preset(name: str | None, option: str = "--preset") -> None:
    """Refuse a preset name that names none of :data:`PRESETS` (None: no preset named).

    Raises
    ------
    ConfigError
        ``"--preset must be one of classic, lean, got 'x'"`` (``option`` naming it).
    """
    if name is not None and name not in PRESETS:
        raise ConfigError(
            f"{option} must be one of {', '.join(sorted(PRESETS))}, got {quote(name)}"
        )


def default_mode(mode: str | None, network: str) -> str:
    """The exchange protocol of a team whose caller named none: ``"good"`` on a full
    network, ``"limited"`` on any other (a link that may break or be slow is what the
    limited protocol was designed for).

    Parameters
    ----------
    mode : str or None
        The protocol named by the caller (kept as it is), or None.
    network : str
        The network's kind (:class:`~.network.NetworkParams`' ``kind``).

    Returns
    -------
    str
        The protocol (:class:`~.exchange.ExchangeParams`' ``mode``).
    """
    return mode if mode is not None else ("good" if network == "full" else "limited")


class PresetClashError(ConfigError):
    """Settings given by the caller that a preset named by the caller would override.

    Attributes
    ----------
    fields : tuple of str
        The clashing fields, in the caller's order.
    """

    def __init__(self, preset: str, fields: list[str]) -> None:
        super().__init__(f"the {preset} preset sets {', '.join(fields)}", field=fields[0])
        self.fields = tuple(fields)


def team_settings(
    chosen: str | None, exchange: ExchangeParams, store: StoreParams, given: Collection[str]
) -> tuple[ExchangeParams, StoreParams, str | None]:
    """One robot's exchange and store in a team, by the rule of ``team run``.

    Parameters
    ----------
    chosen : str or None
        A preset named by the caller, or None for the default.
    exchange, store : ExchangeParams, StoreParams
        The caller's settings: the fields in ``given`` as given, the others at the
        dataclasses' defaults.
    given : collection of str
        The fields of ``exchange`` and ``store`` the caller set explicitly (a clash
        names them in this order).

    Returns
    -------
    (ExchangeParams, StoreParams, str or None)
        The settings and the preset applied. A named preset sets its fields; with none
        named, :data:`DEFAULT_PRESET`'s values stand in for the fields not given, but
        the naive baseline (``mode="naive"``) keeps the caller's settings and no preset.

    Raises
    ------
    PresetClashError
        A named preset and given fields it sets.
    ConfigError
        A named preset that does not go with the naive baseline.
    """
    if chosen is not None:
        clash = PRESETS[chosen].conflicts(given)
        if clash:
            raise PresetClashError(chosen, clash)
        return (*PRESETS[chosen].apply(exchange, store), chosen)
    if exchange.mode == "naive":
        return exchange, store, None
    ex, st = PRESETS[DEFAULT_PRESET].apply(exchange, store)
    ex = replace(ex, **{f.name: getattr(exchange, f.name) for f in fields(ex) if f.name in given})
    st = replace(st, **{f.name: getattr(store, f.name) for f in fields(st) if f.name in given})
    return ex, st, DEFAULT_PRESET
