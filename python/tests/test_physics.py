"""Physics and beamforming from numpy agree with the CLI bit for bit; user-supplied W; errors."""
import csv
import json
import os

import numpy as np
import pytest

import skyloop as sl
from conftest import run_cli


def test_beamform_eval_equals_cli_bit_for_bit(skyloop_bin, tmp_path):
    out = tmp_path / "bf.csv"
    r = run_cli("beamform", "eval", "--methods", "mrt,zf,zfsel,rzf,wmmse,gnn", "--samples", "4", "--seed", "5",
                "--quiet", "--out", str(out))
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(out)))
    cfg = sl.config(run={"seed": 5})
    model = sl.SystemModel(cfg)
    for row in rows:
        snap = model.random_snapshot(3, 12, sl.derive_seed(5, int(row["sample"])))
        bf = sl.beamformer(row["method"], cfg)
        net = model.network(snap)  # every tool designs a snapshot through the network call
        W = bf.design_network(net)
        total = sl.network_sum_rate(net, W)
        assert total == float(row["sum_rate_bps_hz"]), row  # exact: the CSV holds the shortest exact text
        # Orthogonal bands: the network sum rate is the clusters' own sum rates.
        assert total == pytest.approx(sum(sl.sum_rate(c, w) for c, w in zip(net.clusters, W)), rel=1e-14)


def test_snapshot_json_equals_numpy(skyloop_bin, source_dir):
    scenario = os.path.join(source_dir, "configs", "scenarios", "two_uavs.toml")
    r = run_cli("snapshot", "--json", "--method", "wmmse", "--scenario", scenario)
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    cfg = sl.config()
    model = sl.SystemModel(cfg)
    snap = model.snapshot(cfg, [[60.0, 60.0], [150.0, 150.0]],
                          [[60.0, 60.0], [40.0, 90.0], [90.0, 30.0], [170.0, 140.0], [130.0, 180.0], [200.0, 0.0]])
    assert model.associate(snap) == [u["serving_uav"] if u["serving_uav"] is not None else -1 for u in j["users"]]
    bf = sl.beamformer("wmmse", cfg)
    for c in model.clusters(snap):
        W = bf.design(c)
        for k, s in zip(c.users, sl.sinr(c, W)):
            assert s == j["users"][k]["sinr"]
        # G's row k is h_k^H: the JSON channel is h_k itself.
        h = np.array([complex(*x) if isinstance(x, list) else complex(x["re"], x["im"]) for x in j["users"][c.users[0]]["channel"]])
        assert np.allclose(np.conj(c.G[0]), h, rtol=0, atol=1e-15)


def test_user_precoder_in_numpy_matches_registered_mrt():
    cfg = sl.config()
    model = sl.SystemModel(cfg)
    mrt = sl.beamformer("mrt", cfg)
    for seed in range(5):
        for c in model.clusters(model.random_snapshot(3, 12, seed)):
            H = np.conj(c.G).T                                 # [L, K_n], column k = h_k
            W = H / np.linalg.norm(H, axis=0) * np.sqrt(c.p_max / c.size)
            assert np.allclose(W, mrt.design(c), rtol=1e-12, atol=1e-15)
            assert sl.sum_rate(c, W) == pytest.approx(sl.sum_rate(c, mrt.design(c)), rel=1e-12)
            rates = sl.rates(c, W)
            assert rates.shape == (c.size,) and np.all(rates >= 0)
            assert np.isclose(rates.sum(), sl.sum_rate(c, W), rtol=1e-12)


def test_batch_equals_one_by_one():
    cfg = sl.config()
    model = sl.SystemModel(cfg)
    clusters = [c for s in range(20) for c in model.clusters(model.random_snapshot(3, 12, s))]
    for spec in ("wmmse", "zfsel"):  # classical: every cluster alone, bit for bit
        bf = sl.beamformer(spec, cfg)
        batch = bf.design_batch(clusters, threads=2)
        for c, W in zip(clusters, batch):
            assert np.array_equal(W, bf.design(c)), spec
    # The GNN batches its clusters into one forward pass; float32 GEMMs of another shape round
    # differently, so the check runs in float64 (same weights): 1e-8 of sqrt(P) (see nn_test.cpp).
    bf = sl.beamformer("gnn", sl.config(nn={"precision": "float64"}))
    for c, W in zip(clusters, bf.design_batch(clusters)):
        assert np.linalg.norm(W - bf.design(c)) < 1e-8 * np.sqrt(c.p_max)


def test_ranked_selection_is_a_setting_of_the_served_model():
    """nn.selection = "ranked" from Python: never below the network's own beams, on the budget,
    and refused for the interference-aware GNN with InputError."""
    model = sl.SystemModel(sl.config())
    clusters = [c for s in range(10) for c in model.clusters(model.random_snapshot(3, 12, s))]
    soft = sl.beamformer("gnn", sl.config())
    ranked = sl.beamformer("gnn", sl.config(nn={"selection": "ranked"}))
    gain = sl.beamformer("zfgain", sl.config())
    better = 0
    for c in clusters:
        Ws, Wr = soft.design(c), ranked.design(c)
        assert sl.sum_rate(c, Wr) >= sl.sum_rate(c, Ws) - 1e-12
        assert np.linalg.norm(Wr) ** 2 == pytest.approx(c.p_max, rel=1e-9)
        assert np.linalg.norm(gain.design(c)) ** 2 == pytest.approx(c.p_max, rel=1e-9)
        better += sl.sum_rate(c, Wr) > sl.sum_rate(c, Ws) + 1e-9
    assert better > len(clusters) // 2, "the paper's GNN is beaten by ZF on its ranking in most clusters"
    with pytest.raises(sl.InputError, match="nn.selection"):
        sl.beamformer("ignn", sl.config(nn={"selection": "ranked"}))
    with pytest.raises(sl.InputError, match="nn.selection"):
        sl.config(nn={"selection": "hard"})


def test_config_sources_agree(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[channel]\np_max_dbm = 40\n")
    a = sl.config(str(p))
    b = sl.config(overrides={"channel.p_max_dbm": 40})
    c = sl.config(overrides={"channel": {"p_max_dbm": 40}})
    d = sl.config(channel={"p_max_dbm": 40.0})
    assert a.toml() == b.toml() == c.toml() == d.toml()
    assert a["channel.p_max_dbm"] == 40.0
    assert a["trajectory.starts"][0] == (20.0, 20.0)


@pytest.mark.parametrize("kwargs, message", [
    ({"overrides": {"channel.nosuch": 1}}, "unknown key 'channel.nosuch'"),
    ({"overrides": {"channel.p_max_dbm": 400}}, "channel.p_max_dbm = 400 is out of range: allowed a number in [-30, 80]"),
    ({"overrides": {"run.seed": -1}}, "run.seed = -1 is out of range"),
    ({"channel": 3}, "channel = 3 has the wrong type"),
    ({"path": "/nonexistent.toml"}, "cannot be read"),
])
def test_config_errors_carry_the_cli_line(kwargs, message):
    with pytest.raises(sl.InputError) as e:
        sl.config(**kwargs)
    assert message in str(e.value)
    assert "\n" not in str(e.value)
    assert isinstance(e.value, ValueError)


def test_bad_beamformer_and_w_shape():
    cfg = sl.config()
    with pytest.raises(sl.InputError, match="method 'nosuch' is unknown"):
        sl.beamformer("nosuch", cfg)
    with pytest.raises(sl.InputError, match="empty argument"):
        sl.beamformer("gnn=", cfg)
    c = sl.SystemModel(cfg).clusters(sl.SystemModel(cfg).random_snapshot(3, 12, 1))[0]
    with pytest.raises(sl.InputError, match="W has shape"):
        sl.sum_rate(c, np.zeros((c.antennas + 1, c.size), complex))
    with pytest.raises(sl.InputError, match="outside the area"):
        sl.SystemModel(cfg).snapshot(cfg, [[np.nan, 1.0]], [[1.0, 1.0]])


def test_installed_package_finds_its_own_models(tmp_path, source_dir):
    """An installed package (cmake --install --component python, staged with DESTDIR) imports from
    anywhere and loads the shipped models from its own data/ copy, not from the source tree."""
    import os
    import subprocess
    import sys
    build = os.path.join(source_dir, "build")
    if not os.path.exists(os.path.join(build, "CMakeCache.txt")):
        import pytest
        pytest.skip("no build tree")
    env = dict(os.environ, DESTDIR=str(tmp_path))
    r = subprocess.run(["cmake", "--install", build, "--component", "python"], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    # The install goes to the site directory of the interpreter the module was built for (the
    # tests may run under another: the project's .venv).
    cache = open(os.path.join(build, "CMakeCache.txt")).read()
    built_for = next((ln.split("=", 1)[1] for ln in cache.splitlines() if ln.startswith("SKYLOOP_PYTHON_EXECUTABLE:")), sys.executable)
    site = subprocess.run([built_for, "-c", "import sysconfig; print(sysconfig.get_path('platlib'))"],
                          capture_output=True, text=True).stdout.strip()
    staged = str(tmp_path) + site
    assert os.path.exists(os.path.join(staged, "skyloop", "data", "models", "gnn", "model.pt"))
    code = ("import skyloop as sl; import os; d = sl._skyloop.data_dir(); "
            "assert d.startswith(os.environ['STAGED']), d; "
            "cfg = sl.config(); m = sl.SystemModel(cfg); c = m.clusters(m.random_snapshot(3, 12, 1))[0]; "
            "print(sl.sum_rate(c, sl.beamformer('gnn', cfg).design(c)))")
    clean = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "SKYLOOP_DATA_DIR")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(tmp_path),
                       env=dict(clean, PYTHONPATH=staged, STAGED=staged))
    assert r.returncode == 0, r.stderr
    assert float(r.stdout) > 0


def test_torch_precoder_is_accepted():
    torch = pytest.importorskip("torch")
    cfg = sl.config()
    model = sl.SystemModel(cfg)
    c = model.clusters(model.random_snapshot(3, 12, 2))[0]
    W = sl.beamformer("zf", cfg).design(c)
    assert sl.sum_rate(c, torch.from_numpy(W)) == sl.sum_rate(c, W)
    assert np.array_equal(sl.sinr(c, torch.from_numpy(W).requires_grad_(False)), sl.sinr(c, W))


def test_shared_spectrum_eval_equals_cli_bit_for_bit(skyloop_bin, source_dir, tmp_path):
    """Under channel.spectrum = shared, a coordinated and a per-cluster method through the network
    call give the CLI's numbers exactly, and the interference counted by hand matches user_powers."""
    out = tmp_path / "shared.csv"
    ignn = "ignn=" + os.path.join(source_dir, "models", "ignn_structured")
    r = run_cli("beamform", "eval", "--methods", "nwmmse,wmmse," + ignn, "--samples", "3", "--seed", "9",
                "--quiet", "--set", "channel.spectrum=shared", "--out", str(out))
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(out)))
    assert {row["spectrum"] for row in rows} == {"shared"}
    cfg = sl.config(run={"seed": 9}, channel={"spectrum": "shared"})
    model = sl.SystemModel(cfg)
    for row in rows:
        net = model.network(model.random_snapshot(3, 12, sl.derive_seed(9, int(row["sample"]))))
        assert net.spectrum == "shared"
        bf = sl.beamformer(row["method"], cfg)
        assert bf.coordinated == (row["method"] != "wmmse")
        W = bf.design_network(net)
        assert sl.network_sum_rate(net, W) == float(row["sum_rate_bps_hz"]), row
        # The inter-cluster interference of user 0 of cluster 0, by hand from the cross channels.
        powers = sl.user_powers(net, W)
        inter = sum(np.sum(np.abs(net.cross[b][0] @ W[b]) ** 2) for b in range(1, len(W)))
        assert powers[0][0]["inter"] == pytest.approx(inter, rel=1e-12)


def test_snapshot_json_reports_interference(skyloop_bin, source_dir):
    scenario = os.path.join(source_dir, "configs", "scenarios", "two_uavs.toml")
    shared = json.loads(run_cli("snapshot", "--json", "--method", "wmmse", "--scenario", scenario,
                                "--set", "channel.spectrum=shared").stdout)
    orth = json.loads(run_cli("snapshot", "--json", "--method", "wmmse", "--scenario", scenario).stdout)
    assert shared["spectrum"] == "shared" and orth["spectrum"] == "orthogonal"
    for s, o in zip(shared["users"], orth["users"]):
        assert len(s["cross_channels"]) == 2  # one h_{m,k} per UAV
        if s["serving_uav"] is None:
            continue
        assert o["inter_interference_w"] == 0.0
        assert s["inter_interference_w"] > 0.0
        assert s["sinr"] == pytest.approx(s["signal_w"] / (s["intra_interference_w"] + s["inter_interference_w"] + s["noise_w"]),
                                          rel=1e-12)
        assert s["rate"] < o["rate"] or s["sinr"] == 0.0  # same beams, more interference


def test_link_state_and_fast_slots_equal_the_cli(skyloop_bin, source_dir):
    """SystemModel.link / channel under a 3GPP channel with Rician fading give what `snapshot --json`
    reports for the same links (one writer of the field names: channel_model.cpp)."""
    scenario = os.path.join(source_dir, "configs", "scenarios", "two_uavs.toml")
    sets = ["channel.pathloss=3gpp-uma-av", "channel.fading=rician", "channel.fast_slots=4"]
    r = run_cli("snapshot", "--json", "--method", "zfsel", "--scenario", scenario, *sum((["--set", s] for s in sets), []))
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    cfg = sl.config(channel={"pathloss": "3gpp-uma-av", "fading": "rician", "fast_slots": 4})
    model = sl.SystemModel(cfg)
    assert model.fast_slots == 4
    uavs = [c for c in j["clusters"]]
    for u in j["users"]:
        for link in u["links"]:
            uav = uavs[link["uav"]]
            mine = model.link(uav["x"], uav["y"], u["x"], u["y"])
            assert set(mine) == {k for k in link if k not in ("uav", "channel")}
            for k, v in mine.items():
                if isinstance(v, float) and np.isinf(v):
                    assert link[k] == ("inf" if v > 0 else "-inf")
                else:
                    assert link[k] == v, k
            h = model.channel(uav["x"], uav["y"], u["x"], u["y"], 0)
            assert np.allclose(h, [complex(re, im) for re, im in link["channel"]], rtol=0, atol=0)
    # Another fast slot is another realisation of the same link; slot 4 does not exist.
    u, c = j["users"][0], uavs[0]
    assert not np.array_equal(model.channel(c["x"], c["y"], u["x"], u["y"], 1), model.channel(c["x"], c["y"], u["x"], u["y"], 0))
    with pytest.raises(sl.InputError, match="slot = 4 is out of range"):
        model.channel(c["x"], c["y"], u["x"], u["y"], 4)


def test_the_channel_reads_each_uavs_altitude():
    """Al-Hourani urban (a = 9.61, b = 0.16), a user 100 m from the UAV's ground point, evaluated by
    hand: at 100 m altitude the elevation is 45 deg and P_LoS = 0.967692, at 60 m 30.963757 deg and
    0.760204. A snapshot's UAVs [N, 3] are associated by their 3-D distance."""
    model = sl.SystemModel(sl.config(overrides={"channel.pathloss": "al-hourani", "channel.environment": "urban"}))
    high, low = model.link(0.0, 0.0, 100.0, 0.0, uz=100.0), model.link(0.0, 0.0, 100.0, 0.0, uz=60.0)
    assert high["elevation_deg"] == pytest.approx(45.0, abs=1e-6) and high["p_los"] == pytest.approx(0.9676919, abs=1e-6)
    assert low["elevation_deg"] == pytest.approx(30.9637565, abs=1e-6) and low["p_los"] == pytest.approx(0.7602037, abs=1e-6)
    assert model.link(0.0, 0.0, 100.0, 0.0) == high  # the default altitude is scenario.altitude_m
    cfg = sl.config()
    paper = sl.SystemModel(cfg)
    users = np.array([[20.0, 0.0]])
    near_low = paper.snapshot(cfg, np.array([[0.0, 0.0, 140.0], [60.0, 0.0, 60.0]]), users)
    assert paper.associate(near_low) == [1]  # 141.4 m to UAV 0, 72.1 m to UAV 1
    assert paper.associate(paper.snapshot(cfg, np.array([[0.0, 0.0, 140.0], [60.0, 0.0, 140.0]]), users)) == [0]
