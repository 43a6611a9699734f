#!/usr/bin/env python3
"""SIGHUP reloads under load: variants added, replaced and removed with no
request lost; a failed load keeps the old version serving and is counted;
readiness goes 503 while a configured file serves nothing; a config file
error is logged at error level and changes nothing; each changed key that
needs a restart is named with its old and new values; SIGUSR1 logs the
statistics and changes nothing; the stop line counts the requests of
a removed variant. The daemon is configured through a
config file (hairfilterd.conf), which the reload reads again. A TLS
certificate that does not load on reload (a renewal gone wrong) makes the
reload a failed one in the log and in hairfilterd_reloads_total, and a
good one after it an ok one.

usage: test_reload.py HAIRFILTERD LOAD_CLIENT WEIGHTS_DIR MAKE_TEST_CERTS
"""
import os
import shutil
import signal
import ssl
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from opsdaemon import (Daemon, check, finish, load_result, run_then_stop,  # noqa: E402
                       run_load, sample, set_weights_name, workdir)

HAIRFILTERD, LOAD_CLIENT, WEIGHTS, MAKE_TEST_CERTS = sys.argv[1:5]
def write_conf(path, w, extra=""):
    with open(path, "w") as f:
        f.write("; hairfilterd.conf for the reload test\n"
                "listen = unix:%s/s.sock\n"
                "http = tcp:127.0.0.1:0\n"
                "weights-dir = %s/weights\n"
                "backend = cpu-ref\n"
                "queue-size = 256\n"
                "max-inflight = 64\n" % (w, w) + extra)


def served(d):
    """{variant: (file, levels)} from /metrics."""
    s, _ = d.metrics()
    out = {}
    for (name, labels), v in s.items():
        if name == "hairfilterd_variant_info":
            lab = dict(labels)
            out[lab["variant"]] = (os.path.basename(lab["file"]), lab["levels"])
    return out, s


def reload_and_wait(d, before):
    """SIGHUP, then waits until a reload more than before has finished."""
    d.signal(signal.SIGHUP)
    t_end = time.time() + 30
    while time.time() < t_end:
        _, s = served(d)
        n = sum(v for (name, _), v in s.items() if name == "hairfilterd_reloads_total")
        if n > before:
            return n
        time.sleep(0.02)
    raise RuntimeError("reload did not finish")


def main():
    w = workdir()
    os.mkdir(os.path.join(w, "weights"))
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), os.path.join(w, "weights"))
    conf = os.path.join(w, "hairfilterd.conf")
    write_conf(conf, w)
    d = Daemon(HAIRFILTERD, ["--config", conf], w)
    answered = {}
    run_then_stop(d, w, lambda: answered.update(run(d, w, conf)),
                  lambda d: check_stop_line(d, answered))


def not_after(pem):
    """notAfter of a PEM certificate as a Unix time, read by openssl(1)."""
    out = subprocess.run(["openssl", "x509", "-enddate", "-noout", "-in", pem], check=True,
                         capture_output=True, text=True).stdout
    return ssl.cert_time_to_seconds(out.strip().split("=", 1)[1])


def tls_reload():
    """A certificate renewal that does not load: the old certificate keeps
    serving, and the reload is counted and logged as failed (it was "reload
    done ... failed=0" and result="ok", so an alert on failed reloads
    missed a certificate left to expire)."""
    w = workdir()
    os.mkdir(os.path.join(w, "weights"))
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), os.path.join(w, "weights"))
    certs = os.path.join(w, "certs")
    os.mkdir(certs)
    subprocess.run([MAKE_TEST_CERTS, certs], check=True)
    conf = os.path.join(w, "hairfilterd.conf")
    write_conf(conf, w, "listen = tls:127.0.0.1:0\ntls-cert = %s/server.pem\n"
                        "tls-key = %s/server.key\n" % (certs, certs))
    d = Daemon(HAIRFILTERD, ["--config", conf], w, env={"HAIRFILTERD_TOKEN": "t0ken"})

    def body():
        expiry = "hairfilterd_tls_certificate_expiry_timestamp_seconds"
        s, _ = d.metrics()
        check(sample(s, expiry) == not_after(os.path.join(certs, "server.pem")) and
              sample(s, expiry) > time.time(),
              "%s is server.pem's notAfter (%s): %s" %
              (expiry, not_after(os.path.join(certs, "server.pem")), sample(s, expiry)))
        served_pem = not_after(os.path.join(certs, "server.pem"))
        # The renewal writes a certificate that is not the key's.
        shutil.copy(os.path.join(certs, "client.pem"), os.path.join(certs, "new.pem"))
        os.replace(os.path.join(certs, "new.pem"), os.path.join(certs, "server.pem"))
        reload_and_wait(d, 0)
        s, _ = d.metrics()
        check(sample(s, "hairfilterd_reloads_total", result="failed") == 1 and
              sample(s, "hairfilterd_reloads_total", result="ok") == 0,
              "a TLS file that does not load: a failed reload in /metrics: %s" %
              {k: v for k, v in s.items() if k[0] == "hairfilterd_reloads_total"})
        check(sample(s, expiry) == served_pem,
              "after a failed reload %s is still the served certificate's: %s" %
              (expiry, sample(s, expiry)))
        log = d.log_text()
        check("reload: TLS: --tls-key" in log and "reload done with 1 failure(s):" in log and
              "tls=failed" in log,
              "a TLS file that does not load: the reload line says it failed: %s" %
              [l for l in log.splitlines() if "reload" in l])
        # Renewed properly: an ok reload.
        shutil.copy(os.path.join(certs, "expired.pem"), os.path.join(certs, "new.pem"))
        shutil.copy(os.path.join(certs, "expired.key"), os.path.join(certs, "new.key"))
        os.replace(os.path.join(certs, "new.key"), os.path.join(certs, "server.key"))
        os.replace(os.path.join(certs, "new.pem"), os.path.join(certs, "server.pem"))
        reload_and_wait(d, 1)
        s, _ = d.metrics()
        check(sample(s, "hairfilterd_reloads_total", result="ok") == 1,
              "TLS files that load: an ok reload: %s" %
              {k: v for k, v in s.items() if k[0] == "hairfilterd_reloads_total"})
        expired = not_after(os.path.join(certs, "server.pem"))
        check(sample(s, expiry) == expired and expired < time.time(),
              "after the renewal %s is the new (expired) certificate's %s: %s" %
              (expiry, expired, sample(s, expiry)))

    run_then_stop(d, w, body)


def check_stop_line(d, answered):
    """The stop line counts every RESULT written, those of a variant a
    reload removed (whose STATS counters went with it) included."""
    want = "stopped: %d request(s) served, 0 failed, 0 pushed out" % answered.get("ok", -1)
    check(want in d.log_text(), "the stop line says '%s': %s" % (
        want, [l for l in d.log_text().splitlines() if "stopped:" in l]))


def run(d, w, conf):
    wd = os.path.join(w, "weights")
    unix = d.urls["unix"]
    v, _ = served(d)
    check(v == {"Small": ("small.safetensors", "16,32,64")}, "at start: %s" % v)
    stop = os.path.join(w, "stop-load")
    # Two connections keep requests for Small in flight all through.
    load = run_load(LOAD_CLIENT, unix, "Small", 4, "16x16", connections=2, inflight=4,
                    until_file=stop)
    time.sleep(0.3)
    reloads = 0

    # 1. Added: a retrained Small (same metadata name) served beside it
    # under another name given in the config file.
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), os.path.join(w, "retrained.safetensors"))
    write_conf(conf, w, "weights = Small-retrained=%s/retrained.safetensors\n" % w)
    reloads = reload_and_wait(d, reloads)
    v, s = served(d)
    check(set(v) == {"Small", "Small-retrained"}, "added Small-retrained: %s" % v)
    retrained = run_load(LOAD_CLIENT, unix, "Small-retrained", 4, "16x16", count=10)
    r = load_result(retrained)
    check(r["status"] == {"OK": 10}, "Small-retrained serves: %s" % r)

    # 2. Replaced: small.safetensors becomes another network that is also
    # named Small (Shallow's weights, levels 32,64), renamed into place.
    set_weights_name(os.path.join(WEIGHTS, "shallow.safetensors"),
                     os.path.join(wd, "small.safetensors"), "Small")
    reloads = reload_and_wait(d, reloads)
    v, s = served(d)
    check(v.get("Small") == ("small.safetensors", "32,64"), "Small replaced: %s" % v)

    # 3. A failed replacement: the old version keeps serving, readiness stays.
    with open(os.path.join(wd, "small.safetensors.tmp"), "wb") as f:
        f.write(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json at all}")
    os.replace(os.path.join(wd, "small.safetensors.tmp"), os.path.join(wd, "small.safetensors"))
    reloads = reload_and_wait(d, reloads)
    v, s = served(d)
    check(v.get("Small") == ("small.safetensors", "32,64"), "failed replacement keeps Small: %s" % v)
    check(sample(s, "hairfilterd_reloads_total", result="failed") == 1, "failed reload counted")
    check(sample(s, "hairfilterd_model_loads_total", result="failed") == 1, "failed load counted")
    check(d.get("/readyz")[0] == 200, "still ready: the old version serves")
    check("keeps serving the version loaded before" in d.log_text(), "failure logged")

    # 4. A new file that fails: not ready, naming it; the rest serve.
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), os.path.join(wd, "small.safetensors"))
    with open(os.path.join(wd, "broken.safetensors"), "wb") as f:
        f.write(b"\x00" * 7)
    reloads = reload_and_wait(d, reloads)
    st, body = d.get("/readyz")
    check(st == 503 and "broken.safetensors" in body, "/readyz names the broken file: %s %s" % (st, body))
    v, s = served(d)
    check(v.get("Small") == ("small.safetensors", "16,32,64"), "Small back to its own weights: %s" % v)
    check(sample(s, "hairfilterd_weights_files_unserved") == 1, "one file unserved")
    lines = [l for l in d.log_text().splitlines() if "broken.safetensors" in l and "not served" in l]
    check(lines and all(l.count("broken.safetensors") == 2 for l in lines),
          "the failure names the file once (and in file=): %s" % lines)
    os.unlink(os.path.join(wd, "broken.safetensors"))
    reloads = reload_and_wait(d, reloads)
    check(d.get("/readyz") == (200, "ready\n"), "ready again once the broken file is gone")

    # 4b. A new file of a name already served: refused, and the fix named is
    # one a reload can take (the config file; --weights waits for a restart).
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), os.path.join(wd, "dup.safetensors"))
    reloads = reload_and_wait(d, reloads)
    lines = [l for l in d.log_text().splitlines() if "dup.safetensors" in l
             and "a variant named 'Small' is already served" in l]
    check(lines and "name one of them in the --config file (weights = NAME=FILE) and reload "
          "again" in lines[0], "the duplicate name says how to serve both: %s" % lines)
    os.unlink(os.path.join(wd, "dup.safetensors"))
    reloads = reload_and_wait(d, reloads)
    check(d.get("/readyz") == (200, "ready\n"), "ready again once the duplicate is gone")

    # 5. Removed: Small-retrained leaves the config.
    write_conf(conf, w)
    reloads = reload_and_wait(d, reloads)
    v, s = served(d)
    check(set(v) == {"Small"}, "Small-retrained removed: %s" % v)

    # 6. A config file error: the reason is a log line of level error (so
    # journalctl -p warning shows it), and nothing changes.
    with open(conf, "a") as f:
        f.write("queue = 5\n")
    reloads = reload_and_wait(d, reloads)
    lines = [l for l in d.log_text().splitlines() if "unknown key 'queue'" in l]
    check(len(lines) == 1 and "error: %s:" % conf in lines[0],
          "the config error is logged at error level, naming file and line: %s" % lines)
    check(set(served(d)[0]) == {"Small"}, "a config error changes nothing")

    # 7. Keys that need a restart: each changed one is named with its old
    # and new values; unchanged ones are not mentioned.
    write_conf(conf, w)
    with open(conf) as f:
        text = f.read().replace("queue-size = 256", "queue-size = 128")
    with open(conf, "w") as f:
        f.write(text + "max-connections = 100\nqueue-share-by = connection\n"
                "max-handshakes-per-address = 4\nipv6-client-prefix = 56\n")
    reloads = reload_and_wait(d, reloads)
    log = d.log_text()
    check("warning: reload: --queue-size changed from 256 to 128; it takes effect at the next "
          "start" in log, "the reload names --queue-size with both values")
    check("--max-connections changed from 256 to 100" in log,
          "the reload names --max-connections with both values")
    check("--queue-share-by changed from client to connection" in log,
          "the reload names --queue-share-by with both values")
    check("--max-handshakes-per-address changed from (default) to 4" in log,
          "the reload names --max-handshakes-per-address with both values")
    check("--ipv6-client-prefix changed from 64 to 56" in log,
          "the reload names --ipv6-client-prefix with both values")
    check("--max-inflight changed" not in log and "--backend changed" not in log,
          "unchanged keys are not named")
    write_conf(conf, w)
    reloads = reload_and_wait(d, reloads)

    # SIGUSR1: statistics in the log, nothing else.
    d.signal(signal.SIGUSR1)
    time.sleep(0.3)
    check("statistics:" in d.log_text() and d.proc.poll() is None, "SIGUSR1 logs statistics")

    open(stop, "w").close()
    r = load_result(load)
    print("load through the reloads:", r)
    check(r["connection_errors"] == 0 and r["sent"] == r["answered"] and
          r["status"] == {"OK": r["sent"]}, "no request lost or refused: %s" % r)
    check(r["sent"] > 50, "the load ran: %s" % r)
    ok = ("hairfilterd_requests_total", dict(variant="Small", status="ok", **{"class": "ok"}))
    s, _ = d.settled_metrics([ok + (r["sent"],)])
    check(sample(s, ok[0], **ok[1]) == r["sent"], "Small's counter went on through the replacements")
    return {"ok": r["sent"] + 10}


main()
tls_reload()
finish()
