"""The code's shape against its limits (docs/extending/index.md): files over 700 lines and
functions over 120 lines in src/, python/src/ and apps/, longest first. A function is a brace
block opened at namespace level (or a lambda-free member definition); data tables (a braced
initialiser ending in '};' at namespace level) are listed apart, not counted against the limit.
Usage: scripts/python scripts/code_shape.py [--max-file 700] [--max-function 120] [--strict]
(--strict: exit 1 when a limit is passed)."""
import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DIRS = ["src", "python/src", "apps"]


def strip(text):
    """Comments, strings and character literals blanked, line breaks kept."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append("\n" * text.count("\n", i, j))
            i = j
        elif text.startswith('R"', i):
            m = re.match(r'R"([^(]*)\(', text[i:])
            end = text.find(")" + m.group(1) + '"', i) if m else -1
            j = n if end < 0 else end + len(m.group(1)) + 2
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j
        elif c in "\"'":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(c + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def blocks(path):
    """(name, first line, lines, is_table) of each brace block opened at namespace depth."""
    text = strip(path.read_text())
    lines = text.split("\n")
    depth_ns = 0       # braces of namespaces and extern "C" and classes, which are not functions
    stack = []         # for each open brace: kind
    found = []
    head = ""
    for number, line in enumerate(lines, 1):
        for ch in line:
            if ch == "{":
                h = head.strip()
                in_function = any(k[0] in ("fn", "table") for k in stack)
                if in_function:
                    stack.append(("inner",))
                elif re.search(r"\b(namespace|extern)\b[^;{}()]*$", h) or re.search(r"\b(class|struct|union|enum)\b[^;(){}]*$", h):
                    stack.append(("scope",))
                elif h.endswith("=") or h.endswith("]") or re.search(r"=\s*$", h) or re.search(r"\[\]\s*=", h):
                    stack.append(("table", number, h))
                elif re.search(r"\)\s*(const)?\s*(noexcept)?\s*(override)?\s*(->[^{]*)?$|\)\s*:.*$|^[^=]*\btry$", h) or h.endswith(")"):
                    name = re.findall(r"([~\w:]+(?:operator\S*)?)\s*\(", h)
                    stack.append(("fn", number, name[0] if name else h[-40:]))
                else:
                    stack.append(("scope",))
                head = ""
            elif ch == "}":
                if stack:
                    k = stack.pop()
                    if k[0] in ("fn", "table") and not any(x[0] in ("fn", "table") for x in stack):
                        found.append((k[2], k[1], number - k[1] + 1, k[0] == "table"))
                head = ""
            elif ch == ";":
                head = ""
            else:
                head += ch
        head += " "
    return found, len(lines) - (1 if text.endswith("\n") else 0)


def main(argv):
    ap = argparse.ArgumentParser(prog="code_shape.py")
    ap.add_argument("--max-file", type=int, default=700)
    ap.add_argument("--max-function", type=int, default=120)
    ap.add_argument("--strict", action="store_true")
    a = ap.parse_args(argv)
    files, functions, tables = [], [], []
    for d in DIRS:
        for p in sorted((ROOT / d).rglob("*")):
            if p.suffix not in (".cpp", ".hpp", ".h", ".cc"):
                continue
            found, count = blocks(p)
            rel = p.relative_to(ROOT)
            if count > a.max_file:
                files.append((count, rel))
            for name, first, length, table in found:
                if length > a.max_function:
                    (tables if table else functions).append((length, f"{rel}:{first}", name))
    print(f"files over {a.max_file} lines: {len(files)}")
    for count, rel in sorted(files, reverse=True):
        print(f"  {count:5d}  {rel}")
    print(f"functions over {a.max_function} lines: {len(functions)}")
    for length, where, name in sorted(functions, reverse=True):
        print(f"  {length:5d}  {where}  {name}")
    print(f"tables over {a.max_function} lines (allowed): {len(tables)}")
    for length, where, name in sorted(tables, reverse=True):
        print(f"  {length:5d}  {where}")
    return 1 if a.strict and (files or functions) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
