#!/usr/bin/env python3
"""hairfilterd's /metrics, /healthz and /readyz under load.

Load clients send a known number of requests of every kind (served, refused
BUSY by a small queue, TOO_LARGE, INVALID spp, UNKNOWN_VARIANT) while this
scrapes /metrics over and over. Every scrape is parsed by two of
Prometheus's own parsers: promtool (Debian's prometheus package, the Go
parser the server uses; `promtool check metrics` also lints names, types
and help) and the Python client's text parser (Debian's
python3-prometheus-client). Counters must never go down between scrapes,
and once the load is done they must equal what the clients were answered,
status by status. /readyz must say 503 while the daemon drains. The
metrics served are the ones docs/SERVER.md's table lists, of the types it
gives, no more and no fewer (an operator writes alerts from that table).

usage: test_metrics.py HAIRFILTERD LOAD_CLIENT WEIGHTS_DIR
"""
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.parse
import urllib.request

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
# The Python client from the source tree, its own check of a frame's spp
# against the listed variant's turned off (libhairfilter, and so
# load_client, refuses such a frame before sending), so that the server
# refuses it INVALID.
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..",
                                "client", "python"))
import hairfilter  # noqa: E402
from opsdaemon import (Daemon, check, finish, load_result, run_then_stop,  # noqa: E402
                       run_load, sample, workdir)

HAIRFILTERD, LOAD_CLIENT, WEIGHTS = sys.argv[1:4]
class Refused(threading.Thread):
    """count Small frames of shape (h, w, spp*6) through the Python client,
    its own checks of the variant and of the server's announced limits
    turned off, so that the server answers them: 2 spp (Small takes 4) is
    INVALID, a size over --max-size TOO_LARGE. result() is shaped as
    load_client's report."""

    def __init__(self, url, count, shape, name):
        super().__init__()
        self.url, self.count, self.shape, self.name = url, count, shape, name
        self.report = {"sent": 0, "answered": 0, "connection_errors": 0, "status": {}}
        self.start()

    def run(self):
        try:
            with hairfilter.Client(self.url, client_name=self.name) as hf:
                hf._check_variant = lambda name, spp, given: None
                hf._check_limits = lambda *args: None
                features = np.zeros(self.shape, np.float32)
                for _ in range(self.count):
                    hf.submit("Small", features)
                    self.report["sent"] += 1
                    done = hf.wait()
                    self.report["answered"] += 1
                    st = self.report["status"]
                    st[done.status] = st.get(done.status, 0) + 1
        except (hairfilter.Error, OSError) as e:
            print("%s load: %s" % (self.name, e))
            self.report["connection_errors"] += 1

    def result(self):
        self.join(120)
        return self.report


def promtool(text):
    p = subprocess.run(["promtool", "check", "metrics"], input=text, capture_output=True,
                       text=True)
    return p.returncode, p.stdout + p.stderr


SERVER_MD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "docs",
                         "SERVER.md")


def documented_metrics():
    """{name: type or None} from docs/SERVER.md's metrics table ("The
    metrics (all `hairfilterd_` but the `process_` ones)"): a row's first
    cell names one or more metrics, its second their type, one for all or
    one each."""
    text = open(SERVER_MD).read()
    start = text.index("The metrics (all `hairfilterd_`")
    rows = []
    for line in text[start:].splitlines()[1:]:
        if rows and not line.startswith("|"):
            break
        if line.startswith("| `"):
            rows.append([c.strip() for c in line.strip("|").split("|")])
    doc = {}
    for cells in rows:
        names = [n.strip(" `") for n in cells[0].split(",")]
        types = [t.strip() for t in cells[1].split(",")] if cells[1] else []
        for i, n in enumerate(names):
            full = n if n.startswith("process_") else "hairfilterd_" + n
            doc[full] = (types[i] if len(types) == len(names) else types[0]) if types else None
    return doc


TLS_ONLY = {"hairfilterd_tls_certificate_expiry_timestamp_seconds"}


def served_metrics(text):
    """{name: type} from the # TYPE lines of a /metrics text."""
    return {l.split()[2]: l.split()[3] for l in text.splitlines() if l.startswith("# TYPE ")}


def documented_alerts():
    """[(comment, expression)] of docs/SERVER.md's "Alerts an operator
    starts from" block: each expression follows its # comment and may span
    lines."""
    text = open(SERVER_MD).read()
    block = text[text.index("Alerts an operator starts from"):]
    block = block[block.index("```") + 3:]
    block = block[:block.index("```")]
    alerts = []
    for line in block.strip().splitlines():
        if line.startswith("#"):
            alerts.append([line.lstrip("# "), ""])
        elif alerts:
            alerts[-1][1] += " " + line.strip()
    return [(c, e.strip()) for c, e in alerts]


def check_alerts():
    """Every alert expression SERVER.md gives parses as PromQL (promtool
    check rules) and names only metrics the table lists."""
    alerts, doc = documented_alerts(), documented_metrics()
    check(len(alerts) >= 4 and all(e for _, e in alerts),
          "SERVER.md's alert block: one expression per comment: %s" % alerts)
    rules = os.path.join(workdir(), "alerts.yml")
    with open(rules, "w") as f:
        f.write("groups:\n  - name: hairfilterd\n    rules:\n")
        for i, (comment, expr) in enumerate(alerts):
            f.write("      - alert: Doc%d\n        expr: %s\n" % (i, json.dumps(expr)))
    p = subprocess.run(["promtool", "check", "rules", rules], capture_output=True, text=True)
    check(p.returncode == 0, "promtool check rules on SERVER.md's alerts: %s" % (p.stdout + p.stderr))
    for comment, expr in alerts:
        names = set(re.findall(r"\b(hairfilterd_[a-z_]+?)(?:_bucket|_sum|_count)?\b", expr))
        unknown = sorted(n for n in names if n not in doc and
                         re.sub(r"_(bucket|sum|count)$", "", n) not in doc)
        check(not unknown, "alert '%s' names metrics not in the table: %s" % (comment, unknown))


def main():
    check_alerts()
    w = workdir()
    # The config file's keys lose to the command line's: its listener (in a
    # directory that does not exist) is replaced by the flag's, its queue
    # size by --queue-size (checked below as hairfilterd_queue_capacity 2).
    conf = os.path.join(w, "hairfilterd.conf")
    with open(conf, "w") as f:
        f.write("listen = unix:/nonexistent-dir/hf.sock\nqueue-size = 99\nmax-batch = 7\n")
    d = Daemon(HAIRFILTERD, [
        "--config", conf, "--listen", "unix:%s/s.sock" % w, "--http", "tcp:127.0.0.1:0",
        "--weights", os.path.join(WEIGHTS, "small.safetensors"),
        "--weights", os.path.join(WEIGHTS, "shallow.safetensors"),
        "--backend", "cpu-ref", "--queue-size", "2", "--max-inflight", "8",
        "--max-size", "64x64", "--max-batch", "2"], w)
    run_then_stop(d, w, lambda: run(d))
    w = workdir()
    d = Daemon(HAIRFILTERD, [
        "--listen", "unix:%s/s.sock" % w, "--http", "tcp:127.0.0.1:0",
        "--weights", os.path.join(WEIGHTS, "small.safetensors"), "--backend", "cpu-ref",
        "--queue-size", "8", "--max-size", "512x512"], w)
    run_then_stop(d, w, lambda: drain(d))
    w = workdir()
    d = Daemon(HAIRFILTERD, [
        "--listen", "unix:%s/s.sock" % w, "--http", "tcp:127.0.0.1:0",
        "--weights", os.path.join(WEIGHTS, "small.safetensors"), "--backend", "cpu-ref"], w)
    run_then_stop(d, w, lambda: crowd(d))


def run(d):
    unix = d.urls["unix"]
    check(d.get("/healthz") == (200, "ok\n"), "/healthz is 200 at rest")
    check(d.get("/readyz") == (200, "ready\n"), "/readyz is 200 at rest")
    check(d.get("/nope")[0] == 404, "unknown path is 404")
    # Another method: 405, saying which methods are taken (RFC 9110, 15.5.6).
    req = urllib.request.Request(d.urls["http"] + "/healthz", data=b"", method="POST")
    try:
        urllib.request.urlopen(req, timeout=10)
        check(False, "POST /healthz is refused")
    except urllib.error.HTTPError as e:
        check(e.code == 405 and e.headers.get("Allow") == "GET, HEAD" and
              e.read().decode() == "only GET and HEAD\n",
              "POST is 405 with Allow: GET, HEAD (%s %r)" % (e.code, e.headers.get("Allow")))
    samples, text = d.metrics()
    check(sample(samples, "hairfilterd_build_info", version=os.environ["HF_VERSION"],
                 protocol_min="1", protocol_max="4") == 1, "build_info with the version")
    check(sample(samples, "hairfilterd_queue_capacity") == 2, "queue capacity 2")
    rc, out = promtool(text)
    check(rc == 0, "promtool check metrics at rest: " + out)
    doc, served = documented_metrics(), served_metrics(text)
    check(sorted(set(served) - set(doc)) == [],
          "served but not in docs/SERVER.md's metrics table: %s" % sorted(set(served) - set(doc)))
    # Served only with a tls: listener (server.reload checks it there).
    unserved = sorted(set(doc) - set(served) - TLS_ONLY)
    check(unserved == [], "in docs/SERVER.md's metrics table but not served: %s" % unserved)
    wrong = {n: (doc[n], t) for n, t in served.items() if doc.get(n) and doc[n] != t}
    check(not wrong, "types in docs/SERVER.md's table (documented, served): %s" % wrong)

    # The load: every kind of answer, concurrently. The served load runs
    # until the scraper has scraped it a number of times.
    stop = os.path.join(os.path.dirname(d.ready), "stop-load")
    loads = {
        "served": run_load(LOAD_CLIENT, unix, "Small", 4, "32x32", connections=3, inflight=4,
                           until_file=stop),
        "shallow": run_load(LOAD_CLIENT, unix, "Shallow", 4, "16x16", count=20),
        # Clients refuse a frame over the announced size before sending it.
        "too_large": Refused(unix, 5, (64, 80, 4 * 6), "too-large"),
        "bad_spp": Refused(unix, 7, (16, 16, 2 * 6), "bad-spp"),
        "unknown": run_load(LOAD_CLIENT, unix, "Nope", 4, "16x16", count=3),
    }
    scrapes, lint = [], []
    while len(scrapes) < 10:
        s, t = d.metrics()
        scrapes.append(s)
        if len(lint) < 3:
            lint.append(promtool(t))
        time.sleep(0.05)
    still = loads["served"].poll() is None
    open(stop, "w").close()
    results = {k: p.result() if isinstance(p, Refused) else load_result(p)
               for k, p in loads.items()}
    print({k: r["status"] for k, r in results.items()})
    check(still, "the served load was still running at the last scrape")
    for rc, out in lint:
        check(rc == 0, "promtool check metrics under load: " + out)

    # Counters never go down.
    for a, b in zip(scrapes, scrapes[1:]):
        for key, v in a.items():
            name = key[0]
            if (name.endswith("_total") or name.endswith("_count") or
                    name.endswith("_bucket")) and key in b:
                if b[key] < v:
                    check(False, "%s went down: %s -> %s" % (key, v, b[key]))
                    break

    for k, r in results.items():
        check(r["connection_errors"] == 0 and r["sent"] == r["answered"],
              "%s: every request answered: %s" % (k, r))
    served = results["served"]["status"]
    check(served.get("BUSY", 0) > 0, "the small queue refused some requests BUSY: %s" % served)
    check(served.get("OK", 0) > 0, "some requests were served: %s" % served)

    ok = {"class": "ok", "status": "ok"}
    s, text = d.settled_metrics([
        ("hairfilterd_requests_total", dict(variant="Small", **ok), served.get("OK", 0)),
        ("hairfilterd_requests_total", dict(variant="Shallow", **ok),
         results["shallow"]["status"].get("OK", 0))])
    rc, out = promtool(text)
    check(rc == 0, "promtool check metrics after load: " + out)

    def req(variant, status):
        return sample(s, "hairfilterd_requests_total", variant=variant, status=status,
                      **{"class": {"ok": "ok", "busy": "overload"}.get(status, "client_error")})

    small_ok = served.get("OK", 0)
    small_busy = served.get("BUSY", 0) + results["too_large"]["status"].get("BUSY", 0) + \
        results["bad_spp"]["status"].get("BUSY", 0)
    check(req("Small", "ok") == small_ok, "Small ok %s == %s" % (req("Small", "ok"), small_ok))
    check(req("Small", "busy") == small_busy,
          "Small busy %s == %s" % (req("Small", "busy"), small_busy))
    check(req("Small", "too_large") == results["too_large"]["status"].get("TOO_LARGE"),
          "Small too_large %s == %s" % (req("Small", "too_large"), results["too_large"]))
    check(req("Small", "invalid") == results["bad_spp"]["status"].get("INVALID"),
          "Small invalid %s == %s" % (req("Small", "invalid"), results["bad_spp"]))
    check(req("", "unknown_variant") == 3, "unknown variant counted without a variant: %s" %
          req("", "unknown_variant"))
    shallow = results["shallow"]["status"]
    check(req("Shallow", "ok") == shallow.get("OK", 0) and
          req("Shallow", "busy") == shallow.get("BUSY", 0),
          "Shallow ok/busy %s/%s == %s" % (req("Shallow", "ok"), req("Shallow", "busy"), shallow))

    # Histograms: one observation per served request; batch sizes add up to
    # the frames served.
    for h in ("queue", "input", "inference", "output", "request"):
        name = "hairfilterd_%s_duration_seconds" % h
        check(sample(s, name + "_count", variant="Small") == small_ok,
              "%s count == %s" % (name, small_ok))
        check(sample(s, name + "_bucket", variant="Small", le="+Inf") == small_ok,
              "%s +Inf bucket == %s" % (name, small_ok))
    check(sample(s, "hairfilterd_batch_size_sum", variant="Small") == small_ok,
          "batch sizes add up to the frames served")
    check(sample(s, "hairfilterd_request_duration_seconds_sum", variant="Small") > 0,
          "request time sum > 0")
    pushed_out = sample(s, "hairfilterd_queue_pushed_out_total")
    all_busy = small_busy + shallow.get("BUSY", 0)
    check(pushed_out is not None and 0 <= pushed_out <= all_busy,
          "frames pushed out of the queue (%s) are among the BUSY ones (%s)" %
          (pushed_out, all_busy))
    print("frames pushed out of the queue for a connection under its share: %s" % pushed_out)
    check(sample(s, "hairfilterd_queue_depth") == 0, "queue empty after the load")
    check(sample(s, "hairfilterd_requests_in_flight") == 0, "nothing in flight after the load")
    check(sample(s, "hairfilterd_connections_total") >= 7, "connections counted")
    check(sample(s, "hairfilterd_variant_info", variant="Small", backend="cpu-ref",
                 precision="fp32", spp="4", levels="16,32,64",
                 file=os.path.join(WEIGHTS, "small.safetensors")) == 1, "variant_info of Small")
    check(sample(s, "hairfilterd_backend_info", backend="cpu-ref") == 1, "backend_info")
    check(sample(s, "hairfilterd_ready") == 1, "hairfilterd_ready 1")
    check(sample(s, "process_resident_memory_bytes") > 0, "process RSS")


def drain(d):
    """Draining: readiness goes 503 while liveness stays 200. Frames of
    512x512 on cpu-ref keep the worker busy for a while after SIGTERM (the
    first daemon's 64x64 frames could all be done before a poll saw it)."""
    slow = run_load(LOAD_CLIENT, d.urls["unix"], "Small", 4, "512x512", connections=2,
                    inflight=4, count=40)
    # SIGTERM once frames are in the server, so that there is a drain to see.
    t_end = time.time() + 30
    while time.time() < t_end:
        if (sample(d.metrics()[0], "hairfilterd_requests_in_flight") or 0) > 0:
            break
        time.sleep(0.01)
    d.signal(signal.SIGTERM)
    seen = None
    t_end = time.time() + 10
    while time.time() < t_end and d.proc.poll() is None:
        try:
            st, body = d.get("/readyz", timeout=2)
            hz = d.get("/healthz", timeout=2)
        except OSError:
            break
        if st == 503:
            seen = (st, body, hz)
            break
        time.sleep(0.01)
    check(seen is not None and "draining" in seen[1] and seen[2][0] == 200,
          "/readyz 503 'draining' and /healthz 200 while draining: %s" % (seen,))
    slow.communicate(timeout=120)


def crowd(d):
    """Probes get through a crowd on the HTTP port: 40 connections that
    trickle a request's headers a byte at a time (each byte restarts the
    idle timeout), then 40 that say nothing. The endpoint keeps 32; the
    oldest makes room for a new one."""
    u = urllib.parse.urlsplit(d.urls["http"])
    addr = (u.hostname, u.port)
    slow = []
    for _ in range(40):
        s = socket.create_connection(addr)
        s.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\n")
        slow.append(s)
        time.sleep(0.005)
    answered = 0
    for _ in range(6):
        for s in slow:
            try:
                s.send(b"X")
            except OSError:
                pass
        try:  # generous: the property is an answer, not its latency
            answered += d.get("/healthz", timeout=10) == (200, "ok\n")
        except OSError:
            pass
        time.sleep(0.3)
    check(answered == 6, "/healthz answered %d of 6 times among 40 trickling "
          "connections" % answered)
    # The oldest were closed to make room: they read the end of the stream.
    closed = 0
    for s in slow[:8]:
        s.settimeout(10)
        try:
            closed += s.recv(1) == b""
        except socket.timeout:
            pass  # still open
        except ConnectionError:
            closed += 1
    check(closed == 8, "%d of the 8 oldest trickling connections closed" % closed)
    for s in slow:
        s.close()
    idle = [socket.create_connection(addr) for _ in range(40)]
    try:
        st = d.get("/healthz", timeout=10)
    except OSError as e:
        st = e
    check(st == (200, "ok\n"), "/healthz among 40 silent connections: %s" % (st,))
    for s in idle:
        s.close()
    check(d.get("/metrics")[0] == 200, "/metrics after the crowds")


main()
finish()
