"""scripts/golden, the refactor's safety net: a check right after a record is identical, and a
check sees a moved cell, a changed configuration value, a lost file and a command that fails,
each named, with exit 1 (2 for a command that fails or a bad --only)."""
import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BUILD = Path(os.environ.get("SKYLOOP_BUILD_DIR", ROOT / "build"))
COMMANDS = """# two fast seeded commands, the second reading the first's output folder
plan: plan --planner random,greedy --oracle zf --seed 5 --out {out}
snap: plan --planner greedy --oracle zf --seed 6 --set trajectory.t_max=20 --out {out}
"""


def golden(*args):
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "golden.py"), *args, "--build", str(BUILD)],
                       capture_output=True, text=True, cwd=ROOT)
    return p.returncode, p.stdout + p.stderr


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    base = tmp_path_factory.mktemp("golden")
    cmds = base / "commands.txt"
    cmds.write_text(COMMANDS)
    rc, out = golden("record", str(base / "rec"), "--commands", str(cmds))
    assert rc == 0, out
    return base / "rec", cmds


def test_the_harness_runs_every_shipped_command_name_once():
    sys.path.insert(0, str(ROOT / "scripts"))
    import golden as g
    names = [n for n, _ in g.parse_commands(ROOT / "tests" / "golden" / "commands.txt", [])]
    assert len(names) == len(set(names)) >= 20
    with pytest.raises(g.GoldenError, match="unknown command nope"):
        g.parse_commands(ROOT / "tests" / "golden" / "commands.txt", ["nope"])
    # --only pulls in the commands whose outputs it reads
    assert [n for n, _ in g.parse_commands(ROOT / "tests" / "golden" / "commands.txt", ["eval-mappo"])] == \
        ["train-mappo", "eval-mappo"]


def test_a_check_right_after_the_record_is_identical(record):
    rec, cmds = record
    rc, out = golden("check", str(rec), "--commands", str(cmds))
    assert rc == 0, out
    assert "identical" in out


def edit_cell(path, row, column, value):
    rows = list(csv.reader(open(path, newline="")))
    rows[row][rows[0].index(column)] = value
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(rows)


def test_a_moved_cell_is_named_by_file_line_and_column(record, tmp_path):
    rec, cmds = record
    copy = tmp_path / "rec"
    subprocess.run(["cp", "-r", str(rec), str(copy)], check=True)
    summary = copy / "plan" / "summary.csv"
    old = list(csv.DictReader(open(summary)))[1]["objective"]
    edit_cell(summary, 2, "objective", repr(float(old) * (1 + 1e-15)))
    edit_cell(summary, 2, "seconds", "123.0")   # wall clock: never compared
    rc, out = golden("check", str(copy), "--commands", str(cmds))
    assert rc == 1, out
    assert "plan/summary.csv: 1 cells differ" in out and "line 3, column objective" in out, out
    assert "seconds" not in out.split("DIFFERS")[1]


def test_a_changed_value_and_a_lost_file_are_differences(record, tmp_path):
    rec, cmds = record
    copy = tmp_path / "rec"
    subprocess.run(["cp", "-r", str(rec), str(copy)], check=True)
    cfg = copy / "snap" / "config.toml"
    cfg.write_text(cfg.read_text().replace("t_max = 20", "t_max = 21"))
    (copy / "snap" / "extra.csv").write_text("a\n1\n")
    rc, out = golden("check", str(copy), "--commands", str(cmds))
    assert rc == 1, out
    assert "snap/config.toml: trajectory.t_max = 21 -> 20" in out, out
    assert "snap/extra.csv: recorded, not written now" in out, out


def test_a_failing_command_and_a_missing_record_exit_two(record, tmp_path):
    rec, _ = record
    bad = tmp_path / "bad.txt"
    bad.write_text("plan: plan --planner nope --out {out}\n")
    rc, out = golden("check", str(rec), "--commands", str(bad))
    assert rc == 2 and "command plan exited 2" in out, out
    rc, out = golden("check", str(tmp_path / "none"), "--commands", str(bad))
    assert rc == 2 and "holds no golden record" in out, out
