import base64
import json
import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pytest

from spidermatch.data.synthetic import creature_pair_ground_truth, make_creature
from spidermatch.report.colours import position_colours
from spidermatch.report.viewer import ViewerMesh, save_match_viewer, save_viewer_html


@pytest.fixture(scope="module")
def creatures():
    source, target = make_creature(600, seed=0), make_creature(600, seed=1)
    return source.mesh, target.mesh, creature_pair_ground_truth(source, target)


class PageParts(HTMLParser):
    """Collects the tags, the script bodies and any attribute that points elsewhere."""

    def __init__(self):
        super().__init__()
        self.tags, self.scripts, self.links, self._in_script = [], [], [], None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self.links += [value for name, value in attrs if name in ("src", "href") and value]
        if tag == "script":
            self._in_script = dict(attrs).get("id", "")
            self.scripts.append([self._in_script, ""])

    def handle_endtag(self, tag):
        if tag == "script":
            self._in_script = None

    def handle_data(self, data):
        if self._in_script is not None:
            self.scripts[-1][1] += data


def page_data(path) -> dict:
    parts = PageParts()
    parts.feed(path.read_text(encoding="utf-8"))
    assert parts.links == []
    (payload,) = [body for name, body in parts.scripts if name == "match-data"]
    return json.loads(payload)


def decode(text: str, dtype) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype=dtype)


@pytest.mark.parametrize("form", ["dense", "pairs"])
def test_viewer_is_self_contained_and_holds_both_meshes(tmp_path, creatures, form):
    source, target, truth = creatures
    matches = truth if form == "dense" else np.stack([np.arange(source.n_verts), truth], axis=1)[::5]
    path = save_match_viewer(source, target, matches, tmp_path / "viewer.html", "a -> b", "optimal, gap 0")
    text = path.read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text
    data = page_data(path)
    assert data["title"] == "a -> b" and data["status"] == "optimal, gap 0"
    for entry, mesh in zip(data["meshes"], (source, target)):
        positions = decode(entry["positions"], "<f4").reshape(-1, 3)
        faces = decode(entry["faces"], "<u2" if entry["index_bytes"] == 2 else "<u4").reshape(-1, 3)
        np.testing.assert_allclose(positions, mesh.verts, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(faces, mesh.faces)
        colours = decode(entry["layers"]["colour transfer"], np.uint8).reshape(-1, 3)
        assert colours.shape == (mesh.n_verts, 3)
    source_colours = decode(data["meshes"][0]["layers"]["colour transfer"], np.uint8).reshape(-1, 3)
    np.testing.assert_allclose(source_colours / 255, position_colours(source.verts), atol=1 / 255)


def test_viewer_greys_the_target_region_a_part_does_not_cover(tmp_path, creatures):
    source, target, truth = creatures
    covered = target.verts[:, 1] > np.median(target.verts[:, 1])
    path = save_match_viewer(
        source, target, truth, tmp_path / "v.html", "part", "optimal", target_covered=covered
    )
    data = page_data(path)
    target_colours = decode(data["meshes"][1]["layers"]["colour transfer"], np.uint8).reshape(-1, 3) / 255
    spread = target_colours.max(axis=1) - target_colours.min(axis=1)
    assert spread[~covered].max() < 0.2 and spread[covered].max() > 0.3
    assert "not covered" in json.dumps(data)


def test_viewer_error_layer_and_a_title_that_could_break_the_page(tmp_path, creatures):
    source, target, truth = creatures
    title = "</script><script>alert(1)</script> & <b>"
    errors = (np.arange(0, source.n_verts, 3), np.linspace(0, 0.3, len(range(0, source.n_verts, 3))))
    path = save_match_viewer(source, target, truth, tmp_path / "v.html", title, "feasible", errors=errors)
    data = page_data(path)
    assert data["title"] == title
    assert data["layer_names"] == ["colour transfer", "texture", "error"]  # a dense map: the texture too
    assert "mean 0.1500" in data["layer_notes"]["error"]
    assert path.read_text().count("<script") == 2


def test_viewer_refuses_colours_of_the_wrong_shape(tmp_path, creatures):
    source, target, _ = creatures
    good = ViewerMesh("source", source, {"c": np.zeros((source.n_verts, 3))})
    bad = ViewerMesh("target", target, {"c": np.zeros((3, 3))})
    with pytest.raises(ValueError, match=r"colour layer 'c' of 'target' has shape \(3, 3\)"):
        save_viewer_html((good, bad), tmp_path / "v.html")
    with pytest.raises(ValueError, match="two meshes"):
        save_viewer_html((good,), tmp_path / "v.html")


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
RENDERER_FLAGS = {
    "webgl": ["--use-gl=swiftshader", "--enable-unsafe-swiftshader"],
    "canvas2d": ["--disable-3d-apis"],
}


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install -y chromium)")
@pytest.mark.parametrize("renderer", sorted(RENDERER_FLAGS))
def test_headless_chromium_screenshot_shows_both_meshes(tmp_path, creatures, renderer):
    import matplotlib.image

    source, target, truth = creatures
    page = save_match_viewer(source, target, truth, tmp_path / "viewer.html", "synthetic pair", "optimal")
    command = [CHROMIUM, "--headless", "--no-sandbox", "--hide-scrollbars", "--window-size=1000,600"]
    command += RENDERER_FLAGS[renderer] + [f"--user-data-dir={tmp_path / 'profile'}"]
    # headless Chromium may take its screenshot before a software-rendered frame is drawn on a
    # busy machine: take up to three, the first that shows a drawn page counts
    for attempt in range(3):
        shot = tmp_path / f"shot{attempt}.png"
        budget = ["--virtual-time-budget=10000", f"--screenshot={shot}", page.as_uri()]
        subprocess.run(command + budget, capture_output=True, timeout=120, check=False)
        assert shot.exists(), "chromium wrote no screenshot"
        image = matplotlib.image.imread(shot)[:, :, :3]
        if image.std() > 0.05:
            break
    coloured = image.max(axis=2) - image.min(axis=2) > 0.2
    assert image.std() > 0.05
    half = image.shape[1] // 2
    for side in (coloured[:, :half], coloured[:, half:]):
        assert side.mean() > 0.03, "a half of the page shows no mesh"
