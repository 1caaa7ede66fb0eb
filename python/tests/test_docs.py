"""The documentation cannot drift from the code:

- every tutorial's code (and the first-five-minutes page's) runs as written, on the smaller
  settings its page's header names (``test-substitutions``); a block shown for reading only is
  marked ``<!-- no-test -->`` on the line before it;
- the generated reference lists every configuration field (Config.keys(), the table itself) and
  every command and option the CLI's sources define (apps/skyloop/*.cpp, read here independently
  of the generator), so removing one from the generator fails here;
- every relative link between pages resolves to a page that exists;
- the MARL page's results of the paper scenario are the committed paper profile's.

The site itself is built with warnings as errors by scripts/docs (in CI), which also renders it
in headless Chromium."""
import os
import pathlib
import re
import subprocess
import sys

import pytest

import skyloop as sl

ROOT = pathlib.Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
BIN = os.environ.get("SKYLOOP_BIN", str(ROOT / "build" / "skyloop"))
BUILD = pathlib.Path(BIN).resolve().parent
sys.path.insert(0, str(DOCS))
sys.path.insert(0, str(ROOT / "scripts"))

FENCE = re.compile(r"^```(python|sh)\n(.*?)^```", re.S | re.M)
RUN_PAGES = sorted(p for p in DOCS.glob("tutorials/*.md") if p.name != "index.md") + [DOCS / "getting-started" / "first-steps.md"]
NEEDS = {"learning-libraries.md": ("pettingzoo", "gymnasium")}


def substitutions(text):
    """The page's header: `test-substitutions:` then one `"from": "to"` per line."""
    if not text.startswith("---\n"):
        return {}
    header = text[4:text.index("\n---", 4)]
    pairs = re.findall(r'^\s+"(.*?)":\s*"(.*?)"\s*$', header, re.M)
    return dict(pairs)


def runnable_blocks(text):
    out = []
    for m in FENCE.finditer(text):
        before = text[:m.start()].rstrip().splitlines()
        if before and before[-1].strip() == "<!-- no-test -->":
            continue
        out.append((m.group(1), m.group(2)))
    return out


@pytest.mark.parametrize("page", RUN_PAGES, ids=lambda p: str(p.relative_to(DOCS)))
def test_tutorial_code_runs_as_written(page, tmp_path, monkeypatch):
    for module in NEEDS.get(page.name, ()):
        pytest.importorskip(module, reason=f"{module} is not installed (scripts/install-python-env)")
    if not os.path.exists(BIN):
        pytest.skip(f"no skyloop binary at {BIN}")
    text = page.read_text()
    subs = substitutions(text)
    blocks = runnable_blocks(text)
    assert blocks, f"{page.name}: no runnable block"
    for name in ("configs", "models", "examples"):
        (tmp_path / name).symlink_to(ROOT / name)
    monkeypatch.chdir(tmp_path)
    env = dict(os.environ, PATH=f"{BUILD}{os.pathsep}{os.environ.get('PATH', '')}")
    namespace = {"__name__": "__tutorial__"}
    used = set()
    for lang, code in blocks:
        for a, b in subs.items():
            if a in code:
                used.add(a)
                code = code.replace(a, b)
        if lang == "python":
            exec(compile(code, f"{page.name}:python", "exec"), namespace)
        else:
            r = subprocess.run(["bash", "-euo", "pipefail", "-c", code], cwd=tmp_path, env=env, capture_output=True,
                               text=True, timeout=600)
            assert r.returncode == 0, f"{page.name}: a block failed:\n{code}\n--- stderr:\n{r.stderr[-3000:]}"
    assert used == set(subs), f"{page.name}: substitutions that match no block: {sorted(set(subs) - used)}"


def test_config_reference_lists_every_field():
    import _generate
    page = _generate.config_page(str(BUILD))
    missing = [k for k in sl.Config.keys() if f"| `{k}` |" not in page]
    assert not missing, f"the configuration reference lacks {missing}"


def _cli_names():
    """(subcommands, options) as the CLI's sources define them."""
    src = "\n".join(p.read_text() for p in (ROOT / "apps" / "skyloop").glob("*.cpp"))
    return (set(re.findall(r'add_subcommand\("([^"]+)"', src)),
            set(re.findall(r'add_(?:option|flag)\("(--[a-z][a-z0-9-]*)', src)))


def test_cli_reference_lists_every_command_and_option():
    import _generate
    page = _generate.cli_page(str(BUILD))
    commands, options = _cli_names()
    assert {"beamform", "train", "reproduce", "fields"} <= commands and "--set" in options  # the parse found them
    headings = set(re.findall(r"^## `skyloop(?: ([a-z ]+))?`$", page, re.M))
    last = {h.split()[-1] for h in headings if h}
    assert not commands - last, f"the CLI reference lacks the commands {sorted(commands - last)}"
    missing = sorted(o for o in options if not re.search(re.escape(o) + r"\b", page))
    assert not missing, f"the CLI reference lacks the options {missing}"


def test_every_relative_link_between_pages_resolves():
    import _generate
    if not all((DOCS / g).exists() for g in _generate.GENERATED):
        _generate.main(str(BUILD), doxygen=False)  # the pages' text is enough to check their links
    link = re.compile(r"\]\(([^)#\s]+\.md)(#[^)]*)?\)")
    broken = []
    for page in DOCS.rglob("*.md"):
        for target, _ in link.findall(page.read_text()):
            if "://" not in target and not (page.parent / target).resolve().exists():
                broken.append(f"{page.relative_to(DOCS)} -> {target}")
    assert not broken, f"links to no page: {broken}"


def test_marl_page_states_the_paper_profiles_results():
    """The MARL page's table of the paper scenario (objective and UAVs home per learner and seed)
    and its reference line are the committed paper profile's (results/paper/marl_training), so a
    new paper profile that moves them fails here until the page says what it now holds."""
    import csv
    data = ROOT / "results" / "paper" / "marl_training"
    page = (DOCS / "concepts" / "marl.md").read_text()
    with open(data / "marl_training.csv", newline="") as f:
        runs = list(csv.DictReader(f))
    names = {"mappo": "MAPPO", "ippo": "IPPO", "vdn": "VDN", "qmix": "QMIX"}
    for algo, label in names.items():
        row = re.search(r"^\| " + label + r" \| (.*)$", page, re.M)
        assert row, f"docs/concepts/marl.md has no table row for {label}"
        cells = [c.strip() for c in row.group(1).split("|")]
        mine = sorted((r for r in runs if r["algo"] == algo), key=lambda r: int(r["train_seed"]))
        assert len(mine) == 3, f"{algo}: {len(mine)} runs in marl_training.csv, the table has 3 seeds"
        for r, cell in zip(mine, cells):
            want = f"{float(r['objective']):.3f}, {r['arrivals']}/{r['uavs']}"
            assert cell.startswith(want), f"{label} seed {r['train_seed']}: the page says '{cell}', the data {want}"
    with open(data / "references.csv", newline="") as f:
        refs = {r["planner"]: r for r in csv.DictReader(f)}
    for planner, label in (("greedy", "Greedy scores"), ("random", "Random"), ("optimal", "the exact optimum")):
        want = f"{label} {float(refs[planner]['objective']):.3f} ({refs[planner]['arrivals']}/"
        assert want in page.replace("\n", " "), f"docs/concepts/marl.md should say '{want}...'"


def test_benchmark_page_is_made_from_its_data():
    """Every figure on the benchmark page is the median of at least three runs, with its command,
    date and machine, and says how a script measures it again (rows() refuses a row that names
    neither a Google Benchmark nor what to read in its command's output)."""
    import bench_report
    rows = bench_report.rows()
    page = bench_report.page()
    assert rows and all(f"## {r['area']}" in page and r["quantity"] in page for r in rows)
    assert all(r["date"] and r["machine"] and r["command"] for r in rows)
    few = [r["quantity"] for r in rows if int(r["runs"]) < 3]
    assert not few, f"figures over fewer than three runs: {few}"


def test_a_row_that_says_not_how_it_is_measured_is_refused(tmp_path, monkeypatch):
    import bench_report
    path = tmp_path / "current.csv"
    head = ",".join(bench_report.COLUMNS)
    row = "Area,a figure,1,s,3,median of runs,2026-01-01,a machine,skyloop plan --out $DIR,{},{}"
    monkeypatch.setattr(bench_report, "CURRENT", str(path))
    for gbench, reads, message in (("", "", "allowed exactly one"), ("b:BM_X", "x ([0-9]+)", "allowed exactly one"),
                                   ("", "no group", "with a group"), ("", "bad ([0-9]", "with a group")):
        path.write_text(head + "\n" + row.format(gbench, reads) + "\n")
        with pytest.raises(SystemExit, match=message):
            bench_report.rows()
    path.write_text(head + "\n" + row.format("", "wall") + "\n")
    assert bench_report.rows()[0]["reads"] == "wall"
    path.write_text(head + "\n" + row.format("", "wall") + "\n" + row.format("", "wall") + "\n")
    with pytest.raises(SystemExit, match="the same quantity as line 2"):
        bench_report.rows()


def test_a_commands_figure_is_read_from_what_it_prints(tmp_path):
    import bench_report
    row = {"command": 'mkdir -p "$DIR" && echo "warm-up 7 s" && echo "done: 1,234.5 steps in 9.25 s"',
           "reads": r"done: ([0-9,.]+) steps"}
    assert bench_report.run_once(row, root=str(tmp_path)) == 1234.5
    assert bench_report.run_once(dict(row, reads=r"in ([0-9.]+) s"), root=str(tmp_path)) == 9.25
    assert bench_report.run_once({"command": "sleep 0.2", "reads": "wall"}, root=str(tmp_path)) >= 0.2
    with pytest.raises(ValueError, match="no line of the output matches"):
        bench_report.run_once(dict(row, reads=r"took ([0-9.]+) h"), root=str(tmp_path))
    with pytest.raises(RuntimeError, match="exited with 3"):
        bench_report.run_once({"command": "echo 1 s; exit 3", "reads": r"([0-9]) s"}, root=str(tmp_path))


def test_rows_that_share_a_command_share_its_runs(tmp_path, monkeypatch):
    """`scripts/bench --measure` runs a command once per run for all the rows that read it (a ratio
    and a rate from the same runs), records each row's median and leaves the other rows alone."""
    import bench_report
    path = tmp_path / "current.csv"
    monkeypatch.setattr(bench_report, "CURRENT", str(path))
    count = tmp_path / "runs.txt"
    command = f'echo run >> {count}; n=$(wc -l < {count}); echo "ratio 0.$n; rate $((n * 100)) a/s"'
    head = ",".join(bench_report.COLUMNS)
    row = "Area,{},1,{},1,median of runs,2026-01-01,a machine,{},,{}"
    path.write_text("\n".join([head, row.format("ratio", "ratio", command, r"ratio ([0-9.]+);"),
                               row.format("rate", "a/s", command, r"rate ([0-9]+) a/s"),
                               row.format("other", "s", "exit 1", r"([0-9]+)")]) + "\n")
    bench_report.measure("^ra", 3, root=str(tmp_path))
    assert count.read_text().count("run") == 3
    got = {r["quantity"]: r for r in bench_report.rows()}
    assert got["ratio"]["value"] == "0.2" and got["rate"]["value"] == "200"  # the median of runs 1, 2, 3
    assert got["ratio"]["runs"] == got["rate"]["runs"] == "3"
    assert got["other"]["value"] == "1" and got["other"]["date"] == "2026-01-01"


def test_recording_reads_only_the_benchmarks_this_run_wrote(tmp_path, monkeypatch):
    """`scripts/bench --record` refreshes the rows of the binaries it has just run; a CSV left in
    results/bench by an earlier run is not read (its rows would take today's date unmeasured)."""
    import bench_report
    path = tmp_path / "current.csv"
    monkeypatch.setattr(bench_report, "CURRENT", str(path))
    (tmp_path / "results" / "bench").mkdir(parents=True)
    gb = "name,iterations,real_time,cpu_time,time_unit,bytes_per_second,items_per_second,label,error_occurred,error_message\n"
    for binary, t in (("fresh", 2000), ("stale", 9000)):
        (tmp_path / "results" / "bench" / f"{binary}.csv").write_text(
            "2026-01-01T00:00:00\n" + gb + f'"BM_X_median",3,{t},{t},us,,,,,\n')
    head = ",".join(bench_report.COLUMNS)
    row = "Area,{0},1,ms,3,median of repetition means,2026-01-01,a machine,REPS=3 scripts/bench 'BM_X',{0}:BM_X,"
    path.write_text("\n".join([head, row.format("fresh"), row.format("stale")]) + "\n")
    bench_report.record(3, {"fresh"}, root=str(tmp_path))
    got = {r["quantity"]: r for r in bench_report.rows()}
    assert got["fresh"]["value"] == "2" and got["fresh"]["date"] != "2026-01-01"
    assert got["stale"]["value"] == "1" and got["stale"]["date"] == "2026-01-01"


def test_one_version_everywhere():
    """VERSION is the one version: the module (through CMake), the CLI, CITATION.cff and the
    changelog's latest release say the same."""
    version = (ROOT / "VERSION").read_text().strip()
    assert sl.__version__ == version
    out = subprocess.run([BIN, "--version"], capture_output=True, text=True).stdout
    assert out.startswith(f"skyloop {version} "), out
    assert re.search(rf"^version: {re.escape(version)}$", (ROOT / "CITATION.cff").read_text(), re.M)
    releases = re.findall(r"^## \[(\d+\.\d+\.\d+)\]", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert releases and releases[0] == version


@pytest.mark.parametrize("args, expected", [
    ([], "--profile quick --out results/quick"),
    (["--force"], "--profile quick --out results/quick --force"),
    (["paper", "--time-limit", "2h"], "--profile paper --out results/paper --time-limit 2h"),
    (["tiny"], "--profile tiny --out results/tiny"),
])
def test_the_main_job_takes_a_profile_then_reproduces_options(tmp_path, args, expected):
    """`scripts/reproduce [PROFILE] [OPTIONS]`, as the README and the benchmark page's row
    (`scripts/reproduce --force`) call it: an option in first place is passed on, not read as the
    profile. Run in a copy whose install, build and binary only echo what they are given."""
    (tmp_path / "scripts").mkdir()
    (tmp_path / "build").mkdir()
    script = tmp_path / "scripts" / "reproduce"
    script.write_text((ROOT / "scripts" / "reproduce").read_text())
    for stub, body in ((tmp_path / "scripts" / "install-deps", "true"), (tmp_path / "scripts" / "build", "true"),
                       (tmp_path / "build" / "skyloop", 'echo "$*"')):
        stub.write_text(f"#!/usr/bin/env bash\n{body}\n")
    for f in (script, tmp_path / "scripts" / "install-deps", tmp_path / "scripts" / "build", tmp_path / "build" / "skyloop"):
        f.chmod(0o755)
    r = subprocess.run([str(script), *args], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "reproduce " + expected
