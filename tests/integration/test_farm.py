"""`skyloop reproduce` beyond one process: under mpirun (2 and 3 ranks), after a rank is killed
mid-run and the job rerun, and as shards 1/2 and 2/2 plus an assembling run, the tiny profile
gives the same CSVs (every column but the timings) and manifest as one process.

Run by ctest (farm.*) with SKYLOOP_BIN=<the skyloop binary> and SKYLOOP_MPI=1 when the build has
MPI; as root, mpirun needs --allow-run-as-root; --oversubscribe lets 3 ranks share 2 cores."""
import csv
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

BIN = os.environ.get("SKYLOOP_BIN", "build/skyloop")
HAVE_MPI = os.environ.get("SKYLOOP_MPI") == "1"
# Columns that hold wall times or rates: they differ from run to run by nature.
TIMING = {"median_latency_ms", "mean_latency_ms", "latency_ms", "seconds", "train_seconds", "steps_per_second",
          "charts/steps_per_s"}
ARGS = ["reproduce", "--profile", "tiny", "--no-plots"]


def mpirun(n):
    exe = shutil.which("mpirun")
    assert exe, "the build has MPI but mpirun is not on PATH (scripts/install-deps installs openmpi-bin)"
    cmd = [exe, "--oversubscribe", "-np", str(n)]
    if os.geteuid() == 0:
        cmd.insert(1, "--allow-run-as-root")
    return cmd


def run(cmd, **kw):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, **kw)


def results(out: Path):
    """{experiment/file.csv: rows without timing columns} and the manifest's experiments and models."""
    manifest = json.loads((out / "manifest.json").read_text())
    tables = {}
    for e in manifest["experiments"]:
        for f in e["files"]:
            with open(out / f) as fh:
                tables[f] = [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(fh)]
    shape = [(e["name"], e["kind"], e["files"]) for e in manifest["experiments"]]
    return tables, shape, manifest["models"]


def same(a: Path, b: Path):
    ta, sa, ma = results(a)
    tb, sb, mb = results(b)
    assert sa == sb
    assert ma == mb
    assert ta.keys() == tb.keys()
    for f in ta:
        assert len(ta[f]) == len(tb[f]), f
        for i, (x, y) in enumerate(zip(ta[f], tb[f])):
            assert x == y, f"{f} row {i}: {x} != {y}"
    return len(ta)


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    out = tmp_path_factory.mktemp("single") / "run"
    r = run([BIN, *ARGS, "--threads", "2", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    return out


needs_mpi = pytest.mark.skipif(not HAVE_MPI, reason="this build has no MPI (SKYLOOP_MPI != 1)")


@needs_mpi
@pytest.mark.parametrize("ranks", [2, 3])
def test_mpi_matches_one_process(single, tmp_path, ranks):
    out = tmp_path / "run"
    r = run(mpirun(ranks) + [BIN, *ARGS, "--out", str(out)])
    assert r.returncode == 0, r.stderr
    assert f"on {ranks} ranks" in r.stderr
    assert same(single, out) >= 30
    pieces = list(csv.DictReader(open(out / "farm" / "pieces.csv")))
    assert {p["rank"] for p in pieces} == {str(i) for i in range(ranks)}, "every rank computed pieces"
    assert all(p["status"] == "done" for p in pieces)
    # Dependencies ran first: an evaluation of a policy starts after its training run ended.
    at = {(p["phase"], p["piece"]): p for p in pieces}
    for p in pieces:
        for d in filter(None, p["deps"].split(";")):
            assert float(at[(p["phase"], d)]["received_s"]) <= float(p["assigned_s"])
    # The farm's own time per piece (assignment to result, minus the work) stays small.
    overhead = sorted(float(p["overhead_ms"]) for p in pieces)
    assert overhead[len(overhead) // 2] < 50, overhead


@needs_mpi
def test_killed_rank_resumes_from_the_cache(single, tmp_path):
    out = tmp_path / "run"
    job = subprocess.Popen(mpirun(2) + [BIN, *ARGS, "--out", str(out)], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    # Kill rank 1 once it is into the MARL runs (phase 1) and a phase-1 piece is sealed: some pieces
    # done, others not. The farm hands out the costliest ready piece first, so both ranks may start
    # on MARL runs and finish nothing for a while; a seal written after rank 1's first MARL run began
    # is a finished phase-1 piece (phase 0 ends before phase 1 starts).
    log = out / "farm" / "rank1.log"
    seals = lambda: len(list((out / "seals").glob("*.json"))) if (out / "seals").is_dir() else 0
    at_marl = None
    deadline = time.time() + 300
    while time.time() < deadline and job.poll() is None:
        if at_marl is None and log.exists() and "steps) in" in log.read_text():  # "training mappo (K = 12, ...) in"
            at_marl = seals()
        if at_marl is not None and seals() > at_marl:
            break
        time.sleep(0.05)
    assert job.poll() is None, "the job ended before rank 1 was killed: " + job.communicate()[1][-2000:]
    pid = int(log.read_text().split("pid ")[1].split()[0])
    os.kill(pid, signal.SIGKILL)
    _, err = job.communicate(timeout=120)
    assert job.returncode != 0, "mpirun reports the lost rank"
    assert not (out / "manifest.json").exists(), "nothing was assembled from a broken job"

    again = run(mpirun(2) + [BIN, *ARGS, "--out", str(out)])
    assert again.returncode == 0, again.stderr
    # The rerun computes only what was left: the models and finished pieces come from the cache.
    assert "phase 0: 0 of 6 pieces" in again.stderr, again.stderr
    line = next(l for l in again.stderr.splitlines() if l.startswith("phase 1:") and "to compute" in l)
    left, total = int(line.split()[2]), int(line.split()[4])
    assert 0 < left < total, line
    same(single, out)


SBATCH = Path(__file__).resolve().parents[2] / "scripts" / "slurm" / "reproduce.sbatch"


def test_shards_then_assembly_match_one_process(single, tmp_path):
    """The documented Slurm array script, as Slurm would start its two tasks (at the same time)."""
    out = tmp_path / "run"
    env = lambda i: {**os.environ, "SLURM_ARRAY_TASK_ID": str(i), "SLURM_ARRAY_TASK_COUNT": "2", "SKYLOOP": BIN,
                     "PROFILE": "tiny", "OUT": str(out), "EXTRA": "--no-plots"}
    shards = [subprocess.Popen(["bash", str(SBATCH)], env=env(i), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True) for i in (0, 1)]
    for s in shards:
        _, err = s.communicate(timeout=600)
        assert s.returncode == 0, err
        assert "assemble" in err
    assert not (out / "manifest.json").exists(), "a shard assembles nothing"
    r = run([BIN, *ARGS, "--out", str(out)])
    assert r.returncode == 0, r.stderr
    assert not [l for l in r.stderr.splitlines() if l.startswith("  training ")], "the shards computed every piece"
    same(single, out)


def plan(out: Path):
    """reproduce --plan on `out`: {piece id: (estimated core-seconds, done)}."""
    r = run([BIN, *ARGS, "--plan", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    return {p["piece"]: (float(p["cost_estimate"]), p["done"] == "1") for p in csv.DictReader(r.stdout.splitlines())}


def test_time_limit_stops_cleanly_and_the_same_command_goes_on(single, tmp_path):
    """--time-limit 6s: a piece starts only while 1.3 x its estimate fits in what is left, so the
    tiny profile's pieces estimated above 6 / 1.3 s never start (in the pool of two workers, in the
    assembly of one, or in a shard); the run stops with exit status 75 and one line, assembles
    nothing, and the same command without the limit finishes with the numbers of an unlimited run."""
    out = tmp_path / "run"
    for extra in (["--jobs", "1"], ["--jobs", "2"], ["--shard", "1/2"]):
        r = run([BIN, *ARGS, "--threads", "2", *extra, "--time-limit", "6s", "--out", str(out)])
        assert r.returncode == 75, (extra, r.stderr[-2000:])
        last = r.stderr.strip().splitlines()[-1]
        assert last.startswith("time limit: stopped after") and "the next being" in last and "run the same command" in last, last
        assert "results in" not in r.stdout and not (out / "manifest.json").exists(), "nothing is assembled"
        big = [pid for pid, (cost, done) in plan(out).items() if 1.3 * cost > 6]
        assert big, "the tiny profile holds no piece the limit keeps out: the test proves nothing"
        assert not any(plan(out)[pid][1] for pid in big), "a piece estimated beyond the limit was started"
    r = run([BIN, *ARGS, "--threads", "2", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    same(single, out)


@needs_mpi
def test_time_limit_under_mpi_is_refused(tmp_path):
    r = run(mpirun(2) + [BIN, *ARGS, "--time-limit", "1h", "--out", str(tmp_path / "o")])
    assert r.returncode == 2 and "skyloop: error: --time-limit under MPI" in r.stderr, r.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("limit", ["90", "0s", "-5m", "2m3h", "3:61:00", "400d", "abc"])
def test_bad_time_limit_is_one_line(tmp_path, limit):
    r = run([BIN, *ARGS, "--time-limit", limit, "--out", str(tmp_path / "o")])
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--time-limit" in r.stderr and limit in r.stderr, r.stderr
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.parametrize("shard", ["0/2", "3/2", "1/0", "x", "1/2/3", "1-2"])
def test_bad_shard_is_one_line(tmp_path, shard):
    r = run([BIN, *ARGS, "--shard", shard, "--out", str(tmp_path / "o")])
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "--shard" in r.stderr, r.stderr
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_force_with_shard_is_refused(tmp_path):
    r = run([BIN, *ARGS, "--shard", "1/2", "--force", "--out", str(tmp_path / "o")])
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--force" in r.stderr, r.stderr


@needs_mpi
def test_beamform_eval_over_ranks_gives_the_same_rows(tmp_path):
    base = [BIN, "beamform", "eval", "--methods", "mrt,zf,wmmse,gnn", "--samples", "30", "--quiet"]
    one = run(base + ["--out", str(tmp_path / "one.csv")])
    assert one.returncode == 0, one.stderr
    three = run(mpirun(3) + base + ["--out", str(tmp_path / "three.csv")])
    assert three.returncode == 0, three.stderr
    assert "3 ranks" in three.stdout
    strip = lambda p: [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(open(p))]
    assert strip(tmp_path / "one.csv") == strip(tmp_path / "three.csv")
