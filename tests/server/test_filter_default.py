"""hairfilter filter without --variant: the server's only variant, else
KernelMix (the bundled default), else KernelAC, for a frame with the
alpha-corrected estimate when the server has it, else Kernel (any frame) when
it has it, else a clear error that lists what the server has. The default's
result must equal the one named explicitly, byte for byte."""
import os
import subprocess
import sys

from opsdaemon import Daemon, check, finish, run_then_stop, workdir

HAIRFILTERD, HAIRFILTER, WEIGHTS, FRAME = sys.argv[1:5]


def filt(d, w, out, *extra, frame=FRAME):
    p = subprocess.run([HAIRFILTER, "filter", "--server", d.urls["unix"], "--in", frame,
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


def estimate_frame(w):
    """A 64x64 frame of the renderer's defaults, the estimate (acst4.*)
    included."""
    out = os.path.join(w, "ac.exr")
    p = subprocess.run([HAIRFILTER, "render", "frame", "--style", "wavy", "--size", "64x64",
                        "--strands", "3000", "--gt-ss", "1", "--st", "4", "--out", out],
                       capture_output=True, text=True, timeout=120)
    check(p.returncode == 0, "render: %s" % p.stderr)
    return out


def default_is(d, w, frame, name, served):
    """filter without --variant of frame takes variant name, whose result it
    gives byte for byte; served: the server's variants, for the messages."""
    rc, text = filt(d, w, "default_%s.exr" % name, frame=frame)
    check(rc == 0 and name in text, "filter without --variant of a frame with the "
          "estimate on %s: rc %d: %s" % (served, rc, text))
    rc2, text2 = filt(d, w, "named_%s.exr" % name, "--variant", name, frame=frame)
    check(rc2 == 0, "filter --variant %s: rc %d: %s" % (name, rc2, text2))
    if rc == 0 and rc2 == 0:
        a = open(os.path.join(w, "default_%s.exr" % name), "rb").read()
        b = open(os.path.join(w, "named_%s.exr" % name), "rb").read()
        check(a == b, "the default result differs from --variant %s's" % name)


def with_estimate_variant(d, w):
    ac = estimate_frame(w)
    default_is(d, w, ac, "KernelAC", "Kernel+KernelAC")
    # A frame without the estimate: Kernel, as named.
    several_with_kernel(d, w)
    # KernelAC named for a frame without the estimate: the render option named.
    rc3, text3 = filt(d, w, "x.exr", "--variant", "KernelAC")
    check(rc3 != 0 and "acst4.color" in text3 and "--no-alpha-corrected" in text3,
          "KernelAC on a frame without the estimate names what is missing: %r" % text3)


def with_mix_variant(d, w):
    """The bundled default, KernelMix, before KernelAC on a server with both."""
    default_is(d, w, estimate_frame(w), "KernelMix", "Kernel+KernelAC+KernelMix")


def estimate_frame_without_kernel_ac(d, w):
    """A frame with the estimate on a server without KernelAC: Kernel, which
    reads the samples alone."""
    rc, text = filt(d, w, "k.exr", frame=estimate_frame(w))
    check(rc == 0 and "Kernel " in text and "KernelAC" not in text,
          "filter without --variant of a frame with the estimate on Small+Kernel: rc %d: %s"
          % (rc, text))


def several_without_kernel(d, w):
    rc, text = filt(d, w, "x.exr")
    check(rc != 0, "filter without --variant on Small+Shallow succeeded")
    check("name a --variant" in text and "Small" in text and "Shallow" in text,
          "the error names the choice and lists the variants: %r" % text)


def list_header(d, w):
    """--list's first line gives the server's limits: spp as the most any
    variant takes (it read "4 spp" beside a variant of 1 spp)."""
    p = subprocess.run([HAIRFILTER, "filter", "--server", d.urls["unix"], "--list"],
                       capture_output=True, text=True, timeout=60)
    head = p.stdout.splitlines()[0] if p.stdout else ""
    check(p.returncode == 0 and ", up to 4 spp," in head and "Base@1spp" in p.stdout,
          "--list's header says up to 4 spp: rc %d: %r" % (p.returncode, p.stdout + p.stderr))


def only_one(d, w):
    rc, text = filt(d, w, "one.exr")
    check(rc == 0, "filter without --variant on Small alone: rc %d: %s" % (rc, text))


with_daemon(["small.safetensors", "kernel.safetensors"], several_with_kernel)
with_daemon(["kernel.safetensors", "kernel_ac.safetensors"], with_estimate_variant)
with_daemon(["kernel.safetensors", "kernel_ac.safetensors", "kernel_mix.safetensors"],
            with_mix_variant)
with_daemon(["small.safetensors", "kernel.safetensors"], estimate_frame_without_kernel_ac)
with_daemon(["small.safetensors", "shallow.safetensors"], several_without_kernel)
with_daemon(["small.safetensors"], only_one)
with_daemon(["small.safetensors", "base_1spp.safetensors"], list_header)
finish()
