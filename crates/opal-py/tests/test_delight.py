"""opal.delight: a tiny de-lighting of the test Cornell box (3 views of 24², 16² textures)
gives the CLI's albedo textures bit for bit; bad input raises with the CLI's message."""

import json
import subprocess

import numpy as np
import pytest

import opal
from conftest import sensor_to_world, small_cbox

OPTS = dict(resolution=16, light_paths=100000, iterations=2, rerender_spp=0)
FOV_X_DEG = [39.3077, 45.0, 45.0]


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    d = tmp_path_factory.mktemp("delight")
    xml = small_cbox(d, 24)
    scene = opal.load_scene(xml)
    frames = []
    for i, m in enumerate(sensor_to_world(xml)[:3]):
        img = scene.render(spp=16, seed=3, sensor=i)
        opal.write_exr(d / f"v{i}.exr", img)
        gl = m @ np.diag([-1.0, 1.0, -1.0, 1.0])  # Mitsuba camera axes → OpenGL's
        frames.append({"file_path": f"v{i}.exr", "transform_matrix": gl.tolist(),
                       "camera_angle_x": np.radians(FOV_X_DEG[i]), "w": 24, "h": 24})
    tj = d / "transforms.json"
    tj.write_text(json.dumps({"frames": frames}))
    return xml, tj


def test_delight_equals_cli(views, cli, tmp_path):
    xml, tj = views
    r = opal.delight(opal.load_scene(xml), tj, seed=1, **OPTS)
    assert r.albedo, "some object recovered"
    for oid, tex in r.albedo.items():
        assert tex.ndim == 3 and tex.shape[2] == 3 and tex.dtype == np.float32
    assert r.output is None and isinstance(r.log, list)
    assert [o["id"] for o in r.objects] == list(r.albedo)
    out = tmp_path / "cli"
    subprocess.run(
        [cli, "delight", "--scene", str(xml), "--views", str(tj), "-o", str(out), "--resolution", "16",
         "--light-paths", "100000", "--iterations", "2", "--rerender-spp", "0", "--seed", "1", "--quiet"],
        check=True, capture_output=True,
    )
    for oid, tex in r.albedo.items():
        ref = opal.read_exr(out / "albedo" / f"{oid}.exr")
        assert np.array_equal(ref.view(np.uint32), tex.view(np.uint32)), oid
    assert np.isfinite(np.asarray([o["mean_albedo"] for o in r.objects], dtype=float)).all()


def test_delight_output_folder(views, tmp_path):
    xml, tj = views
    r = opal.delight(xml, tj, output=tmp_path / "o", **OPTS)
    assert (tmp_path / "o" / "report.json").exists() and r.output == str(tmp_path / "o")
    assert (tmp_path / "o" / "scene.xml").exists()


def test_bad_input(views, cli, tmp_path):
    xml, tj = views
    cases = [
        (lambda: opal.delight(xml, tmp_path / "missing.json"), ["--views", str(tmp_path / "missing.json"), "--scene", str(xml)]),
        (lambda: opal.delight(xml, tj, update="magic"), ["--views", str(tj), "--scene", str(xml), "--update", "magic"]),
        (lambda: opal.delight(xml, tj, objects=["nope"], **OPTS),
         ["--views", str(tj), "--scene", str(xml), "--objects", "nope", "--resolution", "16"]),
    ]
    for call, args in cases:
        with pytest.raises(opal.OpalError) as e:
            call()
        r = subprocess.run([cli, "delight", "-o", str(tmp_path / "o2"), *args], capture_output=True, text=True)
        assert r.returncode == 2, r.stderr
        assert f"error: {e.value}" in r.stderr
