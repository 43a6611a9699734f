"""The load tool drives a variant that reads the alpha-corrected estimate:
hairfilter-load against hairfilterd serving KernelAC (protocol version 3)
sends every frame with its estimate, over the socket and shared memory, f32
and f16, and gets no error; the daemon served them all. Against a daemon
without shared memory (--max-shm-mb 0), hairfilter-load --shm stops before
the run with status 2, saying so (it ran an empty window and printed a
report of zeros after "not supported here (a dtype, a flag, or ...)")."""
import re
import subprocess
import sys

from opsdaemon import Daemon, check, finish, run_then_stop, workdir

HAIRFILTERD, LOAD, WEIGHTS = sys.argv[1:4]


def drive(d, w):
    for extra in ([], ["--shm", "--f16"]):
        p = subprocess.run([LOAD, "--server", d.urls["unix"], "--variant", "KernelAC",
                            "--size", "48x32", "--seconds", "1", "--warmup", "0.2"] + extra,
                           capture_output=True, text=True, timeout=60)
        out = p.stdout + p.stderr
        m = re.search(r"frames (\d+) .* errors (\d+)", out)
        check(p.returncode == 0 and m and int(m.group(1)) > 0 and m.group(2) == "0",
              "hairfilter-load %s on KernelAC: rc %d: %s" % (" ".join(extra), p.returncode, out))


def no_shm(d, w):
    p = subprocess.run([LOAD, "--server", d.urls["unix"], "--variant", "KernelAC",
                        "--size", "48x32", "--seconds", "1", "--shm"],
                       capture_output=True, text=True, timeout=60)
    out = p.stdout + p.stderr
    check(p.returncode == 2 and "offers no shared memory" in out and "--max-shm-mb 0" in out
          and "frames 0" not in out,
          "hairfilter-load --shm without shared memory: rc %d (want 2): %s" % (p.returncode, out))


w = workdir()
d = Daemon(HAIRFILTERD, ["--listen", "unix:%s/s.sock" % w, "--backend", "cpu-ref",
                         "--max-size", "64x64", "--max-shm-mb", "0",
                         "--weights", WEIGHTS + "/kernel_ac.safetensors"], w)
run_then_stop(d, w, lambda: no_shm(d, w))
w = workdir()
d = Daemon(HAIRFILTERD, ["--listen", "unix:%s/s.sock" % w, "--backend", "cpu-ref",
                         "--max-size", "64x64", "--weights", WEIGHTS + "/kernel_ac.safetensors"], w)
run_then_stop(d, w, lambda: drive(d, w))
finish()
