"""Helpers for the operator tests: start hairfilterd, read its ready file,
GET its HTTP endpoints, parse /metrics with Prometheus's Python client
parser (Debian's python3-prometheus-client), run the load client."""
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

from prometheus_client.parser import text_string_to_metric_families

# The tests' checks: one list of failures for every module a test uses.
from rawwire import check, failures, finish  # noqa: F401


class Daemon:
    def __init__(self, binary, args, workdir, env=None):
        self.ready = os.path.join(workdir, "ready")
        self.log = os.path.join(workdir, "daemon.log")
        if os.path.exists(self.ready):
            os.unlink(self.ready)
        e = dict(os.environ)
        e.update(env or {})
        self.logf = open(self.log, "w")
        self.proc = subprocess.Popen([binary] + args + ["--ready-file", self.ready],
                                     stdout=self.logf, stderr=subprocess.STDOUT, env=e)
        self.urls = {}
        deadline = time.time() + 60
        while time.time() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError("hairfilterd exited with %s:\n%s" % (self.proc.returncode,
                                                                       self.log_text()))
            if os.path.exists(self.ready):
                for line in open(self.ready).read().split():
                    self.urls[line.split(":", 1)[0]] = line
                break
            time.sleep(0.02)
        else:
            self.proc.kill()
            raise RuntimeError("hairfilterd did not become ready:\n" + self.log_text())

    def log_text(self):
        if not self.logf.closed:
            self.logf.flush()
        return open(self.log).read()

    def signal(self, sig):
        self.proc.send_signal(sig)

    def stop(self, timeout=30):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
        self.logf.close()
        return rc

    def get(self, path, timeout=10):
        """(status, body) of GET path on the daemon's HTTP endpoint."""
        try:
            with urllib.request.urlopen(self.urls["http"] + path, timeout=timeout) as r:
                return r.status, r.read().decode()
        except urllib.error.HTTPError as e:
            return e.code, e.read().decode()

    def metrics(self):
        """Every sample of /metrics: {(name, frozenset(labels.items())): value},
        parsed by prometheus_client's text parser (which raises on text it
        cannot parse), and the raw text."""
        status, text = self.get("/metrics")
        assert status == 200, (status, text)
        samples = {}
        for fam in text_string_to_metric_families(text):
            for s in fam.samples:
                samples[(s.name, frozenset(s.labels.items()))] = s.value
        return samples, text

    def settled_metrics(self, want, timeout=10):
        """metrics() once every (name, labels, value) in want is reached, or
        after timeout seconds. A reply is counted in its write's completion,
        which the server's loop may run just after the client has read the
        reply, so counters read right after a load can lag by the last few."""
        t_end = time.time() + timeout
        while True:
            samples, text = self.metrics()
            if all(sample(samples, n, **l) == v for n, l, v in want) or time.time() > t_end:
                return samples, text
            time.sleep(0.05)


def sample(samples, name, **labels):
    return samples.get((name, frozenset(labels.items())))


def set_weights_name(src, dst, name):
    """Copies a safetensors file with its variant name changed in the
    metadata (weights/FORMAT.md), written beside dst and renamed over it, as
    a deployment would replace a file."""
    raw = open(src, "rb").read()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    meta = json.loads(header["__metadata__"]["hairfilter"])
    meta["name"] = name
    header["__metadata__"]["hairfilter"] = json.dumps(meta)
    hb = json.dumps(header).encode()
    hb += b" " * (-len(hb) % 8)
    tmp = dst + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(hb)) + hb + raw[8 + n:])
    os.replace(tmp, dst)


def run_load(load_client, server, variant, spp, size="16x16", connections=1, inflight=1,
             count=None, until_file=None):
    args = [load_client, "--server", server, "--variant", variant, "--spp", str(spp),
            "--size", size, "--connections", str(connections), "--inflight", str(inflight)]
    args += ["--count", str(count)] if count is not None else ["--until-file", until_file]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def load_result(proc, timeout=120):
    out, err = proc.communicate(timeout=timeout)
    if not out.strip():
        raise RuntimeError("load_client printed nothing: " + err)
    return json.loads(out)


def run_then_stop(d, w, body, after=None):
    """Runs body(), then stops the daemon (which must exit 0), runs
    after(d) on the stopped daemon (its log complete) when given, prints its
    log when a check failed, and removes the work directory w."""
    try:
        body()
    finally:
        rc = d.stop()
        check(rc == 0, "daemon exited %s" % rc)
        if after and rc == 0:
            after(d)
        if failures:
            print(d.log_text())
        cleanup(w)


def workdir():
    d = tempfile.mkdtemp(prefix="hfops-")
    os.chmod(d, 0o755)
    return d


def cleanup(d):
    shutil.rmtree(d, ignore_errors=True)
