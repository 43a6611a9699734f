#!/usr/bin/env python3
"""deploy/container/Dockerfile installs what its binaries need.

For every shared library the built binaries load (ldd), the Debian package
that holds it must be installed in the runtime stage (its apt-get list,
their dependencies, or what debian:12-slim holds for apt), and the package
that holds the link-time name (libX.so, the -dev package) of each one a
binary links directly in the build stage. There is no docker here: the check reads this machine's dpkg
database, whose packages are Debian 12's, as the images' are. CUDA's and
cuDNN's libraries come from the GPU images (CUDNN=ON), and a sanitizer
tree's runtimes are not the image's: both are left out.

usage: container_packages.py DOCKERFILE BINARY...   (exit 77: cannot check)
"""
import os
import re
import shutil
import subprocess
import sys


def stage_lists(dockerfile):
    """The packages of each stage's apt-get install, in stage order."""
    text = open(dockerfile).read().replace("\\\n", " ")
    stages = []
    for line in text.splitlines():
        if line.startswith("FROM "):
            stages.append(set())
        m = re.search(r"apt-get install ([^&]*)", line)
        if m and stages:
            stages[-1] |= {w for w in m.group(1).split() if not w.startswith("-")}
    return stages


def closure(packages):
    out = subprocess.run(
        ["apt-cache", "depends", "--recurse", "--no-recommends", "--no-suggests",
         "--no-conflicts", "--no-breaks", "--no-replaces", "--no-enhances", *sorted(packages)],
        capture_output=True, text=True).stdout
    return {l.strip() for l in out.splitlines() if l and not l.startswith((" ", "<"))}


def owner(path):
    """The package holding path (under /usr or /, merged /usr), or None."""
    alt = path[4:] if path.startswith("/usr/") else "/usr" + path
    for p in (path, alt):
        r = subprocess.run(["dpkg", "-S", p], capture_output=True, text=True)
        for line in r.stdout.splitlines():
            if not line.startswith("diversion"):
                return line.split(":")[0]
    return None


def main():
    dockerfile, binaries = sys.argv[1], sys.argv[2:]
    for tool in ("dpkg", "apt-cache", "ldd", "readelf"):
        if not shutil.which(tool):
            print(f"SKIP: no {tool}")
            return 77
    stages = stage_lists(dockerfile)
    if len(stages) != 2 or not all(stages):
        print(f"FAIL: {dockerfile}: want two stages, each with an apt-get install list")
        return 1
    build = closure(stages[0])
    runtime = closure(stages[1] | {"apt"})   # slim holds apt and what it needs
    if "libc6" not in runtime:
        print("SKIP: apt-cache knows no packages (run apt-get update)")
        return 77
    failed, checked = [], 0
    for binary in binaries:
        dyn = subprocess.run(["readelf", "-d", binary], capture_output=True, text=True,
                             check=True).stdout
        needed = set(re.findall(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]", dyn))
        out = subprocess.run(["ldd", binary], capture_output=True, text=True, check=True).stdout
        for m in re.finditer(r"^\s*(\S+) => (\S+)", out, re.M):
            name, path = m.groups()
            # CUDA's (the GPU images'), and the sanitizers' runtimes of a
            # sanitizer tree (the image is built without them).
            if re.match(r"lib(cud|cublas|nv|asan|ubsan|lsan|tsan)", name):
                continue
            checked += 1
            pkg = owner(os.path.realpath(path)) or owner(path)
            if not pkg:
                failed.append(f"{binary} needs {path}, which no Debian package holds")
                continue
            if pkg not in runtime:
                failed.append(f"{binary} needs {name} from {pkg}, which the runtime stage "
                              f"does not install: add {pkg} to its apt-get install")
            if name not in needed or re.match(r"(libc|libm|libgcc_s|libstdc\+\+|libgomp)\.so", name):
                continue   # linked by a library, or the compiler's and libc's (build-essential)
            dev = re.sub(r"\.so\..*$", ".so", path)
            devpkg = owner(dev)
            if not devpkg:
                failed.append(f"no package holds {dev}, the link-time name of {name}")
            elif devpkg not in build:
                failed.append(f"{binary} links {name}, whose {dev} is in {devpkg}, which the "
                              f"build stage does not install: add {devpkg} to its apt-get install")
    for f in failed:
        print("FAIL:", f)
    if not checked:
        print("FAIL: ldd listed no libraries")
        return 1
    if failed:
        return 1
    print(f"{checked} libraries of {len(binaries)} binaries: each in the runtime stage, "
          f"its -dev package in the build stage")
    return 0


if __name__ == "__main__":
    sys.exit(main())
