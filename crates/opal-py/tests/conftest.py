"""Shared fixtures of the opal Python tests: paths of the repository's test data and the CLI."""

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]
CBOX = ROOT / "crates" / "opal" / "tests" / "data" / "cbox" / "scene.xml"


@pytest.fixture(scope="session")
def cli():
    """The `opal` binary built by run-tests.sh (OPAL_CLI), else one on PATH."""
    exe = os.environ.get("OPAL_CLI") or shutil.which("opal")
    if not exe or not os.path.exists(exe):
        pytest.fail("set OPAL_CLI to the opal binary (run-tests.sh does)")
    return exe


@pytest.fixture(scope="session")
def cbox():
    return CBOX


def small_cbox(dir: Path, res: int) -> Path:
    """The test Cornell box with every sensor at res × res (meshes and textures by absolute path)."""
    text = CBOX.read_text()
    text = re.sub(r'(<integer name="(?:width|height)" value=")256(")', rf"\g<1>{res}\2", text)
    text = re.sub(r'(name="filename" value=")([^"/][^"]*)"', lambda m: f'{m.group(1)}{CBOX.parent / m.group(2)}"', text)
    p = dir / "scene.xml"
    p.write_text(text)
    return p


def sensor_to_world(scene_xml: Path):
    """The sensors' to_world matrices (the test scene gives them as <matrix>)."""
    text = scene_xml.read_text()
    out = []
    for m in re.finditer(r'<sensor .*?<matrix value="([^"]+)"', text, re.S):
        out.append(np.array([float(x) for x in m.group(1).split()]).reshape(4, 4))
    return out
