#!/usr/bin/env python3
"""Checks that every option the documentation gives a command exists.

Reads the Markdown files named on the command line, finds each command line
of hairfilterd, hairfilter-load and `hairfilter SUBCOMMAND` in their code
(fenced blocks, indented blocks and inline code spans), and checks each
`--option` written after it against what that command's `--help` lists.
Documentation that names an option a tool does not have (renamed, removed,
misspelt) sends a reader to a usage error; this finds it before they do.

The project's Python scripts (a path ending in .py after python3) are
checked the same way against their own --help, run in an empty folder; a
script path that names no file in the source tree, a --help that exits
with an error or prints nothing, and one that writes files (taking --help
for an argument) are reported too.

usage: doc_options.py SOURCE_DIR BUILD_DIR FILE.md...
Exit status 0 when every option is known, 1 when one is not (each printed
as FILE:LINE: TOOL --option), 2 on bad arguments.
"""

import os
import re
import shlex
import subprocess
import sys
import tempfile

TOOLS = ("hairfilterd", "hairfilter-load", "hairfilter")
SUBCOMMANDS = ("demo", "infer", "filter", "render", "bench", "eval",
               "conformance", "load")
SEPARATORS = {"|", "||", "&&", ";", "&", ")", "(", "$(", "`"}
OPTION = re.compile(r"^--[a-z0-9][a-z0-9-]*")


def code_lines(path):
    """Yields (line number, text) of the code in a Markdown file.

    Fenced and indented blocks give their lines, backslash continuations
    joined; prose gives its inline code spans.
    """
    with open(path, encoding="utf-8") as f:
        lines = f.read().split("\n")
    fenced = False
    pending, pending_no = "", 0
    prev_blank = True
    in_indented = False
    for no, line in enumerate(lines, 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            prev_blank = False
            continue
        indented = (line.startswith("    ") and (prev_blank or in_indented)
                    and line.strip() != "")
        if fenced or indented:
            in_indented = indented
            text = line.strip()
            if pending:
                text = pending + " " + text
                no = pending_no
            if text.endswith("\\"):
                pending, pending_no = text[:-1], no
                continue
            pending = ""
            yield no, text
        else:
            in_indented = False
            for span in re.findall(r"`([^`]+)`", line):
                yield no, span
        prev_blank = line.strip() == ""


def tokens(text):
    """Splits a shell line into words, separators apart; never raises."""
    text = text.replace("$ ", " ", 1) if text.startswith("$ ") else text
    try:
        lexer = shlex.shlex(text, posix=True, punctuation_chars="|&;()")
        lexer.whitespace_split = True
        lexer.commenters = "#"
        return list(lexer)
    except ValueError:
        return text.split()


def invocations(words):
    """Yields (tool key, [option words]) for each tool run in the words."""
    i = 0
    while i < len(words):
        name = os.path.basename(words[i])
        # A script is run when an interpreter comes before it; a path
        # alone in inline code is a mention (`weights/hfnet.py`), not a
        # command.
        if (name.endswith(".py") and "/" in words[i] and i > 0
                and re.fullmatch(r"python3?(\.\d+)?", os.path.basename(words[i - 1]))):
            key = os.path.normpath(words[i])
        elif name in TOOLS:
            key = name
        else:
            i += 1
            continue
        i += 1
        if name == "hairfilter":
            if i >= len(words) or words[i] not in SUBCOMMANDS:
                continue
            key = "hairfilter " + words[i]
            i += 1
        opts = []
        while i < len(words) and words[i] not in SEPARATORS:
            if os.path.basename(words[i]) in TOOLS or words[i].endswith(".py"):
                break
            word = words[i].strip("[]{},.:")
            for part in word.split("|"):
                m = OPTION.match(part)
                if m:
                    opts.append(m.group(0))
            i += 1
        yield key, opts


def find_script(source, doc, key):
    """A script's path: from the source root, from the document's folder,
    or from the root with the leading ../ of a command run after a cd."""
    stripped = key
    while stripped.startswith("../"):
        stripped = stripped[3:]
    for path in (os.path.join(source, key),
                 os.path.join(os.path.dirname(doc), key),
                 os.path.join(source, stripped)):
        if os.path.isfile(path):
            return path
    return None


def help_options(source, build, doc, key):
    """The options a command's --help lists; None for a missing script, or
    a string saying what is wrong with its --help."""
    if key.endswith(".py"):
        script = find_script(source, doc, key)
        if script is None:
            return None
        cmd = [sys.executable, os.path.abspath(script), "--help"]
    else:
        parts = key.split()
        exe = os.path.abspath(os.path.join(build, parts[0]))
        cmd = ([exe] + parts[1:] + (["frame"] if parts[1:] == ["render"] else [])
               + ["--help"])
    # In an empty folder of its own: a tool that takes --help for an
    # argument (an output folder, say) writes there, and is caught.
    with tempfile.TemporaryDirectory() as cwd:
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              timeout=60, check=False, cwd=cwd)
        wrote = sorted(os.listdir(cwd))
    out = proc.stdout.decode("utf-8", "replace")
    if wrote:
        return "`%s --help` wrote %s instead of printing its usage" % (key, ", ".join(wrote))
    if proc.returncode != 0 or not out.strip():
        return "`%s --help` exits %d%s" % (key, proc.returncode,
                                           "" if out.strip() else " and prints nothing")
    return set(re.findall(r"--[a-z0-9][a-z0-9-]*", out)) | {"--help"}


def main(argv):
    if len(argv) < 4:
        print(__doc__.strip().split("\n\n")[3], file=sys.stderr)
        return 2
    source, build, files = argv[1], argv[2], argv[3:]
    known = {}
    faults = 0
    checked = 0
    for path in files:
        for no, text in code_lines(path):
            for key, opts in invocations(tokens(text)):
                if key not in known:
                    known[key] = help_options(source, build, path, key)
                if known[key] is None or isinstance(known[key], str):
                    print(f"{path}:{no}: {key}: " + (known[key] or "no such script"))
                    faults += 1
                    continue
                for opt in opts:
                    checked += 1
                    if opt not in known[key]:
                        print(f"{path}:{no}: {key} {opt}: not in "
                              f"`{key} --help`")
                        faults += 1
    print(f"{checked} option(s) of {len(known)} command(s) checked, "
          f"{faults} unknown")
    return 1 if faults else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
