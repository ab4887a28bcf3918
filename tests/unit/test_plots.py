"""swarm.view.plots: the Fig. 2 panels are written as real, non-blank PNG files."""

import numpy as np
import pytest
from matplotlib import image

from swarm.core import scenario_file as sf
from swarm.view.plots import TITLES, close_pairs, write_panels
from swarm.core.sim import Recording, Simulation

pytestmark = pytest.mark.unit

NAMES = [f"{stem}.png" for stem in TITLES] + ["fig2.png"]


def _check_pngs(paths, out):
    assert [p.name for p in paths] == NAMES
    for p in paths:
        assert p.parent == out and p.is_file()
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = image.imread(p)
        assert img.ndim == 3 and img.shape[0] >= 300 and img.shape[1] >= 400, (p.name, img.shape)


@pytest.fixture(scope="module")
def small_run():
    scn = sf.load("paper-50hz", sf.Overrides(robots=7, seed=0, duration=5.0))
    return Simulation(scn).run().recording, scn


def test_panels_of_a_small_run(small_run, tmp_path):
    rec, scn = small_run
    out = tmp_path / "new" / "dir"  # created on demand
    paths = write_panels(rec, scn, out)
    _check_pngs(paths, out)
    paths_img = image.imread(out / "a_paths.png")[..., :3]
    assert paths_img.var() > 1e-3  # not blank
    assert len(np.unique(paths_img.reshape(-1, 3), axis=0)) > 50  # many colours: robots, obstacles, leader


def test_one_robot_without_obstacles(tmp_path):
    doc = {
        "run": {"duration": 2.0, "dt": 0.02, "seed": 0},
        "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 10.0, "v": 0.5, "w": 0.0}]},
        "formation": {"offsets": [[0.0, 0.0]]},
        "robots": {"poses": [[-2.0, -1.0, 0.5]]},
    }
    scn = sf.resolve(sf.parse(doc, "test", "t"))
    assert scn.n == 1 and len(scn.obstacles) == 0
    rec = Simulation(scn).run().recording
    _check_pngs(write_panels(rec, scn, tmp_path), tmp_path)


@pytest.mark.parametrize("samples", [1, 2])
def test_few_samples(small_run, tmp_path, samples):
    rec, scn = small_run
    cut = Recording(*(a[:samples] for a in (rec.t, rec.q, rec.err, rec.cmd, rec.frozen, rec.leader)))
    _check_pngs(write_panels(cut, scn, tmp_path), tmp_path)


def test_close_pairs_sweep_matches_dense(monkeypatch):
    rng = np.random.default_rng(3)
    q = np.zeros((40, 60, 3))
    q[:, :, :2] = rng.uniform(0, 15, (1, 60, 2)) + np.cumsum(rng.normal(0, 0.1, (40, 60, 2)), axis=0)
    dense = close_pairs(q, 2.4)
    d = np.linalg.norm(q[:, :, None, :2] - q[:, None, :, :2], axis=-1).min(axis=0)
    i, j = np.nonzero(np.triu(d < 2.4, 1))
    assert np.array_equal(dense, np.stack([i, j], axis=1)) and len(dense) > 0
    monkeypatch.setattr("swarm.view.plots.DENSE_PAIRS_N", 0)  # force the sort-and-sweep path
    assert np.array_equal(close_pairs(q, 2.4), dense)
    assert close_pairs(q[:, :1], 2.4).shape == (0, 2)
