#!/usr/bin/env python3
"""Lists C++ functions longer than a limit, longest first.

A function's length is its lines from the first line of its signature to its closing
brace. Functions are found by brace matching over the text with comments, string and
character literals blanked out: a brace opened outside any function body whose header (the
text since the previous ';', '{' or '}') ends in a parameter list, optionally followed by
qualifiers, a trailing return type or a constructor's initializer list, opens a function
body; every brace inside it belongs to that function (lambdas count toward their enclosing
function). Heuristic, but without a compiler or ctags.

    scripts/function_lengths.py [--limit N] [--all] PATH...   (files or folders)
Exit status 1 when some function is over the limit, so CI can use it as a check.
"""
import argparse
import os
import re
import sys

SOURCE_SUFFIXES = (".cpp", ".cc", ".cxx", ".c", ".h", ".hpp", ".hh", ".inl")
CONTROL = re.compile(r"\b(if|for|while|switch|catch|do|else|try)\s*(\(|$)")
SCOPE = re.compile(r"\b(namespace|class|struct|union|enum)\b|extern\s+\"C\"")


def blank_literals(text):
    """Comments and literals become spaces (newlines kept), so braces inside them do not count."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == 'R' and text.startswith('R"', i):
            m = re.match(r'R"([^(\s]*)\(', text[i:])
            if not m:
                out.append(c)
                i += 1
                continue
            end = text.find(")" + m.group(1) + '"', i)
            j = n if end < 0 else end + len(m.group(1)) + 2
            out.append('""' + re.sub(r"[^\n]", " ", text[i + 2:j]))
            i = j
        elif c in "\"'":
            # A digit separator (1'000) is not a character literal.
            if c == "'" and i > 0 and text[i - 1].isalnum():
                out.append(c)
                i += 1
                continue
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            out.append(c + " " * (min(j, n) - i - 1) + (c if j < n else ""))
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def is_function_header(header):
    h = " ".join(header.split())
    if not h or "=" in h.split("(")[0] and not h.startswith("operator"):
        return False  # an initializer (`x = {`), not a body; `operator=` has its '=' after the name
    if CONTROL.search(h) and not re.search(r"\)\s*(const|noexcept|override|final|->|:)", h.split("(", 1)[0] + "(x)"):
        if re.match(r"^(if|for|while|switch|catch|do|else|try)\b", h):
            return False
    if SCOPE.search(h) and "(" not in h:
        return False
    # Strip a constructor's initializer list: `...) : a_(x), b_{y}`.
    m = re.search(r"\)\s*(const\s*)?(noexcept\s*(\([^)]*\))?\s*)?:\s*[\w:]+\s*[({]", h)
    if m:
        return True
    return re.search(r"\)\s*(const|volatile|noexcept(\s*\([^)]*\))?|override|final|&|&&|->\s*[\w:<>,\s*&]+|\s)*$", h) is not None


def functions(path):
    text = blank_literals(open(path, encoding="utf-8", errors="replace").read())
    stack = []  # per open brace: "fn" or "scope"/"other"
    header_start = 0
    fn_start_line = 0
    fn_name = ""
    line = 1
    line_at = [0]
    for i, c in enumerate(text):
        if c == "\n":
            line_at.append(i + 1)
    def line_of(pos):
        lo, hi = 0, len(line_at) - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if line_at[mid] <= pos:
                lo = mid
            else:
                hi = mid - 1
        return lo + 1
    for i, c in enumerate(text):
        if c not in "{};":
            continue
        inside_fn = "fn" in stack or "other" in stack
        if c == "{":
            if inside_fn:
                stack.append("nested")
            else:
                header = text[header_start:i]
                # Preprocessor lines are not part of a header.
                header = "\n".join(l for l in header.split("\n") if not l.lstrip().startswith("#"))
                if is_function_header(header):
                    stripped = header.lstrip()
                    start = line_of(header_start + (len(text[header_start:i]) - len(text[header_start:i].lstrip())))
                    name = re.findall(r"([~\w:]+(?:operator\s*[^\s(]+)?)\s*\(", stripped)
                    stack.append("fn")
                    fn_start_line, fn_name = start, (name[0] if name else "?")
                elif SCOPE.search(header) and "(" not in header:
                    stack.append("scope")
                else:
                    stack.append("other")
            header_start = i + 1
        elif c == "}":
            kind = stack.pop() if stack else "scope"
            if kind == "fn":
                yield fn_name, fn_start_line, line_of(i) - fn_start_line + 1
            if not ("fn" in stack or "other" in stack):
                header_start = i + 1
        elif c == ";" and not inside_fn:
            header_start = i + 1


def source_files(paths):
    for p in paths:
        if os.path.isdir(p):
            for root, dirs, files in os.walk(p):
                dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != "build")
                for f in sorted(files):
                    if f.endswith(SOURCE_SUFFIXES):
                        yield os.path.join(root, f)
        else:
            yield p


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--limit", type=int, default=120, help="report functions longer than this (default 120)")
    ap.add_argument("--all", action="store_true", help="list every function, not only those over the limit")
    args = ap.parse_args()
    found = []
    for path in source_files(args.paths):
        for name, start, length in functions(path):
            found.append((length, path, start, name))
    found.sort(key=lambda f: (-f[0], f[1], f[2]))
    over = [f for f in found if f[0] > args.limit]
    for length, path, start, name in (found if args.all else over):
        print(f"{length:5d}  {path}:{start}  {name}")
    print(f"{len(found)} functions, {len(over)} longer than {args.limit} lines, longest "
          f"{found[0][0] if found else 0}", file=sys.stderr)
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
