"""Golden outputs: run a fixed list of seeded commands (tests/golden/commands.txt) and compare every
output they write, cell by cell, with a recorded run, so a change meant to leave behaviour alone
(a refactor) is shown to be bit-identical, and a change that moves a number names the file, row
and column it moved. Usage (docs/extending/golden.md):

    scripts/golden record DIR [--only NAME,...]        # before the change
    scripts/golden check DIR [--only NAME,...] [--keep OUT]   # after it: exit 0 = identical

Compared: every CSV cell and every JSON value (wall-clock columns and keys aside), every value of
each config.toml (a key the change adds is listed, not a difference), every other file byte for
byte (a trained policy.pt or model.pt is the same bytes for the same seed; logs, timings and
last.pt resume points aside). Commands run in one fixed folder
(BUILD/golden-run), so the paths written into outputs are the same in a record and its check.
"""
import argparse
import csv
import hashlib
import json
import math
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import time
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COMMANDS = ROOT / "tests" / "golden" / "commands.txt"
# Columns that hold wall-clock time: never compared.
TIMING = re.compile(r"(^|[/_.])(seconds|wall_s|time_s|elapsed_s|ms|us)$|_seconds$|per_s$|per_second$")
# Not compared: files that record wall clock or the order in which parallel work finished (logs,
# timings), seals (checksums of files that hold timings), and last.pt (a resume point: LibTorch
# writes Adam's state in the order of its tensors' addresses; model.pt and policy.pt are compared).
VOLATILE = re.compile(r"(^|/)(timings\.csv|seals/[^/]*|locks/[^/]*|[^/]*\.log|last\.pt)$")
# Cache keys: reproduce names a model's or a run's folder by a 12-digit hash of its resolved
# configuration ("gnn-a12ef2003955"), so a configuration field added to the table renames every
# folder. Folder names and the paths written into outputs are compared with the hash masked.
HASHED = re.compile(r"(?<=-)[0-9a-f]{12}(?![0-9a-f])")


# Files named by a 16-digit hash of their key (the optimum cache): compared by contents.
KEYED = re.compile(r"(^|/)[0-9a-f]{16}\.[a-z]+$")


def unhashed(v):
    return HASHED.sub("<hash>", v) if isinstance(v, str) else v


class GoldenError(Exception):
    pass


def parse_commands(path, only):
    commands = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, args = line.partition(":")
        name = name.strip()
        if not sep or not re.fullmatch(r"[a-z0-9][a-z0-9-]*", name):
            raise GoldenError(f"{path}:{number}: expected 'NAME: arguments' with NAME in [a-z0-9-], got {line!r}")
        if any(name == c[0] for c in commands):
            raise GoldenError(f"{path}:{number}: command name {name!r} is used twice")
        commands.append((name, shlex.split(args)))
    if only:
        names = {c[0] for c in commands}
        unknown = sorted(set(only) - names)
        if unknown:
            raise GoldenError(f"--only: unknown command {', '.join(unknown)}; the commands are {', '.join(c[0] for c in commands)}")
        # a command that reads an earlier one's outputs needs it too
        wanted = set(only)
        for name, args in reversed(commands):
            if name in wanted:
                wanted |= {m for a in args for m in re.findall(r"\{([a-z0-9-]+)\}", a) if m != "out"}
        commands = [c for c in commands if c[0] in wanted]
    return commands


def run_all(commands, out, build):
    out.mkdir(parents=True, exist_ok=True)
    skyloop = build / "skyloop"
    if not skyloop.exists():
        raise GoldenError(f"{skyloop} does not exist: run scripts/build first")
    env = dict(os.environ, PYTHONPATH=str(build / "python") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    log = []
    for name, args in commands:
        target = out / name
        if target.exists():
            shutil.rmtree(target)
        subst = [re.sub(r"\{([a-z0-9-]+)\}", lambda m: str(target if m.group(1) == "out" else out / m.group(1)), a) for a in args]
        if subst[0] == "python":
            argv = [str(ROOT / "scripts" / "python")] + subst[1:]
            if not any("{out}" in a for a in args):
                argv.append(str(target))
        else:
            argv = [str(skyloop)] + subst
        t0 = time.monotonic()
        p = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True)
        seconds = time.monotonic() - t0
        target.mkdir(parents=True, exist_ok=True)
        (target / "_stdout.log").write_text(p.stdout + p.stderr)
        print(f"  {name:24s} {seconds:7.1f} s{'' if p.returncode == 0 else f'  exit {p.returncode}'}", flush=True)
        log.append({"name": name, "argv": subst, "seconds": round(seconds, 2), "exit": p.returncode})
        if p.returncode != 0:
            tail = "\n".join((p.stdout + p.stderr).strip().splitlines()[-5:])
            raise GoldenError(f"command {name} exited {p.returncode}: {shlex.join(argv)}\n{tail}")
    return log


def run_root(build):
    """The one folder every command runs in, record and check alike: the paths the outputs hold
    (a model's file in a configuration, a piece's id) are then the same."""
    root = build.resolve() / "golden-run"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    return root


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return (rows[0], rows[1:]) if rows else ([], [])


def as_float(s):
    try:
        return float(s)
    except ValueError:
        return None


def compare_csv(old, new, rel):
    ho, ro = read_csv(old)
    hn, rn = read_csv(new)
    problems = []
    if ho != hn:
        gone = [c for c in ho if c not in hn]
        added = [c for c in hn if c not in ho]
        if gone or not added:
            return [f"{rel}: header changed: {ho} -> {hn}"]
        problems.append(f"{rel}: columns added {added} (compared on the old columns)")
    if len(ro) != len(rn):
        return problems + [f"{rel}: {len(ro)} rows recorded, {len(rn)} now"]
    cols = [c for c in ho if not TIMING.search(c)]
    io = {c: ho.index(c) for c in cols}
    inew = {c: hn.index(c) for c in cols}
    first, count, worst = None, 0, 0.0
    for i, (a, b) in enumerate(zip(ro, rn)):
        for c in cols:
            x = a[io[c]] if io[c] < len(a) else ""
            y = b[inew[c]] if inew[c] < len(b) else ""
            if x == y or unhashed(x) == unhashed(y):
                continue
            count += 1
            first = first or (i + 2, c, x, y)
            fx, fy = as_float(x), as_float(y)
            if fx is not None and fy is not None and math.isfinite(fx) and math.isfinite(fy):
                worst = max(worst, abs(fx - fy) / max(abs(fx), abs(fy), 1e-300))
    if count:
        line, col, x, y = first
        problems.append(f"{rel}: {count} cells differ (largest relative difference {worst:.3g}); "
                        f"first at line {line}, column {col}: {x[:60]} -> {y[:60]}")
    return problems


def flatten(d, prefix=""):
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def compare_json(old, new, rel):
    try:
        a = flatten_json(json.loads(old.read_text()))
        b = flatten_json(json.loads(new.read_text()))
    except (ValueError, UnicodeDecodeError) as e:
        return [f"{rel}: not JSON ({e})"]
    keys = [k for k in sorted(set(a) | set(b)) if not TIMING.search(k.rsplit(".", 1)[-1])]
    diff = [k for k in keys if unhashed(a.get(k, "<absent>")) != unhashed(b.get(k, "<absent>"))]
    if not diff:
        return []
    k = diff[0]
    return [f"{rel}: {len(diff)} values differ; first {k}: {str(a.get(k, '<absent>'))[:60]} -> {str(b.get(k, '<absent>'))[:60]}"]


def flatten_json(v, prefix=""):
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            out.update(flatten_json(x, f"{prefix}{k}."))
        return out
    if isinstance(v, list):
        out = {}
        for i, x in enumerate(v):
            out.update(flatten_json(x, f"{prefix}{i}."))
        return out
    return {prefix[:-1]: v}


def compare_toml(old, new, rel):
    try:
        a = flatten(tomllib.loads(old.read_text()))
        b = flatten(tomllib.loads(new.read_text()))
    except tomllib.TOMLDecodeError as e:
        return [f"{rel}: not TOML ({e})"], []
    problems = [f"{rel}: {k} = {a[k]!r} -> {b[k]!r}" if k in b else f"{rel}: {k} removed"
                for k in a if unhashed(b.get(k, object())) != unhashed(a[k])]
    return problems, sorted(set(b) - set(a))


def untimed(path):
    """A file's contents with a CSV's wall-clock columns left out."""
    if path.suffix != ".csv":
        return path.read_bytes()
    head, rows = read_csv(path)
    keep = [i for i, c in enumerate(head) if not TIMING.search(c)]
    return repr([[r[i] for i in keep if i < len(r)] for r in [head] + rows]).encode()


def compare_pt(old, new, rel):
    """A LibTorch archive: every tensor the same bytes; its metadata (data.pkl) the same but for
    the resolved configuration it embeds as TOML, compared as a config.toml is (keys added noted)."""
    try:
        za, zb = zipfile.ZipFile(old), zipfile.ZipFile(new)
    except zipfile.BadZipFile:
        return ([] if old.read_bytes() == new.read_bytes() else [f"{rel}: differs"]), []
    na, nb = za.namelist(), zb.namelist()
    if [x.split("/", 1)[-1] for x in na] != [x.split("/", 1)[-1] for x in nb]:
        return [f"{rel}: its entries differ"], []
    problems, added = [], []
    for x, y in zip(na, nb):
        a, b = za.read(x), zb.read(y)
        if a == b:
            continue
        if not x.endswith("data.pkl"):
            return [f"{rel}: {x} differs"], []
        sa, sb = re.findall(rb"[ -~\n]{20,}", a), re.findall(rb"[ -~\n]{20,}", b)
        # A JSON string's pickled length may read as text: each piece from its first '{"' on.
        cut = lambda t: t[t.find(b'{"'):] if b'{"' in t else t  # noqa: E731
        sa, sb = [cut(t) for t in sa], [cut(t) for t in sb]
        if len(sa) != len(sb):
            return [f"{rel}: {x} differs"], []
        for u, v in zip(sa, sb):
            if u == v:
                continue
            try:
                ju, jv = json.JSONDecoder().raw_decode(u.decode())[0], json.JSONDecoder().raw_decode(v.decode())[0]
                cu, cv = tomllib.loads(ju.pop("config")), tomllib.loads(jv.pop("config"))
            except (ValueError, KeyError, tomllib.TOMLDecodeError, AttributeError):
                return [f"{rel}: {x} differs"], []
            if ju != jv:
                return [f"{rel}: its metadata differs"], []
            fa, fb = flatten(cu), flatten(cv)
            problems += [f"{rel}: config {k} = {fa[k]!r} -> {fb.get(k)!r}" for k in fa if unhashed(fb.get(k, object())) != unhashed(fa[k])]
            added += sorted(set(fb) - set(fa))
    return problems, added


def outputs(folder):
    """The files a command wrote (its log and hidden files such as the run lock aside)."""
    return {p.relative_to(folder) for p in folder.rglob("*")
            if p.is_file() and p.name != "_stdout.log" and not p.name.startswith(".")
            and not VOLATILE.search(p.relative_to(folder).as_posix())}


def compare_dirs(old, new, names):
    problems, notes, files = [], [], 0
    for name in names:
        o, n = old / name, new / name
        if not o.is_dir():
            problems.append(f"{name}: not recorded in {old} (record again with this commands file)")
            continue
        of = {Path(unhashed(p.as_posix())): p for p in outputs(o)}
        nf = {Path(unhashed(p.as_posix())): p for p in outputs(n)}
        # Files named by a hash of their key alone (the optimum cache): the same contents, in any names.
        keyed = lambda files: sorted(p for p in files if KEYED.search(p.as_posix()))  # noqa: E731
        gone, fresh = keyed(of.keys() - nf.keys()), keyed(nf.keys() - of.keys())
        if gone and len(gone) == len(fresh) and \
                sorted(untimed(o / of[p]) for p in gone) == sorted(untimed(n / nf[p]) for p in fresh):
            files += len(gone)
            for p in gone:
                del of[p]
            for p in fresh:
                del nf[p]
        problems += [f"{name}/{of[p]}: recorded, not written now" for p in sorted(of.keys() - nf.keys())]
        notes += [f"{name}/{nf[p]}: new file" for p in sorted(nf.keys() - of.keys())]
        for key in sorted(of.keys() & nf.keys()):
            p, q = of[key], nf[key]
            rel = f"{name}/{q}"
            if VOLATILE.search(p.as_posix()):
                continue
            files += 1
            if p.suffix == ".csv":
                problems += compare_csv(o / p, n / q, rel)
            elif p.suffix == ".json":
                problems += compare_json(o / p, n / q, rel)
            elif p.name.endswith(".toml"):
                diff, added = compare_toml(o / p, n / q, rel)
                problems += diff
                if added:
                    notes.append(f"{rel}: keys added: {', '.join(added)}")
            elif p.suffix == ".pt":
                diff, added = compare_pt(o / p, n / q, rel)
                problems += diff
                if added:
                    notes.append(f"{rel}: configuration keys added: {', '.join(added)}")
            elif (o / p).read_bytes() != (n / q).read_bytes():
                problems.append(f"{rel}: differs")
    return problems, notes, files


def machine():
    cpu = ""
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    env = {k: os.environ[k] for k in ("ATEN_CPU_CAPABILITY", "OPENBLAS_CORETYPE") if k in os.environ}
    return {"cpu": cpu or platform.processor(), "cores": os.cpu_count(), "kernels": env}


def main(argv):
    ap = argparse.ArgumentParser(prog="scripts/golden", description=__doc__.split("\n\n")[0])
    ap.add_argument("action", choices=["record", "check"])
    ap.add_argument("dir", type=Path, help="the recorded outputs (record writes it, check reads it)")
    ap.add_argument("--only", default="", help="comma-separated command names (and those they read)")
    ap.add_argument("--keep", type=Path, help="check: also copy this run's outputs here (they are in BUILD/golden-run until the next run)")
    ap.add_argument("--commands", type=Path, default=COMMANDS, help="the command list (default tests/golden/commands.txt)")
    ap.add_argument("--build", type=Path, default=Path(os.environ.get("SKYLOOP_BUILD_DIR", ROOT / "build")))
    a = ap.parse_args(argv)
    try:
        commands = parse_commands(a.commands, [s for s in a.only.split(",") if s])
        if a.action == "record":
            if a.dir.exists() and any(a.dir.iterdir()) and not (a.dir / "manifest.json").exists():
                raise GoldenError(f"{a.dir} exists and is not a golden record: choose an empty folder")
            print(f"golden: recording {len(commands)} commands into {a.dir}")
            root = run_root(a.build)
            log = run_all(commands, root, a.build.resolve())
            a.dir.mkdir(parents=True, exist_ok=True)
            for name, _ in commands:
                shutil.rmtree(a.dir / name, ignore_errors=True)
                shutil.copytree(root / name, a.dir / name, symlinks=True)
            commit = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
                                    capture_output=True, text=True).stdout.strip()
            manifest = {"commit": commit, "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "machine": machine(),
                        "commands_sha256": hashlib.sha256(a.commands.read_bytes()).hexdigest(), "runs": log}
            (a.dir / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
            print(f"golden: recorded at {commit} in {sum(r['seconds'] for r in log):.0f} s")
            return 0
        if not (a.dir / "manifest.json").exists():
            raise GoldenError(f"{a.dir} holds no golden record (scripts/golden record {a.dir} first)")
        recorded = json.loads((a.dir / "manifest.json").read_text())
        if recorded["machine"] != machine():
            print(f"golden: warning: recorded on {recorded['machine']}, checked on {machine()}: "
                  "float kernels differ between CPUs, so compare on the machine that recorded", file=sys.stderr)
        print(f"golden: checking {len(commands)} commands against {a.dir} (recorded at {recorded['commit']})")
        root = run_root(a.build)
        run_all(commands, root, a.build.resolve())
        problems, notes, files = compare_dirs(a.dir, root, [c[0] for c in commands])
        if a.keep:
            a.keep.mkdir(parents=True, exist_ok=True)
            for name, _ in commands:
                shutil.rmtree(a.keep / name, ignore_errors=True)
                shutil.copytree(root / name, a.keep / name, symlinks=True)
        for n in notes:
            print(f"  note: {n}")
        for p in problems:
            print(f"  DIFFERS: {p}")
        verdict = "identical" if not problems else f"{len(problems)} differences"
        print(f"golden: {len(commands)} commands, {files} files compared: {verdict}")
        return 0 if not problems else 1
    except GoldenError as e:
        print(f"golden: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
