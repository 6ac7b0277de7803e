#!/usr/bin/env python3
"""Lists C++ function definitions longer than a limit, longest first.

    scripts/function_lengths.py [--limit N] [--all] PATH...

A function's length is the number of source lines from the first line of its
declaration head (return type, name, parameters) to the line of its closing
brace, comments and blank lines included. Functions are found by brace
matching after comments, string and character literals are blanked out: a
`{` whose head (the text since the previous `;`, `{` or `}`) ends in a
parameter list, optionally followed by qualifiers or a trailing return type,
opens a function unless the head starts with a control keyword. Lambdas and
local classes count towards the function that holds them.

Exit status: 0 when no function is over the limit, 1 otherwise, 2 on usage
errors.
"""
import argparse
import pathlib
import re
import sys

SOURCE_SUFFIXES = {".cpp", ".cc", ".cxx", ".h", ".hpp", ".inl"}
CONTROL = {"if", "for", "while", "switch", "catch", "do", "else", "try", "return", "namespace", "struct", "class",
           "union", "enum"}
FUNCTION_HEAD_END = re.compile(
    r"\)\s*(?:(?:const|noexcept|override|final|mutable|volatile|&&|&)\s*)*(?:->\s*[\w:<>,\s*&]+)?$")


def blank_literals_and_comments(text):
    """The text with comments and literals replaced by spaces, newlines kept."""
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
        elif c == 'R' and text.startswith('R"', i) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            open_paren = text.find("(", i + 2)
            delimiter = text[i + 2:open_paren]
            j = text.find(")" + delimiter + '"', open_paren)
            j = n if j < 0 else j + len(delimiter) + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c in "\"'":
            if c == "'" and i > 0 and text[i - 1].isalnum():  # digit separator: 1'000
                out.append(" ")
                i += 1
                continue
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(" " * (j - i))
            i = j
        else:
            out.append(c)
            i += 1
    return "".join(out)


def function_name(head):
    before_params = head[:head.find("(")].rstrip()
    match = re.search(r"([\w:~]+(?:\s*<[^()]*>)?|operator\s*\S+)$", before_params)
    return match.group(1) if match else before_params.split()[-1]


def functions(path):
    """(name, first line, last line) of every function defined in `path`."""
    text = blank_literals_and_comments(path.read_text(encoding="utf-8", errors="replace"))
    found = []
    stack = []  # per open brace: (is_function, name, first line)
    head_start = 0
    for i, c in enumerate(text):
        if c not in "{};":
            continue
        if c == "{":
            head = text[head_start:i].strip()
            inside_function = any(is_function for is_function, _, _ in stack)
            first_word = re.match(r"\w*", head).group(0)
            is_function = (not inside_function and "(" in head and first_word not in CONTROL and
                           "=" not in head[:head.find("(")] and FUNCTION_HEAD_END.search(head) is not None)
            first_line = text.count("\n", 0, head_start + (len(text[head_start:i]) - len(text[head_start:i].lstrip())))
            stack.append((is_function, function_name(head) if is_function else "", first_line + 1))
        elif c == "}" and stack:
            is_function, name, first_line = stack.pop()
            if is_function:
                found.append((name, first_line, text.count("\n", 0, i) + 1))
        head_start = i + 1
    return found


def source_files(paths):
    for p in map(pathlib.Path, paths):
        if p.is_dir():
            yield from sorted(f for f in p.rglob("*") if f.suffix in SOURCE_SUFFIXES)
        else:
            yield p


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("paths", nargs="+", help="source files or folders (searched recursively)")
    parser.add_argument("--limit", type=int, default=120, help="longest allowed function in lines (default 120)")
    parser.add_argument("--all", action="store_true", help="list every function, not only those over the limit")
    args = parser.parse_args()
    rows = []
    for f in source_files(args.paths):
        if not f.is_file():
            print(f"function_lengths.py: {f}: no such file", file=sys.stderr)
            return 2
        for name, first, last in functions(f):
            rows.append((last - first + 1, f"{f}:{first}", name))
    rows.sort(key=lambda r: (-r[0], r[1]))
    over = [r for r in rows if r[0] > args.limit]
    for length, where, name in rows if args.all else over:
        print(f"{length:5d}  {where}  {name}")
    print(f"{len(over)} of {len(rows)} functions longer than {args.limit} lines", file=sys.stderr)
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
