#!/usr/bin/python3
"""The config files deploy/ ships start hairfilterd as they are written:
deploy/systemd/hairfilterd.conf, deploy/container/hairfilterd.conf and the
hairfilterd-config ConfigMap of deploy/kubernetes/hairfilterd.yaml. Only
the host's paths are moved under a work directory (the socket directory,
the weights directory with Small in it, the token, the TLS files of the
Kubernetes Secret, made by make_test_certs and given its 0440 mode) and the
fixed ports become 0. Each must serve on every listener and the HTTP
endpoint it names (its ready file lists them), answer /readyz, and the
Kubernetes one must complete a TLS handshake with a client trusting the CA,
and not warn of plain TCP on a network address (it did when it listened on
tcp:0.0.0.0:7070).

usage: shipped_configs.py HAIRFILTERD WEIGHTS_DIR MAKE_TEST_CERTS DEPLOY_DIR
"""
import os
import shutil
import socket
import ssl
import subprocess
import sys
import urllib.request

import yaml

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "server"))
from opsdaemon import Daemon, check, finish, workdir, cleanup  # noqa: E402

HAIRFILTERD, WEIGHTS, MAKE_TEST_CERTS, DEPLOY = sys.argv[1:5]
PLAIN_TCP_WARNING = "unencrypted"


def configmap_conf():
    """hairfilterd.conf of the hairfilterd-config ConfigMap."""
    with open(os.path.join(DEPLOY, "kubernetes", "hairfilterd.yaml")) as f:
        for doc in yaml.safe_load_all(f):
            if doc and doc.get("kind") == "ConfigMap" and \
                    doc["metadata"]["name"] == "hairfilterd-config":
                return doc["data"]["hairfilterd.conf"]
    raise SystemExit("FAIL: no hairfilterd-config ConfigMap in hairfilterd.yaml")


def moved(text, w):
    """text with the host's paths under w and the fixed ports 0."""
    for host, here in (("/run/hairfilterd", os.path.join(w, "run")),
                       ("/usr/local/share/hairfilter/weights", os.path.join(w, "weights")),
                       ("/etc/hairfilter/token/token", os.path.join(w, "token")),
                       ("/etc/hairfilter/tls", os.path.join(w, "tls")),
                       (":7070", ":0"), (":9090", ":0")):
        text = text.replace(host, here)
    return text


def start(name, text):
    w = workdir()
    os.mkdir(os.path.join(w, "run"))
    os.mkdir(os.path.join(w, "weights"))
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), os.path.join(w, "weights"))
    with open(os.path.join(w, "token"), "w") as f:
        f.write("t0ken-of-the-test\n")
    os.chmod(os.path.join(w, "token"), 0o440)
    certs = os.path.join(w, "certs")
    os.mkdir(certs)
    subprocess.run([MAKE_TEST_CERTS, certs], check=True, stdout=subprocess.DEVNULL)
    # A kubernetes.io/tls Secret's two files, as the pod sees them (0440).
    os.mkdir(os.path.join(w, "tls"))
    for src, dst in (("server.pem", "tls.crt"), ("server.key", "tls.key")):
        shutil.copy(os.path.join(certs, src), os.path.join(w, "tls", dst))
        os.chmod(os.path.join(w, "tls", dst), 0o440)
    conf = os.path.join(w, "hairfilterd.conf")
    with open(conf, "w") as f:
        f.write(moved(text, w))
    try:
        # The container's token comes from the environment (its Dockerfile).
        d = Daemon(HAIRFILTERD, ["--config", conf], w,
                   env={"HAIRFILTERD_TOKEN": "t0ken-of-the-test"})
    except RuntimeError as e:
        check(False, "%s: does not start: %s" % (name, e))
        cleanup(w)
        return None, None, None
    return d, w, certs


def tls_handshake(url, ca):
    host, port = url.split(":", 1)[1].rsplit(":", 1)
    ctx = ssl.create_default_context(cafile=ca)
    with socket.create_connection(("127.0.0.1" if host == "0.0.0.0" else host, int(port)),
                                  timeout=10) as raw:
        with ctx.wrap_socket(raw, server_hostname="localhost") as s:
            return s.version()


def run(name, text, kinds, tls):
    d, w, certs = start(name, text)
    if not d:
        return
    try:
        got = sorted(d.urls)
        check(got == sorted(kinds), "%s: listens on %s, want %s (ready file)" % (name, got, kinds))
        if "http" in d.urls:
            url = d.urls["http"].replace("0.0.0.0", "127.0.0.1")
            with urllib.request.urlopen(url + "/readyz", timeout=10) as r:
                check(r.status == 200, "%s: /readyz %s" % (name, r.status))
        if tls and "tls" in d.urls:
            version = tls_handshake(d.urls["tls"], os.path.join(certs, "ca.pem"))
            check(version in ("TLSv1.2", "TLSv1.3"), "%s: TLS handshake: %s" % (name, version))
            check(PLAIN_TCP_WARNING not in d.log_text(),
                  "%s: warns of plain TCP: %s" % (name, d.log_text()))
    finally:
        rc = d.stop()
        check(rc == 0, "%s: daemon exited %s" % (name, rc))
        log = d.log_text()
        errors = [l for l in log.splitlines() if "error:" in l]
        check(not errors, "%s: errors in the log: %s\n%s" % (name, errors, log))
        cleanup(w)


def main():
    with open(os.path.join(DEPLOY, "systemd", "hairfilterd.conf")) as f:
        run("systemd", f.read(), ["http", "unix"], tls=False)
    with open(os.path.join(DEPLOY, "container", "hairfilterd.conf")) as f:
        run("container", f.read(), ["http", "tcp", "unix"], tls=False)
    run("kubernetes", configmap_conf(), ["http", "tls", "unix"], tls=True)


main()
finish()
