"""``--video``: MuJoCo's own rendering of a run, headless; the physics does not change.

Frames are few and tiny here (a 64 x 48 video of a fraction of a second) to keep the suite fast.
Tests that render are skipped, with the reason, on a machine without an offscreen OpenGL library
(CI installs one: .ci/run).
"""

import json
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import ROOT

from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError
from qcontrol.render import context
from qcontrol.render.frames import FrameRenderer, Instant, camera_id
from qcontrol.render.video import frame_rows

EX1, EX2 = ROOT / "scenarios" / "example1.toml", ROOT / "scenarios" / "example2.toml"
CHAIN3 = ROOT / "scenarios" / "chain3.toml"


def _gl_missing() -> str | None:
    try:
        context.require_offscreen_gl()
        import imageio_ffmpeg  # noqa: F401
    except (QcontrolInputError, ImportError) as exc:
        return str(exc)
    return None


_MISSING = _gl_missing()
needs_gl = pytest.mark.skipif(_MISSING is not None, reason=f"no offscreen rendering here: {_MISSING}")


def _frames(path: Path) -> list[np.ndarray]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    return [np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in reader]


def _numbers(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in ("wall_time_s", "provenance")}


@needs_gl
def test_run_video_has_a_frame_per_instant_and_same_summary(tmp_path, capsys):
    plain, filmed, video = tmp_path / "plain", tmp_path / "filmed", tmp_path / "run.mp4"
    common = ["run", str(EX2), "--duration", "0.3", "-q"]
    assert main([*common, "--out", str(plain)]) == 0
    assert main([*common, "--out", str(filmed), "--video", str(video), "--video-fps", "10",
                 "--video-size", "64x48"]) == 0
    assert "per simulated second" in capsys.readouterr().out
    a = json.loads((plain / "summary.json").read_text())
    b = json.loads((filmed / "summary.json").read_text())
    assert _numbers(a) == _numbers(b)  # rendering only reads the trajectory
    frames = _frames(video)
    assert len(frames) == 4  # t = 0, 0.1, 0.2, 0.3 s
    assert frames[0].shape == (48, 64, 3)
    assert not np.array_equal(frames[0], frames[-1])  # the arm moved (and the overlay's t changed)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary left


@needs_gl
def test_compare_gif_draws_the_twin(tmp_path):
    video = tmp_path / "cmp.gif"
    assert main(["compare", str(EX1), "--duration", "0.2", "-q", "--video", str(video),
                 "--video-fps", "10", "--video-size", "64x48"]) == 0
    assert video.read_bytes()[:6] == b"GIF89a"
    assert len(_frames(video)) == 3


@needs_gl
def test_renderer_poses_the_model_and_draws_the_ghost():
    model = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "pendulum.xml"))
    with FrameRenderer(model, "hinge", camera_id(model, "front", "pendulum"), 80, 60) as renderer:
        down = renderer.render(Instant(0.0, 0.0, 0.0, 0.0, 0.0)).copy()
        turned = renderer.render(Instant(0.0, 1.2, 1.2, 0.0, 0.0)).copy()
        ghost = renderer.render(Instant(0.0, 1.2, 1.2, 0.0, 0.0, twin_x1=-1.2)).copy()
    assert down.shape == (60, 80, 3) and down.std() > 5  # a scene, not a blank frame
    assert np.mean(np.any(down != turned, axis=2)) > 0.005
    assert np.mean(np.any(ghost != turned, axis=2)) > 0.005


def test_frame_rows_sample_simulated_time():
    from qcontrol.engine import Trajectory  # noqa: F401  (the rows depend only on t)

    class Run:
        t = np.arange(1001) * 1e-3  # 1 s at dt = 1 ms

    assert frame_rows(Run, 30.0)[:4].tolist() == [0, 33, 66, 100]
    assert len(frame_rows(Run, 30.0)) == 31 and frame_rows(Run, 30.0)[-1] == 1000


@pytest.mark.parametrize("args, expected", [
    (["--video", "run.avi"], "give a .mp4 or .gif"),
    (["--video", "run.mp4", "--video-fps", "0"], "--video-fps must be > 0"),
    (["--video", "run.mp4", "--video-fps", "1e-9"], "must be 1 to 240 frames per simulated second"),
    (["--video", "run.mp4", "--video-fps", "1e9"], "must be 1 to 240 frames per simulated second"),
    (["--video", "run.mp4", "--video-fps", "240", "--duration", "200"], "48,001 frames, more than"),
    (["--video", "run.mp4", "--video-camera", "nope"], "no camera of that name"),
])
def test_bad_video_request_exit_2_before_the_run(tmp_path, capsys, args, expected):
    args = [a if not a.startswith("run.") else str(tmp_path / a) for a in args]
    assert main(["run", str(EX2), "--duration", "0.1", "-q", *args]) == 2
    captured = capsys.readouterr()
    assert expected in captured.err and len(captured.err.strip().splitlines()) == 1
    assert captured.out == ""  # refused before the run
    assert list(tmp_path.iterdir()) == []


def test_video_of_a_scenario_without_model_exit_2(tmp_path, capsys):
    assert main(["run", str(CHAIN3), "-q", "--video", str(tmp_path / "x.mp4")]) == 2
    assert "no MuJoCo model to render" in capsys.readouterr().err


def test_missing_gl_names_the_package(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(context, "_candidates", lambda: [])
    context._context_class.cache_clear()
    try:
        assert main(["run", str(EX2), "-q", "--video", str(tmp_path / "x.mp4")]) == 2
    finally:
        context._context_class.cache_clear()
    err = capsys.readouterr().err
    assert "libegl1" in err and "apt-get install" in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def _views(container) -> list:
    """The views of a layout, depth first."""
    import rerun.blueprint as rrb

    found = []
    for item in container.contents:
        found += _views(item) if isinstance(item, rrb.Container) else [item]
    return found


@needs_gl
def test_recording_holds_the_camera_view_beside_the_3d_view(tmp_path):
    from rerun.chunk import RrdReader

    from qcontrol.recording.layout import default_blueprint

    rrd = tmp_path / "run.rrd"
    assert main(["run", str(EX2), "--duration", "0.2", "-q", "--rrd", str(rrd), "--camera-view"]) == 0
    times, blobs = [], 0
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path.lstrip("/") == "camera/front":
            batch = chunk.to_record_batch()
            times += batch.column("sim_time").cast("int64").to_pylist()
            blob = next(c for c in batch.column_names if c.lower().endswith("blob"))
            blobs += sum(1 for b in batch.column(blob).to_pylist() if b and bytes(b[0][:2]) == b"\xff\xd8")
    # 15 frames per simulated second, each at the row it shows: 0, 66, 133 and 200 ms
    assert times == [0, 66_000_000, 133_000_000, 200_000_000] and blobs == 4  # JPEG files
    layout = default_blueprint([], None, "camera/front")
    assert [(type(v).__name__, v.origin) for v in _views(layout.root_container)][0] == (
        "Spatial2DView", "camera/front")  # the first view: top left


def test_camera_view_needs_a_recording(capsys):
    assert main(["run", str(EX2), "-q", "--camera-view"]) == 2
    assert "add --rrd FILE" in capsys.readouterr().err


def _across(model: mujoco.MjModel, data: mujoco.MjData, camera: int, point: np.ndarray,
            aspect: float) -> float:
    """Where ``point`` falls across camera ``camera``'s picture: -1 its left edge, 1 its right."""
    seen = data.cam_xmat[camera].reshape(3, 3).T @ (point - data.cam_xpos[camera])
    assert seen[2] < 0  # in front of the camera (it looks along its -z)
    return seen[0] / -seen[2] / (np.tan(np.radians(model.cam_fovy[camera]) / 2) * aspect)


@pytest.mark.parametrize(("camera", "low", "high"), [("side", -1.1, 1.4), ("track", -20.0, 20.0)])
def test_cart_cameras_keep_the_whole_cart_inside_the_picture(camera, low, high):
    """The slide's `side` camera frames the travel its model states whole (the shipped runs go
    from -0.81 m to 1.11 m), with a margin; `track` follows the cart wherever it goes. Checked by
    projecting the cart's ends, at 4:3 (the default video size), with the model posed as the
    renderer poses it (kinematics and mj_camlight)."""
    model = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "slider.xml"))
    data = mujoco.MjData(model)
    cid, cart = camera_id(model, camera, "slider.xml"), model.geom("cart_body")
    for x in np.linspace(low, high, 7):
        data.qpos[0] = x
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_camlight(model, data)
        for end in (-1, 1):
            point = data.geom_xpos[cart.id] + end * np.array([cart.size[0], 0.0, 0.0])
            assert abs(_across(model, data, cid, point, 4 / 3)) <= 0.9, (camera, x, end)


_VIDEO_RUN = ["run", str(EX2), "--duration", "0.3", "-q"]
_SMALL_VIDEO = ["--video-fps", "10", "--video-size", "64x48"]


def _run_video(cwd: Path, target: str, *extra: str) -> subprocess.CompletedProcess:
    argv = [sys.executable, "-m", "qcontrol.cli", *_VIDEO_RUN, "--video", target, *_SMALL_VIDEO, *extra]
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=300, check=False)


@needs_gl
def test_a_full_disk_keeps_the_previous_video(small_disk, tmp_path):
    """The encoder cannot finish the new video: exit 3, one line, the previous video as it was and
    still playable, no temporary left."""
    previous = small_disk / "prev.mp4"  # (made here: only the run that fails the disk is a process)
    assert main(_VIDEO_RUN + ["--video", str(previous), *_SMALL_VIDEO]) == 0
    before = previous.read_bytes()
    (small_disk / "ballast").write_bytes(b"\0" * (64 * 1024 - 4096 - len(before)))
    proc = _run_video(tmp_path, str(previous), "--video-size", "320x240", "--duration", "2")
    assert proc.returncode == 3, proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "no space left" in err and "nothing was replaced" in err, err
    assert "wrote" not in proc.stdout
    assert previous.read_bytes() == before and len(_frames(previous)) == 4
    assert sorted(p.name for p in small_disk.iterdir()) == ["ballast", "prev.mp4"]


@needs_gl
def test_an_encoder_that_fails_replaces_nothing(tmp_path, monkeypatch, capsys):
    """ffmpeg refusing its arguments (its exit status) is a write error: exit 3, the file kept."""
    from qcontrol.render import video

    target = tmp_path / "v.mp4"
    target.write_bytes(b"a previous video")
    real = video._encoder_command
    monkeypatch.setattr(video, "_encoder_command",
                        lambda *a: [*real(*a)[:-1], "-no-such-option", str(a[0])])
    assert main(["run", str(EX2), "--duration", "0.2", "-q", "--video", str(target), "--video-fps", "10",
                 "--video-size", "64x48"]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot write the video" in err and "exit status" in err, err
    assert target.read_bytes() == b"a previous video"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


@needs_gl
def test_the_video_folder_is_made_like_saves(tmp_path, capsys):
    target = tmp_path / "new" / "sub" / "v.gif"
    assert main(["run", str(EX2), "--duration", "0.2", "-q", "--video", str(target), "--video-fps", "10",
                 "--video-size", "64x48"]) == 0
    assert len(_frames(target)) == 3
