"""opal.load_scene / Scene.render: shapes, the CLI's bits for the same seed, threads, sensors,
progress, Ctrl-C, the GIL, bad input."""

import _thread
import subprocess
import threading
import time

import numpy as np
import pytest

import opal


def bits(a):
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


@pytest.fixture(scope="module")
def scene(cbox):
    return opal.load_scene(cbox)


def test_load_scene_and_sensors(scene, cbox):
    assert isinstance(scene, opal.Scene)
    assert len(scene.sensors) == 8
    assert scene.sensors[0] == ("view_00", 256, 256)
    assert scene.path == str(cbox)
    assert "sensors=8" in repr(scene)


def test_render_shape_and_values(scene):
    img = scene.render(spp=2, seed=1)
    assert img.shape == (256, 256, 3) and img.dtype == np.float32
    assert np.isfinite(img).all() and img.mean() > 0.01


def test_render_equals_cli_bit_for_bit(scene, cbox, cli, tmp_path):
    """Acceptance: scene.render(spp=4, seed=5) equals `opal render scene.xml --spp 4 --seed 5`."""
    out = tmp_path / "cli.exr"
    subprocess.run([cli, "render", str(cbox), "-o", str(out), "--spp", "4", "--seed", "5", "--quiet"], check=True)
    img = scene.render(spp=4, seed=5)
    ref = opal.read_exr(out)
    assert ref.shape == img.shape
    assert np.array_equal(bits(img), bits(ref))
    # and written through opal.write_exr, the very same file bytes
    mine = tmp_path / "py.exr"
    opal.write_exr(mine, img)
    assert mine.read_bytes() == out.read_bytes()


def test_render_options_match_cli(scene, cbox, cli, tmp_path):
    out = tmp_path / "cli.exr"
    args = ["--spp", "3", "--seed", "9", "--max-depth", "3", "--sensor", "view_02", "--threads", "1"]
    subprocess.run([cli, "render", str(cbox), "-o", str(out), *args, "--quiet"], check=True)
    img = scene.render(spp=3, seed=9, max_depth=3, sensor="view_02", threads=1)
    assert np.array_equal(bits(img), bits(opal.read_exr(out)))
    # the sensor by index is the same sensor
    assert np.array_equal(bits(img), bits(scene.render(spp=3, seed=9, max_depth=3, sensor=2)))


def test_render_independent_of_threads_and_seeded(scene):
    a = scene.render(spp=2, seed=3, threads=1)
    b = scene.render(spp=2, seed=3, threads=2)
    c = scene.render(spp=2, seed=4, threads=2)
    assert np.array_equal(bits(a), bits(b))
    assert not np.array_equal(bits(a), bits(c))


def test_render_max_depth_changes_image(scene):
    direct = scene.render(spp=2, seed=1, max_depth=2)
    full = scene.render(spp=2, seed=1, max_depth=-1)
    assert full.mean() > direct.mean()


def test_render_report(scene):
    img, rep = scene.render(spp=2, seed=1, report=True)
    assert rep["spp"] == 2 and rep["seed"] == 1 and rep["width"] == 256
    assert rep["sensor"] == "view_00" and rep["seconds"] > 0
    assert np.allclose(rep["mean_rgb"], img.reshape(-1, 3).astype(np.float64).mean(axis=0), rtol=1e-4)


def test_render_default_spp_is_the_sensors(cbox, tmp_path):
    """spp=None: the sensor's sampler (64 in the test scene), as the CLI."""
    scene = opal.load_scene(cbox)
    _, rep = scene.render(seed=0, report=True, sensor=1, max_depth=2)
    assert rep["spp"] == 64


def test_progress_callback(scene):
    calls = []
    scene.render(spp=2, seed=1, progress=lambda stage, done, total: calls.append((stage, done, total)))
    assert calls, "called at least once (at the end)"
    assert calls[-1] == ("render", 256, 256)
    assert all(0 <= d <= t for _, d, t in calls)


def test_progress_callback_exception_stops_render(scene):
    def cb(stage, done, total):
        raise RuntimeError("stop here")

    t0 = time.time()
    with pytest.raises(RuntimeError, match="stop here"):
        scene.render(spp=4096, seed=1, progress=cb)
    assert time.time() - t0 < 30


def test_ctrl_c_interrupts_render(scene):
    """A KeyboardInterrupt (as Ctrl-C raises) stops a long render within seconds."""
    timer = threading.Timer(0.5, _thread.interrupt_main)
    t0 = time.time()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            scene.render(spp=4000, seed=1)
    finally:
        timer.cancel()
    assert time.time() - t0 < 30
    # the next call runs normally (the cancel flag is reset)
    assert scene.render(spp=1, seed=1).mean() > 0


def test_gil_released_during_render(scene):
    ticks = []
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            ticks.append(1)
            time.sleep(0.01)

    t = threading.Thread(target=spin)
    t.start()
    try:
        scene.render(spp=48, seed=1)
    finally:
        stop.set()
        t.join()
    assert len(ticks) > 5, "another Python thread ran while the render worked"


def test_load_scene_parameters(tmp_path):
    p = tmp_path / "s.xml"
    p.write_text(
        """<scene version="3.0.0">
  <default name="res" value="8"/>
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>
  </sensor>
  <shape type="sphere"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
</scene>"""
    )
    assert opal.load_scene(p).sensors[0][1:] == (8, 8)
    s = opal.load_scene(p, res=12)
    assert s.sensors[0][1:] == (12, 12)
    img = s.render(spp=1)
    assert img.shape == (12, 12, 3) and img.max() > 0


def cli_error(cli, args):
    r = subprocess.run([cli, *args], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    return r.stderr


def test_bad_input_raises_with_cli_messages(scene, cbox, cli, tmp_path):
    out = str(tmp_path / "x.exr")
    cases = [
        (lambda: scene.render(spp=0), ["--spp", "0"], "--spp must be at least 1"),
        (lambda: scene.render(spp=1, sensor=99), ["--spp", "1", "--sensor", "99"], "the scene has 8 sensors"),
        (lambda: scene.render(spp=1, sensor="nope"), ["--spp", "1", "--sensor", "nope"], "no sensor with that id"),
    ]
    for call, args, text in cases:
        with pytest.raises(opal.OpalError, match=text) as e:
            call()
        assert isinstance(e.value, ValueError)
        assert f"error: {e.value}" in cli_error(cli, ["render", str(cbox), "-o", out, *args])


def test_bad_scene_files(tmp_path, cli):
    with pytest.raises(opal.OpalError) as e:
        opal.load_scene(tmp_path / "missing.xml")
    assert str(tmp_path / "missing.xml") in str(e.value)
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><shape type='nonsense'/>")
    with pytest.raises(opal.OpalError) as e:
        opal.load_scene(bad)
    assert f"error: {e.value}" in cli_error(cli, ["render", str(bad), "-o", str(tmp_path / "o.exr")])


def test_bad_spp_types(scene):
    for spp in (-1, 1.5, True):
        with pytest.raises(opal.OpalError, match="--spp must be a positive integer"):
            scene.render(spp=spp)
