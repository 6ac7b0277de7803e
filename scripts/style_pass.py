#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""The steps of the mechanical style pass (docs/style.md) that clang-format cannot do.

scripts/apply_style.sh runs them for one part; scripts/check_style.sh uses `files`.

  style_pass.py files PART...        the part's sources that clang-format keeps (one a line)
  style_pass.py rename PART BUILD    clang-tidy's naming fixes for the names the part declares,
                                     applied to every file that uses them
  style_pass.py headers PART         .hpp -> .h (includes and CMake lists follow) and
                                     #ifndef guards -> #pragma once
  style_pass.py spdx PART            the SPDX line first in every .cpp/.h/.c

Each step is idempotent: a second run changes nothing.
"""
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
PARTS = ["abi", "traces", "engine", "replay", "analyze", "capture", "tools", "tests", "bench",
         "examples", "common"]
SOURCE_EXTS = (".cpp", ".h", ".hpp", ".c")
SPDX = "// SPDX-License-Identifier: Apache-2.0"
JOBS = os.cpu_count() or 2


def tracked(part):
    out = subprocess.run(["git", "ls-files", "-z", "--", part], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    return [f for f in out.split("\0") if f and os.path.exists(os.path.join(ROOT, f))]


def sources(part):
    return [f for f in tracked(part) if f.endswith(SOURCE_EXTS)]


def read(path):
    with open(os.path.join(ROOT, path), encoding="utf-8", errors="surrogateescape") as f:
        return f.read()


def write(path, text):
    with open(os.path.join(ROOT, path), "w", encoding="utf-8", errors="surrogateescape") as f:
        f.write(text)


# ---------------------------------------------------------------------------------------------
# Renames: clang-tidy's readability-identifier-naming fixes, kept only for declarations inside
# the part, applied wherever clang-tidy saw a use.


def in_tree(path):
    """A file of ours: under the root, not in a build folder (/build*/ in .gitignore)."""
    return path.startswith(ROOT + os.sep) and not os.path.relpath(path, ROOT).startswith("build")


def compile_commands(build):
    with open(os.path.join(build, "compile_commands.json")) as f:
        entries = json.load(f)
    by_file = {}
    for e in entries:
        path = os.path.normpath(os.path.join(e["directory"], e["file"]))
        if in_tree(path):
            by_file[path] = e
    return by_file


def dependencies(entry):
    """In-tree files the translation unit reads (the preprocessor's -MM list)."""
    args = entry.get("arguments") or shlex.split(entry["command"])
    cmd, skip = [], False
    for a in args:
        if skip:
            skip = False
            continue
        if a in ("-o", "-c"):
            skip = a == "-o"
            continue
        cmd.append(a)
    cmd += ["-MM", "-MG", "-MF", "-", "-w"]
    r = subprocess.run(cmd, cwd=entry["directory"], capture_output=True, text=True)
    if r.returncode != 0:
        return None
    paths = r.stdout.replace("\\\n", " ").split(":", 1)[-1].split()
    deps = set()
    for p in paths:
        p = os.path.normpath(os.path.join(entry["directory"], p))
        if in_tree(p):
            deps.add(p)
    return deps


def cached_dependencies(build, units):
    """dependencies() of every unit, kept in BUILD between parts: a part's pass changes no
    include except .hpp -> .h, and an entry naming a file that is gone is scanned again."""
    cache_path = os.path.join(build, "style_dependencies.json")
    try:
        with open(cache_path) as f:
            cache = {u: set(d) for u, d in json.load(f).items()}
    except (OSError, ValueError):
        cache = {}
    stale = [u for u in units if u not in cache or not all(map(os.path.exists, cache[u]))]
    with ThreadPoolExecutor(JOBS * 2) as pool:
        for u, d in zip(stale, pool.map(dependencies, (units[u] for u in stale))):
            cache[u] = d
    with open(cache_path, "w") as f:
        json.dump({u: sorted(d) for u, d in cache.items() if d is not None and u in units}, f)
    return {u: cache.get(u) for u in units}


def run_tidy(build, files, part, fixes_dir):
    """clang-tidy over `files` in parallel; returns the exported-fix files."""
    header_filter = "^" + re.escape(os.path.join(ROOT, part)) + "/"

    os.makedirs(fixes_dir, exist_ok=True)

    def one(i_path):
        i, path = i_path
        out = os.path.join(fixes_dir, f"{i}.yaml")
        r = subprocess.run(["clang-tidy-14", "-p", build, "--quiet",
                            "--header-filter=" + header_filter, "--export-fixes=" + out, path],
                           capture_output=True, text=True)
        if "error:" in r.stdout and not os.path.exists(out):
            sys.stderr.write(f"style: clang-tidy could not parse {path}\n{r.stdout[-2000:]}\n")
        return out

    with ThreadPoolExecutor(JOBS) as pool:
        return [p for p in pool.map(one, enumerate(sorted(files))) if os.path.exists(p)]


new_names = {}  # old spelling -> new, of every name renamed so far


def collect_renames(fix_files, part):
    """{file: {(offset, length): text}} for the part's declarations; and the old names."""
    import yaml  # python3-yaml; imported here so that `files` needs nothing beyond Python

    prefix = os.path.join(ROOT, part) + os.sep
    edits, names = {}, set()
    for path in fix_files:
        with open(path) as f:
            doc = yaml.safe_load(f) or {}
        for d in doc.get("Diagnostics") or []:
            message = d.get("DiagnosticMessage") or {}
            if not message.get("FilePath", "").startswith(prefix):
                continue
            m = re.search(r"for (.+) '([^']+)'", message.get("Message", ""))
            if m:
                names.add((m.group(1) == "enum constant", m.group(2)))
                for r in message.get("Replacements") or []:
                    new_names[(m.group(1) == "enum constant", m.group(2))] = r["ReplacementText"]
            for r in message.get("Replacements") or []:
                target = os.path.normpath(r["FilePath"])
                if not target.startswith(ROOT + os.sep):
                    continue
                edits.setdefault(target, {})[(r["Offset"], r["Length"])] = r["ReplacementText"]
    return edits, names


IDENTIFIER = re.compile(rb"[A-Za-z_]\w*")


BARE_IDENTIFIER = re.compile(rb"(?<![\w.>:])([A-Za-z_]\w*)")


def collisions(edits):
    """Renames whose new name the file already uses as a bare name: T -> t beside a loop counter
    t compiles and silently changes what the code means, so such a rename is refused."""
    found = []
    for path, spans in edits.items():
        with open(path, "rb") as f:
            data = f.read()
        bare = {m.group(1).decode() for m in BARE_IDENTIFIER.finditer(data)}
        for (offset, length), text in spans.items():
            old = data[offset:offset + length].decode(errors="replace")
            start = data[max(0, offset - 2):offset]
            if text != old and text in bare and not start.endswith((b".", b">", b"::")):
                found.append(f"{os.path.relpath(path, ROOT)}: {old} -> {text}")
    return sorted(set(found))


def apply_edits(edits):
    clash = collisions(edits)
    if clash:
        sys.stderr.write("style: these renames would collide with names already in the file; "
                         "rename them by hand first:\n  " + "\n  ".join(clash) + "\n")
        sys.exit(1)
    changed = 0
    for path, spans in edits.items():
        with open(path, "rb") as f:
            data = f.read()
        last_start = len(data) + 1
        for (offset, length), text in sorted(spans.items(), reverse=True):
            # clang-tidy 14 renames a variable that a lambda captures by default by replacing
            # the capture default ('&' or '='): only identifiers are ever replaced.
            if not IDENTIFIER.fullmatch(data[offset:offset + length]):
                continue
            if offset + length > last_start:
                sys.stderr.write(f"style: overlapping rename at {path}:{offset} skipped\n")
                continue
            data = data[:offset] + text.encode() + data[offset + length:]
            last_start = offset
        with open(path, "wb") as f:
            f.write(data)
        changed += 1
    return changed


def rename(part, build):
    build = os.path.abspath(build)
    units = compile_commands(build)
    part_dir = os.path.join(ROOT, part) + os.sep
    deps = cached_dependencies(build, units)
    # First round: the part's own translation units, plus one unit for each of the part's
    # headers that none of them reads. It finds every name the part declares wrongly.
    first = {u for u in units if u.startswith(part_dir)}
    covered = set().union(*(deps[u] or set() for u in first)) if first else set()
    for header in (os.path.join(ROOT, h) for h in sources(part) if not h.endswith((".cpp", ".c"))):
        if header in covered:
            continue
        user = next((u for u in sorted(units) if deps[u] and header in deps[u]), None)
        if user:
            first.add(user)
            covered |= deps[user]
    with tempfile.TemporaryDirectory() as tmp:
        fix_files = run_tidy(build, first, part, tmp)
        edits, names = collect_renames(fix_files, part)
        if not names:
            print(f"style: {part}: no names to change ({len(first)} units checked)")
            return
        # Second round: units elsewhere that read one of the names (in their own file or in a
        # header of another part), so that their uses change with the declaration.
        # Enum values are found by their qualified use (`Kind::value`): bare, names like `ok`
        # would select nearly every unit.
        word = re.compile("|".join(("::" if enum else r"\b") + re.escape(name) + r"\b"
                                   for enum, name in sorted(names)))
        second = set()
        for u, d in deps.items():
            if u in first or not d or not any(p.startswith(part_dir) for p in d):
                continue
            if any(not p.startswith(part_dir) and word.search(read(p)) for p in d):
                second.add(u)
        fix_files = run_tidy(build, second, part, tmp + "/2") if second else []
        more, _ = collect_renames(fix_files, part) if second else ({}, set())
        for path, spans in more.items():
            edits.setdefault(path, {}).update(spans)
        changed = apply_edits(edits)
        changed_macros = rename_in_macros()
        print(f"style: {part}: {len(names)} names changed in {changed} files "
              f"({len(first)} + {len(second)} units checked); macro bodies fixed in "
              f"{changed_macros} files")


MACRO = re.compile(r"^[ \t]*#[ \t]*define\b(?:[^\n]*\\\n)*[^\n]*", re.M)


def rename_in_macros():
    """clang-tidy leaves uses inside #define bodies alone: rename them by spelling, only where
    the spelling says what it is: members and methods after `.` or `->`, enum values after
    `::`, and only camelCase or PascalCase spellings. A local variable used in a macro is left
    alone (clang-tidy leaves its declaration alone too)."""
    def pattern(after, names):
        if not names:
            return None
        return re.compile(after + r"(" + "|".join(map(re.escape, sorted(names))) + r")\b")

    members = {o: n for (enum, o), n in new_names.items() if not enum and re.search("[A-Z]", o)}
    values = {o: n for (enum, o), n in new_names.items() if enum and o != n}
    rules = [(p, m) for p, m in ((pattern(r"(?:(?<=\.)|(?<=->))", members), members),
                                 (pattern(r"(?<=::)", values), values)) if p]
    if not rules:
        return 0
    count = 0
    for part in PARTS:
        for f in sources(part):
            text = read(f)
            if "#" not in text:
                continue

            def fix(m):
                body = m.group(0)
                for p, names in rules:
                    body = p.sub(lambda w: names[w.group(1)], body)
                return body

            new = MACRO.sub(fix, text)
            if new != text:
                write(f, new)
                count += 1
    return count


# ---------------------------------------------------------------------------------------------
# Headers: .hpp -> .h, include guards -> #pragma once.

TEXT_EXTS = SOURCE_EXTS + (".inc", ".txt", ".md", ".cmake", ".py", ".sh", ".fbs")


def rename_hpp(part):
    moved = []
    for f in sources(part):
        if not f.endswith(".hpp"):
            continue
        target = f[:-4] + ".h"
        if os.path.exists(os.path.join(ROOT, target)):
            sys.stderr.write(f"style: {f} not renamed: {target} exists\n")
            continue
        subprocess.run(["git", "mv", f, target], cwd=ROOT, check=True)
        moved.append(os.path.basename(f))
    if not moved:
        return
    pattern = re.compile(r"(?<=[\"</\s])(" + "|".join(map(re.escape, moved)) + r")\b")
    for f in tracked("."):
        if not (f.endswith(TEXT_EXTS) or os.path.basename(f) == "CMakeLists.txt"):
            continue
        text = read(f)
        new = pattern.sub(lambda m: m.group(1)[:-4] + ".h", text)
        if new != text:
            write(f, new)
    print(f"style: {part}: {len(moved)} .hpp files renamed to .h")


GUARD_OPEN = re.compile(r"^#ifndef\s+(\w+)[ \t]*\n#define\s+\1[ \t]*\n", re.M)
GUARD_CLOSE = re.compile(r"\n#endif[^\n]*\n?\s*\Z")


def pragma_once(part):
    count = 0
    for f in sources(part):
        if not f.endswith((".h", ".hpp")):
            continue
        text = read(f)
        m = GUARD_OPEN.search(text)
        # Only a guard that opens the file: nothing but comments and blank lines before it.
        if not m or "#pragma once" in text:
            continue
        before = re.sub(r"//[^\n]*|/\*.*?\*/", "", text[:m.start()], flags=re.S)
        if before.strip():
            continue
        close = GUARD_CLOSE.search(text)
        if not close:
            continue
        write(f, text[:m.start()] + "#pragma once\n" + text[m.end():close.start()] + "\n")
        count += 1
    if count:
        print(f"style: {part}: {count} include guards became #pragma once")


def spdx(part):
    count = 0
    for f in sources(part):
        text = read(f)
        # A file that names its own licence (the stand-in driver is MIT) keeps it.
        if text.startswith("// SPDX-License-Identifier: "):
            continue
        write(f, SPDX + "\n" + text)
        count += 1
    if count:
        print(f"style: {part}: SPDX line added to {count} files")


def main(argv):
    if len(argv) < 3 or argv[1] not in ("files", "rename", "headers", "spdx"):
        sys.stderr.write(__doc__)
        return 2
    command, parts = argv[1], argv[2:]
    if command == "rename":
        if len(parts) != 2:
            sys.stderr.write("usage: style_pass.py rename PART BUILD_DIR\n")
            return 2
        parts, build = parts[:1], parts[1]
    for part in parts:
        if part not in PARTS:
            sys.stderr.write(f"style: unknown part '{part}' (parts: {' '.join(PARTS)})\n")
            return 2
    for part in parts:
        if command == "files":
            for f in sources(part):
                print(f)
        elif command == "rename":
            rename(part, build)
        elif command == "headers":
            rename_hpp(part)
            pragma_once(part)
        elif command == "spdx":
            spdx(part)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
