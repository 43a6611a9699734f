#!/usr/bin/python3
"""The asset tools of client/render/tools against the renderer:

- hair_models.py: the four models carry per-point widths in the range
  they document and draw hair (the fur with its body mesh as occluder,
  the spiky and coily cuts over the fitted head);
- hair_convert.py: a model rewritten z up in centimetres, loaded with
  --up z --units cm, covers the same samples as the original, and loaded
  without them (taken as y up) does not; a damaged input is refused.

Compares the renderer's own regime line (stderr of `render frame`), so it
needs no image reader. Needs numpy; without it the test is skipped (77)."""
import argparse
import os
import re
import struct
import subprocess
import sys

try:
    import numpy as np
except ImportError:
    print("render.asset_tools skipped: numpy not found", file=sys.stderr)
    sys.exit(77)

TOOLS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "client", "render",
                     "tools")
REGIME = re.compile(r"samples covered ([0-9.]+), hair pixels ([0-9.]+)")


def run(cmd):
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"FAIL: {' '.join(cmd)} -> {r.returncode}\n{r.stderr}")
    return r.stderr


def coverage(hf, work, name, args):
    err = run([hf, "render", "frame", "--size", "64x64", "--gt-ss", "0", "--spp", "4",
               "--no-alpha-corrected", "--out", os.path.join(work, name + ".exr")] + args)
    m = REGIME.search(err)
    if not m:
        sys.exit(f"FAIL: no regime line from render frame {' '.join(args)}:\n{err}")
    return float(m.group(1)), float(m.group(2))


def read_header(path):
    b = open(path, "rb").read()
    strands, points, flags, _ = struct.unpack_from("<4I", b, 4)
    return b, strands, points, flags


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--hairfilter", required=True)
    ap.add_argument("--work", required=True)
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    hf, w = a.hairfilter, a.work
    py = sys.executable

    # hair_models.py: per-point widths as documented
    tied = os.path.join(w, "tied.hair")
    fur = os.path.join(w, "fur.hair")
    body = os.path.join(w, "body.obj")
    run([py, os.path.join(TOOLS, "hair_models.py"), "tied", tied, "--strands", "400"])
    run([py, os.path.join(TOOLS, "hair_models.py"), "fur", fur, "--strands", "400", "--mesh", body])
    spiky = os.path.join(w, "spiky.hair")
    coily = os.path.join(w, "coily.hair")
    run([py, os.path.join(TOOLS, "hair_models.py"), "spiky", spiky, "--strands", "400"])
    run([py, os.path.join(TOOLS, "hair_models.py"), "coily", coily, "--strands", "400"])
    for path, lo, hi in ((tied, 0.0012, 0.0035), (fur, 0.03, 0.09), (spiky, 0.003, 0.009),
                         (coily, 0.05, 0.09)):
        b, strands, points, flags = read_header(path)
        if strands != 400 or flags != 1 | 2 | 4:
            sys.exit(f"FAIL: {path}: {strands} strands, flags {flags} (want 400, 7)")
        thk = np.frombuffer(b, "<f4", points, 128 + 2 * strands + 12 * points)
        if len(b) != 128 + 2 * strands + 16 * points:
            sys.exit(f"FAIL: {path}: {len(b)} bytes for {strands} strands, {points} points")
        if abs(thk.min() - lo) > 1e-6 or abs(thk.max() - hi) > 1e-6:
            sys.exit(f"FAIL: {path}: widths {thk.min()}..{thk.max()}, want {lo}..{hi}")
    if sum(1 for line in open(body) if line.startswith("f ")) < 1000:
        sys.exit(f"FAIL: {body}: too few triangles for the body")

    # refusals name the option or the directory, and write nothing
    for args, needle in ((["tied", tied, "--mesh", body], "only the fur model has a body mesh"),
                         (["fur", os.path.join(w, "none", "f.hair")], "does not exist; create it first")):
        r = subprocess.run([py, os.path.join(TOOLS, "hair_models.py")] + args, capture_output=True,
                           text=True)
        if r.returncode == 0 or needle not in r.stderr:
            sys.exit(f"FAIL: hair_models.py {' '.join(args)} -> {r.returncode}: {r.stderr}")

    # hair_convert.py: the tied model (y up, inches) rewritten z up in
    # centimetres covers the same samples when loaded with that convention
    # and the same width, and other samples when taken as y up
    conv = os.path.join(w, "tied_zup_cm.hair")
    run([py, os.path.join(TOOLS, "hair_convert.py"), tied, conv, "--up", "z", "--scale", "2.54"])
    # a damaged or cut-short input is refused naming the file and the
    # reason, as the renderer refuses it; it was rewritten into a file that
    # looked whole, or failed with a numpy traceback
    b = open(tied, "rb").read()
    for name, blob, needle in (
            ("cut.hair", b[:len(b) - 5], "the file is cut short"),
            ("header.hair", b[:100], "shorter than the 128-byte header"),
            ("count.hair", b[:8] + struct.pack("<I", struct.unpack_from("<I", b, 8)[0] - 1) + b[12:],
             "the header says"),
            ("big.hair", b[:4] + b"".join(b[i:i + 4][::-1] for i in range(4, 40, 4)) + b[40:],
             "big-endian")):
        bad = os.path.join(w, name)
        with open(bad, "wb") as f:
            f.write(blob)
        out = os.path.join(w, "conv_" + name)
        if os.path.exists(out):
            os.remove(out)   # from an earlier run
        r = subprocess.run([py, os.path.join(TOOLS, "hair_convert.py"), bad, out],
                           capture_output=True, text=True)
        if r.returncode == 0 or f"hair_convert.py: {bad}: " not in r.stderr or \
                needle not in r.stderr or "Traceback" in r.stderr or os.path.exists(out):
            sys.exit(f"FAIL: hair_convert.py {bad} -> {r.returncode}: {r.stderr}")
    ref = coverage(hf, w, "ref", ["--hair", tied, "--units", "in", "--thickness", "0.004",
                                  "--cam-yaw", "40"])
    got = coverage(hf, w, "conv", ["--hair", conv, "--up", "z", "--units", "cm",
                                    "--thickness", "0.01016", "--cam-yaw", "40"])
    wrong = coverage(hf, w, "wrong", ["--hair", conv, "--units", "cm", "--thickness", "0.01016",
                                      "--cam-yaw", "40"])
    print(f"coverage (samples, hair pixels): original {ref}, converted {got}, "
          f"converted taken as y up {wrong}")
    if ref[1] <= 0.01:
        sys.exit("FAIL: the original draws no hair")
    if abs(ref[0] - got[0]) > 0.002 or abs(ref[1] - got[1]) > 0.002:
        sys.exit(f"FAIL: the converted model covers {got}, the original {ref}")
    if abs(ref[1] - wrong[1]) <= 0.002 and abs(ref[0] - wrong[0]) <= 0.002:
        sys.exit("FAIL: the up axis changed nothing: the comparison cannot tell conventions apart")

    # the models draw hair, the fur with its body as the occluder
    t = coverage(hf, w, "tied", ["--hair", tied, "--units", "in", "--children", "4"])
    # (fur 2 mm wide: at 64x64 its own 0.03-0.09 mm would be 1/200 of a pixel)
    f = coverage(hf, w, "fur", ["--hair", fur, "--up", "z", "--units", "mm", "--children", "8",
                                "--thickness", "2", "--occluder", body])
    f_fit = coverage(hf, w, "fur_fit", ["--hair", fur, "--up", "z", "--units", "mm",
                                        "--children", "8", "--thickness", "2"])
    # the spiky and coily cuts over the fitted head, 8 times as wide to
    # show at 64x64, each in its own convention
    sp, co = (coverage(hf, w, name, ["--hair", path, "--occluder", "fit", "--thickness-scale", "8"]
                       + conv_args)
              for name, path, conv_args in (("spiky", spiky, ["--up", "z", "--units", "cm"]),
                                            ("coily", coily, ["--units", "mm"])))
    print(f"coverage: tied {t}, fur with its body {f}, fur with the fitted occluder {f_fit}, "
          f"spiky {sp}, coily {co}")
    if min(t[1], f[1], sp[1], co[1]) <= 0.02:
        sys.exit("FAIL: a model draws (almost) no hair")
    # the body hides the fur behind it: fewer samples than over a smaller
    # fitted ellipsoid is not guaranteed, but the same count would mean the
    # mesh was not used
    if abs(f[0] - f_fit[0]) < 1e-4:
        sys.exit("FAIL: the body mesh changed nothing")
    print("PASS")


if __name__ == "__main__":
    main()
