"""The layout a recording opens with, read back from the file: the blueprint sent active and
default, its fixed camera, the collapsed time panel, the panels (made from the signal table)."""

from __future__ import annotations

import re
import subprocess
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import ROOT
from rerun.chunk import RrdReader
from test_record import PENDULUM, RERUN_CLI, SLIDER, example2, read_entities, temporal

from qcontrol.recording import Recording, styles
from qcontrol.recording.camera import FIELD_OF_VIEW_Y, FRAME_MARGIN, TRAVEL_MARGIN, VIEW_WIDTH_PER_HEIGHT
from qcontrol.recording.styles import Plot

COLLAPSED = 2  # rerun.blueprint.components.PanelState


def activations(path: Path) -> list[tuple[str, bool, bool]]:
    """(blueprint id, make_active, make_default) of every activation command, in file order."""
    if not RERUN_CLI.exists():
        pytest.skip("the rerun CLI is not installed in this environment")
    printed = subprocess.run([str(RERUN_CLI), "rrd", "print", str(path)], capture_output=True, text=True,
                             timeout=60, check=True).stdout
    found = re.findall(r'BlueprintActivationCommand\(StoreId\(Blueprint, "[^"]*", "([^"]+)"\), '
                       r"make_active: (\w+), make_default: (\w+)\)", printed)
    return [(store, active == "true", default == "true") for store, active, default in found]


def active_blueprint(path: Path) -> dict[str, dict[str, list]]:
    """The blueprint the file activates last, as {entity: {component: value}}."""
    store_id = activations(path)[-1][0]
    reader = RrdReader(path)
    (store,) = [b for b in reader.blueprints() if b.recording_id == store_id]
    entities: dict[str, dict[str, list]] = defaultdict(dict)
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        for column in batch.column_names:
            if ":" in column:
                entities[chunk.entity_path.lstrip("/")][column] = batch.column(column).to_pylist()[0]
    return entities


def views(blueprint: dict[str, dict[str, list]]) -> dict[str, tuple[str, str, str]]:
    """{display name: (view entity, class, origin)} of the blueprint's views."""
    return {c["ViewBlueprint:display_name"][0]: (e, c["ViewBlueprint:class_identifier"][0],
                                                 c["ViewBlueprint:space_origin"][0])
            for e, c in blueprint.items() if "ViewBlueprint:display_name" in c}


def eye(blueprint: dict[str, dict[str, list]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    (entity, kind, _) = views(blueprint)["motion"]
    assert kind == "3D"
    controls = blueprint[f"{entity}/EyeControls3D"]
    return tuple(np.asarray(controls[f"EyeControls3D:{k}"][0]) for k in ("position", "look_target", "eye_up"))


@pytest.fixture(scope="module")
def compare_file(tmp_path_factory) -> tuple[Path, mujoco.MjModel]:
    path = tmp_path_factory.mktemp("layout") / "compare.rrd"
    model = mujoco.MjModel.from_xml_string(PENDULUM)
    with Recording(path) as rec:
        main = example2(1.0, rec.observer("mujoco", model, "hinge"))
        example2(1.0, rec.observer("ode", model, "hinge", ghost=True, twin_of=main))
    return path, model


def test_every_layout_is_sent_active_and_default(compare_file):
    """So that the web viewer and a viewer already open show it, not rerun's automatic layout. A
    recording that only writes a file sends it once, when it closes, with the twin's panels
    (the test below finds them), not once per change as it does for a live viewer."""
    found = activations(compare_file[0])
    assert len(found) == 1
    assert all(active and default for _, active, default in found)
    stores = {b.recording_id for b in RrdReader(compare_file[0]).blueprints()}
    assert {store for store, _, _ in found} == stores


def test_time_panel_collapsed_panels_and_their_views(compare_file):
    blueprint = active_blueprint(compare_file[0])
    assert blueprint["time_panel"]["TimePanelBlueprint:state"] == [COLLAPSED]
    assert blueprint["time_panel"]["TimePanelBlueprint:timeline"] == ["sim_time"]
    origins = {origin for _, _, origin in views(blueprint).values()}
    assert {"world", "signals/tracking", "signals/error", "signals/input", "signals/state/x1",
            "signals/state/x2", "signals/quantization/x1", "signals/quantization/x2", "signals/adaptive",
            "theory/lemma2", "signals/difference/y", "signals/difference/u", "info/constants"} <= origins
    lemma2 = next(e for e, _, origin in views(blueprint).values() if origin == "theory/lemma2")
    low, high = blueprint[f"{lemma2}/ScalarAxis"]["ScalarAxis:range"][0]
    assert low == 0 and 1.05 <= high <= 1.2  # the bound 1 is a line inside the plot, not its border
    tabs = [c for c in blueprint.values() if "ContainerBlueprint:active_tab" in c]
    (front,) = [blueprint[c["ContainerBlueprint:active_tab"][0]] for c in tabs]
    assert front["ContainerBlueprint:display_name"] == ["twin difference"]


def test_hinge_camera_looks_along_the_axis_and_frames_the_arm_circle(compare_file):
    """The model gives MuJoCo's default view (45 degrees down), far from the plane of motion: the
    eye is turned onto the hinge axis, at the anchor, just far enough for the whole circle."""
    path, model = compare_file
    position, target, up = eye(active_blueprint(path))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    anchor, axis = data.xanchor[0], data.xaxis[0]
    bob = model.geom("bob").id
    reach = np.linalg.norm(data.geom_xpos[bob] - anchor) + model.geom_size[bob][0]
    np.testing.assert_allclose(target, anchor, atol=1e-9)
    offset = position - target
    np.testing.assert_allclose(offset / np.linalg.norm(offset), -axis, atol=1e-9)
    half_height = np.linalg.norm(offset) * np.tan(FIELD_OF_VIEW_Y / 2)
    assert half_height == pytest.approx(FRAME_MARGIN * reach)
    np.testing.assert_array_equal(up, [0, 0, 1])
    grid = active_blueprint(path)[f"{views(active_blueprint(path))['motion'][0]}/LineGrid3D"]
    assert grid["LineGrid3D:visible"] == [False]


def test_model_view_direction_is_kept_when_it_sees_the_plane_of_motion(tmp_path):
    """models/pendulum.xml asks for azimuth 90, elevation -10: within 20 degrees of the axis."""
    model = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "pendulum.xml"))
    path = tmp_path / "pendulum.rrd"
    with Recording(path) as rec:
        example2(0.1, rec.observer("mujoco", model, "hinge"))
    position, target, _ = eye(active_blueprint(path))
    direction = (target - position) / np.linalg.norm(target - position)
    np.testing.assert_allclose(direction, [0, np.cos(np.radians(10)), -np.sin(np.radians(10))], atol=1e-9)


def test_slide_camera_frames_the_travelled_interval_not_the_rail(tmp_path):
    """Streamed in 500-row chunks the first rows travel less than the run: the layout, sent at
    the close, has a camera that frames all positions (and the target's) with a margin; the 4 m
    rail is not framed whole."""
    path = tmp_path / "slider.rrd"
    model = mujoco.MjModel.from_xml_string(SLIDER)
    with Recording(path) as rec:
        run = example2(2.0, rec.observer("mujoco", model), observe_every=500)
    assert len(activations(path)) == 1
    position, target, _ = eye(active_blueprint(path))
    low = min(run.y.min(), run.yd[:, 0].min())
    high = max(run.y.max(), run.yd[:, 0].max())
    cart_half_length = 0.1
    reach = (high - low) * (0.5 + TRAVEL_MARGIN) + cart_half_length  # the whole cart at either end
    assert target[0] == pytest.approx((low + high) / 2)
    half_width = np.linalg.norm(position - target) * np.tan(FIELD_OF_VIEW_Y / 2) * VIEW_WIDTH_PER_HEIGHT
    assert reach < half_width < 2.0  # the interval fits; the rail's half-length (2 m) does not
    entities = read_entities(path)
    _, cart = temporal(entities["world/bodies/cart"], "Transform3D:translation")
    assert np.all(np.abs(cart[:, 0] - target[0]) < half_width)


def test_no_model_no_3d_view(tmp_path):
    """A run with nothing drawn in 3-D (an ODE-only scenario such as chain3) gets no empty 3-D view."""
    path = tmp_path / "ode.rrd"
    with Recording(path) as rec:
        example2(0.1, rec.observer("ode"))
    kinds = {kind for _, kind, _ in views(active_blueprint(path)).values()}
    assert "3D" not in kinds and "TimeSeries" in kinds


def test_a_new_plot_lands_in_its_panel_or_a_tab_of_its_own(tmp_path, monkeypatch):
    """A series added to the signal table under an existing panel (e.g. an applied torque beside
    the commanded u) is drawn in that panel's view; one under a new panel gets a view of its own."""
    extra = (Plot("signals/input/u_again", "u again"), Plot("signals/extra/u", "u again"))
    monkeypatch.setitem(styles.PLOTS, "u", styles.PLOTS["u"] + extra)
    path = tmp_path / "extra.rrd"
    with Recording(path) as rec:
        run = example2(0.1, rec.observer("ode"))
    entities = read_entities(path)
    for added in ("signals/input/u_again", "signals/extra/u"):
        _, values = temporal(entities[added], "Scalars:scalars")
        np.testing.assert_array_equal(values[:, 0], run.u)
    found = views(active_blueprint(path))
    assert found["input u"][2] == "signals/input"  # shows everything under signals/input
    assert found["signals/extra"][2] == "signals/extra"


def test_a_panel_of_one_value_gets_a_range_and_a_varying_one_does_not(tmp_path: Path) -> None:
    """rerun labels a constant series' axis with one tick: such a panel gets value -+ 1 when the
    recording closes; a panel whose values vary keeps rerun's own fit."""
    from qcontrol.recording.layout import default_blueprint
    from qcontrol.recording.series import Panel

    flat, varying = Panel("signals/input", "signals/input"), Panel("signals/tracking", "signals/tracking")
    with Recording(tmp_path / "r.rrd") as rec:
        rec.see_values(flat, np.zeros(50))
        rec.see_values(flat, np.array([0.0, np.nan]))
        rec.see_values(varying, np.linspace(-1.0, 1.0, 50))
        ranges = rec._flat_ranges()
    assert ranges == {flat: (-1.0, 1.0)}
    views = default_blueprint([flat, varying], None, None, ranges).root_container.contents[1].contents
    axes = {view.origin: view for view in views}
    assert "[[-1.0, 1.0]]" in repr(axes["signals/input"].properties["ScalarAxis"])
    assert "ScalarAxis" not in axes["signals/tracking"].properties
