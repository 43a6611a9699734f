"""client/lib/examples/filter_exr.cpp (a feature EXR read with OpenEXR's C++
API and filtered with hairfilter.hpp) gives what `hairfilter filter` gives
for the same file: the same values in color, highlight and alpha, the same
data and display windows. Files: a 64x64 frame (Kernel); the same frame
with the alpha-corrected estimate (the example's default, KernelMix, the
estimate from a buffer of its own); a crop of it (KernelAC), tiled, HALF, with its data window inside a larger
display window. A file without the channels the variant reads fails with
the channel named, an unknown variant with the server's listed.

usage: test_example_filter_exr.py HAIRFILTERD HAIRFILTER FILTER_EXR WEIGHTS FRAME"""
import os
import subprocess
import sys

import numpy as np
import OpenImageIO as oiio

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "server"))
from opsdaemon import Daemon, check, finish, run_then_stop, workdir  # noqa: E402

HAIRFILTERD, HAIRFILTER, FILTER_EXR, WEIGHTS, FRAME = sys.argv[1:6]


def read(path):
    """(pixels [h][w][c] float32, channel names, (x, y, w, h), (full w, full h))."""
    i = oiio.ImageInput.open(path)
    check(i is not None, "%s does not open: %s" % (path, oiio.geterror()))
    s = i.spec()
    px = i.read_image(oiio.FLOAT)
    i.close()
    return px, list(s.channelnames), (s.x, s.y, s.width, s.height), (s.full_width, s.full_height)


def write(path, px, names, window=None, full=None, tiled=False, half=False):
    h, w, c = px.shape
    s = oiio.ImageSpec(w, h, c, oiio.HALF if half else oiio.FLOAT)
    s.channelnames = tuple(names)
    if window:
        s.x, s.y = window
    if full:
        s.full_width, s.full_height = full
    if tiled:
        s.tile_width = s.tile_height = 16
    s.attribute("compression", "zip")
    o = oiio.ImageOutput.create(path)
    check(o.open(path, s), "write %s: %s" % (path, o.geterror()))
    o.write_image(px)
    o.close()


def make_files(w):
    """The frame with the estimate (each pixel's sample mean of colour,
    highlight, alpha), and a tiled HALF crop of it."""
    px, names, _, _ = read(FRAME)
    mean = [px[..., [names.index("S%d.%s" % (k, f)) for k in range(4)]].mean(axis=-1)
            for f in ("color", "highlight", "alpha")]
    est = np.concatenate([px, np.stack(mean, axis=-1)], axis=-1).astype(np.float32)
    est_names = names + ["acst4.color", "acst4.highlight", "acst4.alpha"]
    ac = os.path.join(w, "ac.exr")
    write(ac, est, est_names)
    crop = os.path.join(w, "crop.exr")
    write(crop, np.ascontiguousarray(est[20:50, 10:50]), est_names, window=(10, 20),
          full=(64, 64), tiled=True, half=True)
    return ac, crop


def compare(d, w, tag, frame, variant):
    """The example's result against hairfilter filter's for frame."""
    mine, theirs = os.path.join(w, tag + "_example.exr"), os.path.join(w, tag + "_cli.exr")
    p = subprocess.run([FILTER_EXR, d.urls["unix"], frame, mine] +
                       ([variant] if variant != "default" else []),
                       capture_output=True, text=True, timeout=60)
    check(p.returncode == 0, "%s: filter_exr: rc %d: %s" % (tag, p.returncode, p.stderr))
    q = subprocess.run([HAIRFILTER, "filter", "--server", d.urls["unix"], "--in", frame,
                        "--out", theirs, "--variant",
                        variant if variant != "default" else "KernelMix"],
                       capture_output=True, text=True, timeout=60)
    check(q.returncode == 0, "%s: hairfilter filter: rc %d: %s" % (tag, q.returncode, q.stderr))
    if p.returncode or q.returncode:
        return
    a, an, aw, af = read(mine)
    b, bn, bw, bf = read(theirs)
    check(aw == bw and af == bf, "%s: windows %s %s against %s %s" % (tag, aw, af, bw, bf))
    for ch in ("color", "highlight", "alpha"):
        x, y = a[..., an.index(ch)], b[..., bn.index(ch)]
        check(x.shape == y.shape and np.array_equal(x, y),
              "%s: channel %s differs (max %g)" % (tag, ch, np.abs(x - y).max()
                                                   if x.shape == y.shape else -1))
    print("%s: %s, window %s of %s, %s" % (tag, variant, aw, af, p.stdout.strip()))


def body(d, w):
    ac, crop = make_files(w)
    compare(d, w, "frame", FRAME, "Kernel")
    compare(d, w, "estimate", ac, "default")     # KernelMix for a file with acst4.*
    compare(d, w, "crop", crop, "KernelAC")
    p = subprocess.run([FILTER_EXR, d.urls["unix"], FRAME, os.path.join(w, "x.exr"), "KernelAC"],
                       capture_output=True, text=True, timeout=60)
    check(p.returncode == 1 and "no channel acst4.color" in p.stderr,
          "KernelAC on a file without the estimate names the channel: rc %d %r"
          % (p.returncode, p.stderr))
    p = subprocess.run([FILTER_EXR, d.urls["unix"], FRAME, os.path.join(w, "x.exr"), "Bsae"],
                       capture_output=True, text=True, timeout=60)
    check(p.returncode == 1 and "no variant Bsae; it has Kernel, KernelAC" in p.stderr,
          "an unknown variant lists the server's: rc %d %r" % (p.returncode, p.stderr))
    p = subprocess.run([FILTER_EXR, d.urls["unix"]], capture_output=True, text=True, timeout=60)
    check(p.returncode == 2 and "usage: filter_exr" in p.stderr,
          "a wrong command line: rc %d %r" % (p.returncode, p.stderr))


w = workdir()
args = ["--listen", "unix:%s/s.sock" % w, "--backend", "cpu-ref", "--max-size", "64x64"]
for f in ("kernel.safetensors", "kernel_ac.safetensors", "kernel_mix.safetensors"):
    args += ["--weights", os.path.join(WEIGHTS, f)]
d = Daemon(HAIRFILTERD, args, w)
run_then_stop(d, w, lambda: body(d, w))
finish()
