"""The layout a recording opens with (a rerun blueprint), made from the panels its series fill.

Right (three fifths of the width, so that a 10 s time axis has a label every second at
1600 x 1000): the panels of :data:`PANELS` placed in the ``column``, top to bottom (y with y_d,
the tracking error z1, the input u). Left: the 3-D view ``world`` (everything under ``world/``,
seen from the fixed camera of :mod:`.camera`; left out when nothing is drawn in 3-D), beside it
MuJoCo's own rendering when the recording holds one (``camera/<name>``), over tabs,
one per group of panels (stacked in the tab): for each x_i, x_i with q(x_i) over the quantization
error with its band +-delta/2; the adaptive estimates; Lemma 2's ratios; a twin's differences;
then the controller constants, the scenario text and the version. A panel that is not in
:data:`PANELS` (a series someone added to the signal table under a new path) gets a tab of its
own, titled by its path. The time panel is collapsed to its play bar.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from .camera import Camera
from .series import TIMELINE, Panel

if TYPE_CHECKING:
    import rerun.blueprint as rrb

COLUMN = "column"


@dataclass(frozen=True)
class PanelStyle:
    """How the layout shows a panel: its ``title`` (``{i}``: the component's number), its
    ``group`` (``"column"``: a row of the right column; otherwise the tab it shares, stacked, with
    the other panels of that group), a fixed initial range of its y axis, if any, and its
    ``height`` relative to the other panels of its column or tab."""

    title: str
    group: str
    y_range: tuple[float, float] | None = None
    height: float = 1.0


PANELS: dict[str, PanelStyle] = {  # keyed by panel (a series path's parent), in the layout's order
    "signals/tracking": PanelStyle("output y and reference y_d", COLUMN),
    "signals/error": PanelStyle("tracking error z1 = y - y_d", COLUMN, height=1.4),  # the finest detail
    "signals/input": PanelStyle("input u", COLUMN),
    "signals/state/x{i}": PanelStyle("x{i} and its quantized reading q(x{i})", "x{i}"),
    "signals/quantization/x{i}": PanelStyle(
        "quantization error x{i} - q(x{i}) of the reading, band +-delta/2", "x{i}"),
    "signals/adaptive": PanelStyle("adaptive estimates", "adaptive"),
    "theory/lemma2": PanelStyle("Lemma 2: |e_zi| / L_zi <= 1 at every step (the bound 1: red line)",
                                "Lemma 2", (0.0, 1.1)),
    "theory/law": PanelStyle("law diagnostics", "Lemma 2"),  # titled by the law's own (styles.PLOTS)
    "signals/difference/y": PanelStyle("log10 |y - y_twin|: the main run against its twin (-16: equal to "
                                       "rounding)", "twin difference", (-17.0, 1.0)),
    "signals/difference/u": PanelStyle("log10 |u - u_twin| (-16: equal to rounding)", "twin difference",
                                       (-17.0, 3.0)),
}
FRONT_TABS = ("twin difference", "x1")  # the first of these present is the tab shown on opening


def _style(panel: Panel) -> PanelStyle:
    style = PANELS.get(panel.key)
    if style is None:
        return PanelStyle(panel.origin, panel.origin.rsplit("/", 1)[-1])
    title = panel.title or style.title.format(i=panel.index)
    return PanelStyle(title, style.group.format(i=panel.index), style.y_range, style.height)


def _order(panel: Panel) -> tuple[int, int, str]:
    keys = list(PANELS)
    return (keys.index(panel.key) if panel.key in keys else len(keys), panel.index, panel.origin)


def _plot(panel: Panel, style: PanelStyle) -> rrb.TimeSeriesView:
    import rerun.blueprint as rrb

    axis = None if style.y_range is None else rrb.ScalarAxis(range=style.y_range)
    return rrb.TimeSeriesView(origin=panel.origin, name=style.title, axis_y=axis,
                              plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop))


def _motion(camera: Camera) -> rrb.Spatial3DView:
    import rerun.blueprint as rrb

    eye = rrb.EyeControls3D(position=camera.position, look_target=camera.look_target, eye_up=camera.eye_up)
    return rrb.Spatial3DView(origin="world", name="motion", eye_controls=eye,
                             line_grid=rrb.LineGrid3D(visible=False))


def _camera_view(origin: str) -> rrb.Spatial2DView:
    import rerun.blueprint as rrb

    return rrb.Spatial2DView(origin=origin, name="MuJoCo render")


def default_blueprint(panels: Sequence[Panel], camera: Camera | None,
                      camera_view: str | None = None,
                      ranges: Mapping[Panel, tuple[float, float]] | None = None) -> rrb.Blueprint:
    """The layout for a recording whose series fill ``panels`` (in any order, repeats allowed),
    with the 3-D view seen from ``camera`` (None: no 3-D view) and, with ``camera_view`` (an
    entity holding MuJoCo's rendered frames), that picture beside it. ``ranges`` fixes the y axis
    of panels (those whose values are all one number: rerun would show one tick)."""
    import rerun.blueprint as rrb

    groups: dict[str, list[tuple[rrb.TimeSeriesView, float]]] = {COLUMN: []}
    for panel in sorted(set(panels), key=_order):
        style = _style(panel)
        if ranges and panel in ranges:
            style = replace(style, y_range=ranges[panel])
        groups.setdefault(style.group, []).append((_plot(panel, style), style.height))
    stacks = {group: rrb.Vertical(*(view for view, _ in views), row_shares=[share for _, share in views],
                                  name=None if group == COLUMN else group)
              for group, views in groups.items()}
    column = stacks.pop(COLUMN)
    tabs = list(stacks.values())  # each named by its group
    tabs += [rrb.TextDocumentView(origin="info/constants", name="constants"),
             rrb.TextDocumentView(origin="info/scenario", name="scenario"),
             rrb.TextDocumentView(origin="info/version", name="version")]
    front = next((list(stacks).index(name) for name in FRONT_TABS if name in stacks), 0)
    details = rrb.Tabs(*tabs, active_tab=front)
    views = ([] if camera is None else [_motion(camera)]) + ([] if camera_view is None else
                                                           [_camera_view(camera_view)])
    top = views[0] if len(views) == 1 else rrb.Horizontal(*views) if views else None
    left = details if top is None else rrb.Vertical(top, details, row_shares=[2, 3])
    return rrb.Blueprint(
        rrb.Horizontal(left, column, column_shares=[2, 3]),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )
