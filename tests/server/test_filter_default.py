"""hairfilter filter without --variant: the server's only variant, else
Kernel (the bundled default) when the server has it, else a clear error
that lists what the server has. The Kernel result must equal the one named
explicitly, byte for byte."""
import os
import subprocess
import sys

from opsdaemon import Daemon, check, finish, run_then_stop, workdir

HAIRFILTERD, HAIRFILTER, WEIGHTS, FRAME = sys.argv[1:5]


def filt(d, w, out, *extra):
    p = subprocess.run([HAIRFILTER, "filter", "--server", d.urls["unix"], "--in", FRAME,
                        "--out", os.path.join(w, out)] + list(extra),
                       capture_output=True, text=True, timeout=120)
    return p.returncode, p.stdout + p.stderr


def with_daemon(files, body):
    w = workdir()
    args = ["--listen", "unix:%s/s.sock" % w, "--backend", "cpu-ref", "--max-size", "64x64"]
    for f in files:
        args += ["--weights", os.path.join(WEIGHTS, f)]
    d = Daemon(HAIRFILTERD, args, w)
    run_then_stop(d, w, lambda: body(d, w))


def several_with_kernel(d, w):
    rc, text = filt(d, w, "default.exr")
    check(rc == 0, "filter without --variant on Small+Kernel: rc %d: %s" % (rc, text))
    rc2, text2 = filt(d, w, "named.exr", "--variant", "Kernel")
    check(rc2 == 0, "filter --variant Kernel: rc %d: %s" % (rc2, text2))
    if rc == 0 and rc2 == 0:
        a = open(os.path.join(w, "default.exr"), "rb").read()
        b = open(os.path.join(w, "named.exr"), "rb").read()
        check(a == b, "the default result differs from --variant Kernel's")


def several_without_kernel(d, w):
    rc, text = filt(d, w, "x.exr")
    check(rc != 0, "filter without --variant on Small+Shallow succeeded")
    check("name a --variant" in text and "Small" in text and "Shallow" in text,
          "the error names the choice and lists the variants: %r" % text)


def only_one(d, w):
    rc, text = filt(d, w, "one.exr")
    check(rc == 0, "filter without --variant on Small alone: rc %d: %s" % (rc, text))


with_daemon(["small.safetensors", "kernel.safetensors"], several_with_kernel)
with_daemon(["small.safetensors", "shallow.safetensors"], several_without_kernel)
with_daemon(["small.safetensors"], only_one)
finish()
