#!/usr/bin/python3
"""weights/experiments/swap_truth.py against the renderer: a dataset
rendered with the 4x4 truth and every baseline, the same frames' 8x8
truth rendered alone, swapped. The output keeps the samples and baselines
of the first to the bit and holds the truth of the second; its manifest
says gt_supersample 8, so hairfilter eval no longer warns of a truth on
the MSAA positions; truths of other frames (another seed) are refused,
and nothing is written then. Needs numpy and OpenImageIO; without them the
test is skipped (77)."""
import argparse
import json
import os
import shutil
import subprocess
import sys

try:
    import numpy as np
    import OpenImageIO as oiio
except ImportError as e:
    print(f"render.swap_truth skipped: {e}", file=sys.stderr)
    sys.exit(77)

SWAP = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "weights",
                    "experiments", "swap_truth.py")
WARNING = "sub-pixel centres include the MSAA sample positions"


def run(cmd, ok=True):
    r = subprocess.run(cmd, capture_output=True, text=True)
    if ok and r.returncode != 0:
        sys.exit(f"FAIL: {' '.join(cmd)} -> {r.returncode}\n{r.stderr}")
    return r


def channels(path):
    buf = oiio.ImageBuf(path)
    return list(buf.spec().channelnames), buf.get_pixels(oiio.FLOAT)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--hairfilter", required=True)
    ap.add_argument("--work", required=True)
    a = ap.parse_args()
    shutil.rmtree(a.work, ignore_errors=True)
    dirs = {k: os.path.join(a.work, k) for k in ("gt4", "gt8", "gt8_seed", "out", "bad")}
    for k in ("gt4", "gt8", "gt8_seed"):
        os.makedirs(dirs[k])
    common = [a.hairfilter, "render", "dataset", "--styles", "wavy,curly", "--count", "1",
              "--size", "40x32", "--strands", "1500", "--spp", "4", "--quiet"]
    run(common + ["--st", "4,16", "--gt-ss", "4", "--seed", "3", "--out", dirs["gt4"]])
    run(common + ["--no-alpha-corrected", "--seed", "3", "--out", dirs["gt8"]])
    run(common + ["--no-alpha-corrected", "--seed", "4", "--out", dirs["gt8_seed"]])

    if WARNING not in run([a.hairfilter, "eval", dirs["gt4"]]).stderr:
        sys.exit("FAIL: eval did not warn of the 4x4 truth")
    run([sys.executable, SWAP, dirs["gt4"], dirs["gt8"], dirs["out"]])
    names = sorted(f for f in os.listdir(dirs["gt4"]) if f.endswith(".exr"))
    if sorted(f for f in os.listdir(dirs["out"]) if f.endswith(".exr")) != names or len(names) != 2:
        sys.exit(f"FAIL: frames written {os.listdir(dirs['out'])}, expected {names}")
    for n in names:
        ch4, px4 = channels(os.path.join(dirs["gt4"], n))
        ch8, px8 = channels(os.path.join(dirs["gt8"], n))
        cho, pxo = channels(os.path.join(dirs["out"], n))
        if cho != ch4:
            sys.exit(f"FAIL: {n}: channels {cho}, expected {ch4}")
        truth = [c for c in ch4 if c.startswith("gt.")]
        moved = 0
        for c in ch4:
            src = (px8[..., ch8.index(c)] if c in truth else px4[..., ch4.index(c)])
            if not np.array_equal(pxo[..., cho.index(c)], src):
                sys.exit(f"FAIL: {n}: {c} is not the {'8x8 truth' if c in truth else 'original'}")
            if c in truth:
                moved += not np.array_equal(px4[..., ch4.index(c)], src)
        if moved == 0:
            sys.exit(f"FAIL: {n}: the 4x4 and 8x8 truths are the same; the test shows nothing")
    with open(os.path.join(dirs["out"], "manifest.json")) as f:
        m = json.load(f)
    if [fr["gt_supersample"] for fr in m["frames"]] != [8, 8] or m["st"] != [4, 16]:
        sys.exit(f"FAIL: manifest {m['st']}, {[fr['gt_supersample'] for fr in m['frames']]}")
    if WARNING in run([a.hairfilter, "eval", dirs["out"]]).stderr:
        sys.exit("FAIL: eval warned of the swapped 8x8 truth")
    # The EXR header's record of the truth is the truth's, so a frame taken
    # out of its directory says so too.
    for n in names:
        spec = oiio.ImageInput.open(os.path.join(dirs["out"], n)).spec()
        got = [spec.getattribute(k) for k in ("hairfilter:gtSupersample",
                                              "hairfilter:gtSharedPositions")]
        if got != [8, 0]:
            sys.exit(f"FAIL: {n}: header says gtSupersample, gtSharedPositions {got}, "
                     "expected the 8x8 truth's [8, 0]")
    os.remove(os.path.join(dirs["out"], "manifest.json"))
    if WARNING in run([a.hairfilter, "eval", dirs["out"]]).stderr:
        sys.exit("FAIL: eval warned of the swapped 8x8 truth without the manifest")

    r = run([sys.executable, SWAP, dirs["gt4"], dirs["gt8_seed"], dirs["bad"]], ok=False)
    if r.returncode != 1 or "differs between the two renderings" not in r.stderr:
        sys.exit(f"FAIL: other frames' truth: {r.returncode} {r.stderr}")
    if os.path.exists(dirs["bad"]):
        sys.exit("FAIL: a refused swap wrote its output directory")
    r = run([sys.executable, SWAP, dirs["gt4"], dirs["gt8"], dirs["gt4"]], ok=False)
    if r.returncode != 1 or "one of the input directories" not in r.stderr:
        sys.exit(f"FAIL: OUT_DIR = FRAMES_DIR: {r.returncode} {r.stderr}")
    print("swap_truth: 2 frames swapped and checked; other frames' truth refused")


if __name__ == "__main__":
    main()
