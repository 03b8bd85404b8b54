"""Foxglove layouts for the recorded and live topics of each layer (``docs/layouts/``).

Built with the Foxglove SDK's layout classes (:mod:`foxglove.layouts`, its layout JSON,
``"version": 1``): a 3D panel in the ``map`` frame with the layer's grids, markers and
trails, beside a plot of its figures. The files in ``docs/layouts/`` are
:func:`write_layouts`'s output (a test keeps them in step).

Examples
--------
>>> import json
>>> json.loads(layout("patrol"))["version"]
1
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

from ..errors import ConfigError

__all__ = ["LAYERS", "layout", "write_layouts"]

#: The layers with a layout, in the order of ``docs/guides/live-view.md``.
LAYERS = ("stream", "patrol", "team")

#: Robots whose topics a layout names (topics of absent robots are simply not drawn).
LAYOUT_ROBOTS = 4


def _three_dee(topics: dict[str, Any], title: str) -> Any:
    import foxglove.layouts as fl

    return fl.ThreeDeePanel(
        title=title,
        config=fl.ThreeDeeConfig(
            follow_tf="map",
            follow_mode="follow-none",
            topics=topics,
            camera_state=fl.ThreeDeeCameraState(perspective=False, distance=60.0),
        ),
    )


def _plot(series: list[str], title: str) -> Any:
    import foxglove.layouts as fl

    return fl.PlotPanel(
        title=title,
        config=fl.PlotConfig(paths=[fl.PlotSeries(value=s) for s in series], show_legend=True),
    )


def _split(main: Any, side: Any) -> Any:
    import foxglove.layouts as fl

    return fl.SplitContainer(
        direction="row",
        items=[fl.SplitItem(proportion=3, content=main), fl.SplitItem(proportion=1, content=side)],
    )


def _grid(
    colour_mode: Literal["map", "costmap", "raw"],
    alpha: float,
    *,
    visible: bool = True,
    behind: bool = True,
) -> Any:
    import foxglove.layouts as fl

    return fl.BaseRendererRosOccupancyGridTopicSettings(
        visible=visible, color_mode=colour_mode, alpha=alpha, draw_behind=behind
    )


def _markers(visible: bool = True) -> Any:
    import foxglove.layouts as fl

    return fl.BaseRendererRosMarkerTopicSettings(visible=visible)


def _trail() -> Any:
    import foxglove.layouts as fl

    return fl.BaseRendererPosesTopicSettings(visible=True, type="line", line_width=0.1)


def layout(layer: str) -> str:
    """The layout JSON of ``layer``: ``stream``, ``patrol`` or ``team``."""
    if layer not in LAYERS:
        raise ConfigError(f"no layout for {layer!r}; layers: {', '.join(LAYERS)}")
    import foxglove.layouts as fl

    robots = range(LAYOUT_ROBOTS)
    if layer == "stream":
        topics: dict[str, Any] = {
            "/map": _grid("map", 1.0),
            "/map_occupancy": _grid("raw", 0.8, visible=False),
        }
        content = _split(
            _three_dee(topics, "the map and the robot"),
            fl.RawMessagesPanel(title="readings", config=fl.RawMessagesConfig(topic_path="/tf")),
        )
    elif layer == "patrol":
        topics = {
            "/map": _grid("map", 1.0),
            "/fog": _grid("costmap", 0.6, behind=False),
            "/robots": _markers(),
            "/network": _markers(),
            "/crowding": _markers(),
            **{f"/robot{k}/path": _trail() for k in robots},
        }
        content = _split(
            _three_dee(topics, "territory, fog, robots and links"),
            _plot(["/mtb.data", "/mean_tb.data"], "time since last seen (s)"),
        )
    else:
        topics = {
            "/map": _grid("map", 0.5),
            **{f"/robot{k}/map": _grid("map", 0.8, visible=k == 0) for k in robots},
            **{f"/robot{k}/graph": _markers(visible=k == 0) for k in robots},
            **{f"/robot{k}/path": _trail() for k in robots},
            "/robots": _markers(),
            "/network": _markers(),
        }
        content = _split(
            _three_dee(topics, "robot 0's global map and pose graph; robots and links"),
            _plot(
                ["/bytes_sent.data", *(f"/robot{k}/bytes_sent.data" for k in robots)],
                "bytes sent",
            ),
        )
    text = fl.Layout(content=content).to_json()
    return json.dumps(json.loads(text), indent=2, sort_keys=True) + "\n"


def write_layouts(folder: str | Path) -> list[Path]:
    """Write ``LAYER.json`` for every layer into ``folder``; the files written."""
    from ..files import atomic_write_text

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in LAYERS:
        p = out / f"{name}.json"
        atomic_write_text(p, layout(name))
        paths.append(p)
    return paths
