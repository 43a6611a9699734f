#!/usr/bin/env python3
"""What hairfilterd says when it cannot start, as journald sees it: every
reason is a log line with its level (a "<N>" priority prefix when stderr is
the journal, so `journalctl -p warning` shows it), and the checks that need
no weights are made before any is loaded.

  * a config file line with an unknown key: exit 2, priority 3, file:line;
  * a section header, the file's last line included: exit 2, its line;
  * an indented line (inih's continuation of the key above): exit 2, its
    line, said as such;
  * a config or token file that is a directory: exit 2, said as such;
  * a --ready-file that is a directory or in a missing directory: exit 1
    at start, before the backend starts;
  * a value the option refuses: exit 2, the file and line named;
  * a key of one value given twice in the file: a warning naming both
    lines, the later one winning;
  * tcp: on a non-loopback address without a token: exit 2 at once, before
    the backend starts or a weights file is read;
  * nothing to listen on: the message names the tls: form too;
  * a TLS key the daemon's user cannot read: exit 1 before the weights
    load, naming the file, the uid and the fix (install -o ... -m 0600);
  * a --backend that names no backend: exit 2 before anything starts;
  * a port in use, for --listen and for --http: exit 1, the port said to
    be in use and how to find who holds it (--http said "Failed to bind to
    port 0" and guessed);
  * a running daemon's ready file given to a second daemon: status 1
    before anything loads, and the file left alone;
  * a ready file left by a daemon killed before it could remove it: gone
    as the next one starts, so it never says "serving" for a daemon that
    is still loading, or that failed to start;
  * a weights file that does not load: named as a weights file, with
    what to do (it was the path and the reason alone); one the daemon's
    user cannot read: that user, the file's owner and mode, and chmod;
  * a --warm shape over the size --max-size is lowered to: a warning;
  * a config or token file the daemon's user cannot read: that user, the
    file's owner and mode, and the fix;
  * a DER certificate, or the certificate and key swapped: said as such.

usage: test_start_errors.py HAIRFILTERD MAKE_TEST_CERTS WEIGHTS_DIR
"""
import base64
import os
import shutil
import socket
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from opsdaemon import Daemon, check, cleanup, finish, workdir  # noqa: E402

HAIRFILTERD, MAKE_TEST_CERTS, WEIGHTS = sys.argv[1:4]


def run(args, w, env=None, journal=True, user=None):
    """Runs hairfilterd until it exits: (status, its stderr). With journal,
    $JOURNAL_STREAM names the file stderr goes to, as systemd sets it for
    a stream to journald."""
    log = os.path.join(w, "stderr.log")
    e = {k: v for k, v in os.environ.items() if k not in ("HAIRFILTERD_TOKEN", "JOURNAL_STREAM")}
    e.update(env or {})
    with open(log, "w") as f:
        if journal:
            st = os.fstat(f.fileno())
            e["JOURNAL_STREAM"] = "%d:%d" % (st.st_dev, st.st_ino)
        pre = None
        if user is not None:
            def pre():
                os.setgroups([])
                os.setgid(user)
                os.setuid(user)
        rc = subprocess.run([HAIRFILTERD] + args, stdout=f, stderr=subprocess.STDOUT, env=e,
                            timeout=60, preexec_fn=pre).returncode
    return rc, open(log).read()


def main():
    w = workdir()
    try:
        body(w)
    finally:
        cleanup(w)
    finish()


def body(w):
    wd = os.path.join(w, "weights")
    os.mkdir(wd)
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), wd)
    conf = os.path.join(w, "hairfilterd.conf")
    base = ("listen = unix:%s/s.sock\n"
            "weights-dir = %s\n"
            "backend = auto\n" % (w, wd))

    # An unknown key: the reason at priority 3, naming the file and line.
    with open(conf, "w") as f:
        f.write(base + "queue = 5\n")
    rc, out = run(["--config", conf], w)
    check(rc == 2, "unknown key: exit status %s, not 2" % rc)
    check("<3>error: %s:4: unknown key 'queue'" % conf in out.splitlines()[0] if out else False,
          "unknown key: the reason is a priority 3 line naming %s:4: %r" % (conf, out))
    check(all(l.startswith("<") for l in out.splitlines()),
          "every line has a priority prefix: %r" % out)

    # A value the option refuses is said with the file and line it came
    # from, as an unknown key is; the same option on the command line not.
    with open(conf, "w") as f:
        f.write(base + "queue-size = abc\n")
    rc, out = run(["--config", conf], w)
    check(rc == 2 and "<3>error: %s:4: --queue-size wants an integer" % conf in out,
          "a bad value in the file: exit status %s (want 2), naming %s:4: %r" % (rc, conf, out))
    with open(conf, "w") as f:
        f.write(base)
    rc, out = run(["--config", conf, "--queue-size", "xyz"], w)
    check(rc == 2 and "<3>error: --queue-size wants an integer in 1..65536, not 'xyz'" in out,
          "a bad value on the command line: status %s, no file named: %r" % (rc, out))

    # A config or token file that is a directory (the folder given for the
    # file in it): said as such, not read as an empty file.
    rc, out = run(["--config", w], w)
    check(rc == 2 and "<3>error: cannot read config file %s: it is a directory; give the file "
          "in it" % w in out,
          "--config DIR: exit status %s (want 2), said to be a directory: %r" % (rc, out))
    rc, out = run(["--config", "none", "--listen", "tcp:127.0.0.1:0", "--auth-token-file", w,
                   "--weights-dir", wd], w)
    check(rc == 2 and "<3>error: --auth-token-file %s: it is a directory; give the file in it"
          % w in out,
          "--auth-token-file DIR: exit status %s (want 2), said to be a directory: %r" % (rc, out))

    # A section is an error, also as the file's last line (inih passes
    # only key lines on, so nothing used to see it there): exit 2, its line.
    # (No weights file there: a daemon that let the section by stops at once.)
    short = "listen = unix:%s/s.sock\nweights = %s/none.safetensors\n" % (w, w)
    for text, line in ((short + "[server]\n", 3), (short + "[server]\nqueue-size = 8\n", 3)):
        with open(conf, "w") as f:
            f.write(text)
        rc, out = run(["--config", conf], w)
        check(rc == 2 and "<3>error: %s:%d: no sections ([server])" % (conf, line) in out,
              "a section on line %d: exit status %s (want 2), naming the line: %r" % (line, rc, out))

    # An indented line: inih would take it for more of the key above
    # ('weights = ...' as a second listen URL); refused, saying so, while
    # an indented comment and an empty line pass.
    with open(conf, "w") as f:
        f.write(short + "  ; a comment\n\n  queue-size = 8\n")
    rc, out = run(["--config", conf], w)
    check(rc == 2 and "<3>error: %s:5: the line starts with whitespace, which continues the key "
          "above it (inih's rule): indent nothing" % conf in out,
          "an indented line: exit status %s (want 2), said so: %r" % (rc, out))

    # Lines longer than libinih's buffer (199 bytes): a comment of any
    # length passes and the lines after it keep their numbers; a long key
    # line, or one holding a NUL byte, is refused naming its own line (it
    # was read as two lines, the error naming the wrong one).
    with open(conf, "w") as f:
        f.write("# " + "A" * 300 + "\n" + short + "queue-size = 0\n")
    rc, out = run(["--config", conf], w)
    check(rc == 2 and "<3>error: %s:4: " % conf in out and "queue" in out,
          "a 302-byte comment, then a bad value on line 4: exit status %s (want 2), line 4 "
          "named: %r" % (rc, out))
    with open(conf, "w") as f:
        long_line = "weights = %s/%s.safetensors\n" % (w, "x" * 250)
        f.write(short + long_line)
    rc, out = run(["--config", conf], w)
    check(rc == 2 and "<3>error: %s:3: the line is %d bytes with its line end, more than "
          "the 199" % (conf, len(long_line)) in out and
          "give this option on the command line" in out,
          "a long key line: exit status %s (want 2), its line named: %r" % (rc, out))
    with open(conf, "wb") as f:
        f.write(short.encode() + b"queue-size = 3\0junk\n")
    rc, out = run(["--config", conf], w)
    check(rc == 2 and "<3>error: %s:3: the line holds a NUL byte" % conf in out,
          "a NUL byte: exit status %s (want 2), said so: %r" % (rc, out))

    # The same listen address twice (also spelled another way) is said as
    # such, not as another server.
    for second in ("%s/d.sock" % w, "%s/../%s/d.sock" % (w, os.path.basename(w))):
        rc, out = run(["--config", "none", "--listen", "unix:%s/d.sock" % w, "--listen",
                       "unix:" + second, "--weights", "%s/none.safetensors" % w], w)
        check(rc == 2 and "is given twice" in out,
              "--listen twice (%s): exit status %s (want 2), said so: %r" % (second, rc, out))
    # A number with whitespace before it is refused, as one with whitespace after.
    for v in (" 5", "5 "):
        rc, out = run(["--config", "none", "--queue-size", v, "--listen", "unix:%s/d.sock" % w,
                       "--weights", "%s/none.safetensors" % w], w)
        check(rc == 2 and "--queue-size wants an integer in 1..65536, not '%s'" % v in out,
              "--queue-size %r: exit status %s (want 2): %r" % (v, rc, out))

    # A repeated key warns naming both lines; the TCP listener without a
    # token is refused before the backend starts (no "starting" line, no
    # backend named). Then a flag: no-auth = no on a later line undoes
    # no-auth = yes (the later line wins), so the token is missing.
    with open(conf, "w") as f:
        f.write(base + "listen = tcp:0.0.0.0:0\nbackend = cpu-ref\n")
    rc, out = run(["--config", conf], w)
    check("<4>warning: %s:5: 'backend' was given already on line 3" % conf in out,
          "repeated key: a warning naming both lines: %r" % out)
    check(rc == 2 and "<3>error: --listen tcp:0.0.0.0:0: TCP needs a token" in out,
          "tcp: without a token: exit status %s (want 2): %r" % (rc, out))
    check("starting" not in out and "cpu-ref" not in out,
          "tcp: without a token is refused before anything starts: %r" % out)
    with open(conf, "w") as f:
        f.write(base + "no-auth = yes\nno-auth = no\nlisten = tcp:127.0.0.1:0\n")
    rc, out = run(["--config", conf], w)
    check(rc == 2 and "'no-auth' was given already on line 4" in out and
          "TCP needs a token" in out,
          "no-auth = no on a later line wins over yes: status %s: %r" % (rc, out))

    # --log-level error (here on the command line, read after the file)
    # silences the repeated-key warning, as it does every warning.
    with open(conf, "w") as f:
        f.write(base + "backend = cpu-ref\nlisten = tcp:0.0.0.0:0\n")
    rc, out = run(["--config", conf, "--log-level", "error"], w)
    check(rc == 2 and "given already" not in out and "TCP needs a token" in out,
          "--log-level error: no repeated-key warning, the error still said: %r" % out)

    # --warm with a tail after its numbers is refused (it was dropped:
    # 8x8y warmed 8x8), as every other option's value is, before anything
    # loads (no weights file there: a daemon that let it by stops at once).
    for bad in ("8x8y", "8x8x", "8x8x2x"):
        rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights",
                       os.path.join(w, "none.safetensors"), "--warm", bad], w)
        check(rc == 2 and "--warm wants WxH or WxHxBATCH" in out and "'%s'" % bad in out,
              "--warm %s: exit status %s (want 2): %r" % (bad, rc, out))

    # Nothing to listen on: every URL form named.
    rc, out = run(["--config", "none", "--weights-dir", wd], w)
    check(rc == 2 and "unix:PATH, tcp:HOST:PORT or tls:HOST:PORT" in out,
          "nothing to listen on: status %s: %r" % (rc, out))

    # A TLS key the daemon's user cannot read: root reads every file, so
    # the daemon runs as nobody then; otherwise the key loses its mode.
    certs = os.path.join(w, "certs")
    os.mkdir(certs)
    subprocess.run([MAKE_TEST_CERTS, certs], check=True)
    os.chmod(certs, 0o755)
    os.chmod(os.path.join(certs, "server.pem"), 0o644)
    key = os.path.join(certs, "server.key")
    user = None
    if os.geteuid() == 0:
        user = 65534
        os.chmod(key, 0o600)
    else:
        os.chmod(key, 0)
    rc, out = run(["--config", "none", "--listen", "tls:127.0.0.1:0", "--tls-cert",
                   os.path.join(certs, "server.pem"), "--tls-key", key, "--weights-dir", wd,
                   "--backend", "cpu-ref"], w, env={"HAIRFILTERD_TOKEN": "t0ken"}, user=user)
    uid = user if user is not None else os.geteuid()
    lines = [l for l in out.splitlines() if "--tls-key %s" % key in l]
    check(rc == 1 and len(lines) == 1 and lines[0].startswith("<3>error: "),
          "unreadable key: status %s (want 1), one error line: %r" % (rc, out))
    check(lines and "runs as uid %d" % uid in lines[0] and "-m 0600" in lines[0] and
          "install -o" in lines[0] and "error:8000000D" not in lines[0],
          "unreadable key: the uid and the fix named: %r" % lines)
    check("cpu-ref" not in out, "unreadable key: refused before the backend starts: %r" % out)

    # A certificate in DER, and the certificate and key given in each
    # other's place: said as such (OpenSSL said "no start line" or
    # "DECODER routines::unsupported"), status 1 before the backend starts.
    os.chmod(key, 0o644)
    pem = open(os.path.join(certs, "server.pem")).read()
    body = pem.split("-----BEGIN CERTIFICATE-----")[1].split("-----END CERTIFICATE-----")[0]
    der = os.path.join(certs, "server.der")
    with open(der, "wb") as f:
        f.write(base64.b64decode("".join(body.split())))
    for cert_file, key_file, said in (
            (der, key, "--tls-cert %s holds no PEM certificate (no -----BEGIN line; a DER "
                       "certificate converts with openssl x509 -inform DER" % der),
            (key, key, "--tls-cert %s holds no certificate (no -----BEGIN CERTIFICATE----- "
                       "block" % key),
            (os.path.join(certs, "server.pem"), os.path.join(certs, "server.pem"),
             "--tls-key %s holds no private key" % os.path.join(certs, "server.pem")),
            # A directory (a Secret's mount point): not said to hold DER.
            (certs, key, "--tls-cert %s is a directory: give the PEM file in it" % certs)):
        rc, out = run(["--config", "none", "--listen", "tls:127.0.0.1:0", "--tls-cert", cert_file,
                       "--tls-key", key_file, "--weights-dir", wd, "--backend", "cpu-ref"], w,
                      env={"HAIRFILTERD_TOKEN": "t0ken"})
        check(rc == 1 and "<3>error: TLS: " + said in out and "cpu-ref" not in out,
              "TLS files of the wrong kind: status %s (want 1), said what they hold: %r"
              % (rc, out))

    # A backend name that is none of the four is a bad option, refused
    # before anything starts (it was found by the backend: status 1).
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights-dir", wd,
                   "--backend", "gpu"], w)
    check(rc == 2 and "<3>error: --backend wants auto, cudnn, cpu or cpu-ref, not 'gpu'" in out
          and "starting" not in out,
          "--backend gpu: exit status %s (want 2), refused before starting: %r" % (rc, out))

    # A port in use: the listener and the HTTP endpoint say so, and how to
    # find who holds it.
    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    port = holder.getsockname()[1]
    try:
        rc, out = run(["--config", "none", "--listen", "tcp:127.0.0.1:%d" % port, "--no-auth",
                       "--weights-dir", wd, "--backend", "cpu-ref"], w)
        check(rc == 1 and "<3>error: --listen tcp:127.0.0.1:%d: port %d is in use" % (port, port)
              in out and "ss -ltnp" in out,
              "--listen on a port in use: status %s (want 1), said so: %r" % (rc, out))
        rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--http",
                       "tcp:127.0.0.1:%d" % port, "--weights-dir", wd, "--backend", "cpu-ref"], w)
        check(rc == 1 and "<3>error: --http tcp:127.0.0.1:%d: port %d is in use" % (port, port)
              in out and "port 0" not in out,
              "--http on a port in use: status %s (want 1), said so: %r" % (rc, out))
        check(not os.path.exists(os.path.join(w, "s.sock")),
              "--http on a port in use: the Unix socket opened before it is removed")
    finally:
        holder.close()

    # A socket path a live server answers on, and a path that is no socket:
    # named as the --listen they came from, with what to do.
    live = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    live.bind(os.path.join(w, "live.sock"))
    live.listen()
    try:
        rc, out = run(["--config", "none", "--listen", "unix:%s/live.sock" % w, "--weights-dir",
                       wd, "--backend", "cpu-ref"], w)
        check(rc == 1 and "<3>error: --listen unix:%s/live.sock: another server is listening "
              "there" % w in out and "stop it, or give each daemon its own socket path" in out,
              "a socket a live server answers on: status %s (want 1), said so: %r" % (rc, out))
    finally:
        live.close()
    with open(os.path.join(w, "plain.sock"), "w") as f:
        f.write("not a socket\n")
    rc, out = run(["--config", "none", "--listen", "unix:%s/plain.sock" % w, "--weights-dir",
                   wd, "--backend", "cpu-ref"], w)
    check(rc == 1 and "<3>error: --listen unix:%s/plain.sock: %s/plain.sock exists and is not a "
          "socket; remove it, or give another path" % (w, w) in out,
          "a socket path that is a file: status %s (want 1), said so: %r" % (rc, out))

    # A weights folder that is not there, or holds no weights file: what
    # to give instead.
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights-dir",
                   os.path.join(w, "nodir"), "--backend", "cpu-ref"], w)
    check(rc == 1 and "<3>error: --weights-dir %s/nodir: No such file or directory; give the "
          "folder that holds the weights files (*.safetensors;" % w in out,
          "a missing --weights-dir: status %s (want 1), said with what to do: %r" % (rc, out))
    os.mkdir(os.path.join(w, "noweights"))
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights-dir",
                   os.path.join(w, "noweights"), "--backend", "cpu-ref"], w)
    check(rc == 1 and "<3>error: no *.safetensors in %s/noweights: copy the weights files there, "
          "or give the folder that holds them" % w in out,
          "an empty --weights-dir: status %s (want 1), said with what to do: %r" % (rc, out))

    # Two files in one --weights, as `hairfilter eval --weights` takes them:
    # the daemon takes one per --weights, and says so.
    pair = "%s,%s" % (os.path.join(WEIGHTS, "small.safetensors"), os.path.join(WEIGHTS, "base.safetensors"))
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights", pair,
                   "--backend", "cpu-ref"], w)
    check(rc == 1 and "one file per --weights: give --weights once for each" in out,
          "--weights A,B: status %s (want 1), said how to give two: %r" % (rc, out))

    # A weights path that is a FIFO: refused as not a regular file, at once
    # (opening it waited for a writer forever, holding the start and any
    # stop); in a --weights-dir a FIFO, a folder or a dangling link named
    # *.safetensors is loaded and refused too, not passed over in silence.
    fifo = os.path.join(w, "fifo.safetensors")
    os.mkfifo(fifo)
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights", fifo,
                   "--backend", "cpu-ref"], w)
    check(rc == 1 and "is a FIFO, not a regular file" in out,
          "--weights FIFO: status %s (want 1, at once), said so: %r" % (rc, out))
    odd = os.path.join(w, "oddweights")
    os.mkdir(odd)
    os.mkfifo(os.path.join(odd, "f.safetensors"))
    for name, make, words in (("f.safetensors", None, "is a FIFO"),
                              ("d.safetensors", os.mkdir, "is a directory"),
                              ("l.safetensors", lambda p: os.symlink("/nonexistent", p),
                               "is a symbolic link to /nonexistent, which does not exist")):
        for other in os.listdir(odd):
            if other != name:
                p = os.path.join(odd, other)
                os.rmdir(p) if os.path.isdir(p) and not os.path.islink(p) else os.unlink(p)
        if make:
            make(os.path.join(odd, name))
        rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights-dir", odd,
                       "--backend", "cpu-ref"], w)
        check(rc == 1 and name in out and words in out,
              "--weights-dir with %s: status %s (want 1), named with %r: %r" %
              (name, rc, words, out))

    # A ready file that cannot be written: said at start, before the
    # backend starts and the models are built (minutes with --warm on a
    # GPU), not once they are.
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights-dir", wd,
                   "--ready-file", w], w)
    check(rc == 1 and "<3>error: --ready-file %s is a directory: give the path of a file" % w
          in out and "backend" not in out,
          "--ready-file DIR: exit status %s (want 1), said before anything loads: %r" % (rc, out))
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights-dir", wd,
                   "--ready-file", os.path.join(w, "nodir", "ready")], w)
    check(rc == 1 and "<3>error: --ready-file %s/nodir/ready: cannot create a file beside it: No "
          "such file or directory; its directory must exist" % w in out and "backend" not in out,
          "--ready-file in a missing directory: exit status %s (want 1), said before anything "
          "loads: %r" % (rc, out))

    # A ready file a killed daemon left is removed as the next starts, here
    # one that then fails (its weights file is missing): nothing says ready.
    ready = os.path.join(w, "ready")
    with open(ready, "w") as f:
        f.write("unix:%s/old.sock\n" % w)
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights",
                   os.path.join(w, "none.safetensors"), "--ready-file", ready], w)
    check(rc == 1 and not os.path.exists(ready),
          "a stale ready file: status %s (want 1), file still there: %s: %r"
          % (rc, os.path.exists(ready), out))
    check("<4>warning: --ready-file %s: removed the one there" % ready in out,
          "a stale ready file: its removal is said: %r" % out)
    # (and the missing weights file is said with what to do about it)
    check("<3>error: weights file %s: No such file or directory; every configured weights "
          "file must load at start: fix it, or take it out of --weights or --weights-dir"
          % os.path.join(w, "none.safetensors") in out,
          "a missing weights file: named, with what to do: %r" % out)

    # A running daemon's ready file given to a second daemon by mistake:
    # the second stops (status 1) before anything loads, and the file
    # stays. It was removed as stale, saying the first daemon was gone
    # while it served, and the second then failed on its own socket.
    live_dir = os.path.join(w, "live")
    os.makedirs(live_dir)
    first = Daemon(HAIRFILTERD, ["--config", "none", "--listen", "unix:%s/a.sock" % live_dir,
                                 "--weights-dir", wd, "--backend", "cpu-ref"], live_dir)
    try:
        before = open(first.ready).read()
        rc, out = run(["--config", "none", "--listen", "unix:%s/b.sock" % live_dir,
                       "--weights-dir", wd, "--ready-file", first.ready], w)
        check(rc == 1 and "<3>error: --ready-file %s: a running daemon wrote it (unix:%s/a.sock "
              "answers); give each daemon its own ready file" % (first.ready, live_dir) in out
              and "backend" not in out,
              "a running daemon's ready file: status %s (want 1), said before anything loads: %r"
              % (rc, out))
        check(os.path.exists(first.ready) and open(first.ready).read() == before,
              "a running daemon's ready file left as it was")
    finally:
        check(first.stop() == 0, "the first daemon stopped with 0")

    # --weights NAME=FILE whose name cannot be one, or with no file after
    # '=': a bad option (status 2) saying which, not the whole value's "No
    # such file" once the backend has started.
    small = os.path.join(WEIGHTS, "small.safetensors")
    for val, want in (("Mi ne=%s" % small, "'Mi ne' before '=' is not a variant name"),
                      ("=%s" % small, "'' before '=' is not a variant name"),
                      ("Small=", "--weights Small=: no file after '='")):
        rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights", val],
                      w)
        check(rc == 2 and want in out, "--weights %r: status %s (want 2), says %r: %r"
              % (val, rc, want, out))
    # With a '/' before the '=' the value is a path (docs/SERVER.md): a
    # missing one is a weights file that does not load, not a bad name.
    val = os.path.join(w, "run=3", "final.safetensors")
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights", val,
                   "--backend", "cpu-ref"], w)
    check(rc == 1 and "<3>error: weights file %s: No such file or directory" % val in out
          and "not a variant name" not in out,
          "--weights %r: status %s (want 1), a missing file: %r" % (val, rc, out))

    # A weights file the daemon's user cannot read (copied in by root with
    # a private mode): who the daemon runs as, the file's owner and mode,
    # and the fix, not "Permission denied" alone.
    private = os.path.join(w, "private")
    os.mkdir(private)
    os.chmod(private, 0o755)
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), private)
    pw = os.path.join(private, "small.safetensors")
    os.chmod(pw, 0o600 if os.geteuid() == 0 else 0)
    user = 65534 if os.geteuid() == 0 else None
    uid = user if user is not None else os.geteuid()
    rc, out = run(["--config", "none", "--listen", "unix:%s/s.sock" % w, "--weights-dir", private,
                   "--backend", "cpu-ref"], w, user=user)
    check(rc == 1 and "<3>error: weights file %s: permission denied: hairfilterd runs as uid %d"
          % (pw, uid) in out and "chmod 0644 %s" % pw in out,
          "an unreadable weights file: status %s (want 1), the uid and the fix: %r" % (rc, out))


    # A --warm shape over the size the memory budget lowers --max-size to:
    # a warning naming it (its plans were built for frames that all get
    # TOO_LARGE). The socket directory is missing, so the daemon stops
    # right after the limits are derived.
    rc, out = run(["--config", "none", "--listen", "unix:%s/no-such-dir/s.sock" % w,
                   "--weights-dir", wd, "--backend", "cpu-ref", "--max-memory-mb", "64",
                   "--warm", "1920x1080,32x32"], w)
    lines = [l for l in out.splitlines() if "--warm" in l]
    check(rc == 1 and len(lines) == 1 and lines[0].startswith("<4>warning: --warm 1920x1080 is "
                                                               "over the largest frame served"),
          "a --warm shape over the lowered max size: one warning naming it: %r" % out)


    # The config file and the token file the daemon's user cannot read
    # (written by root with a private mode): exit 2, that user, the file's
    # owner and mode, and a fix that keeps the token from others; they said
    # "Permission denied" alone, the token file without its option.
    user = 65534 if os.geteuid() == 0 else None
    uid = user if user is not None else os.geteuid()
    secret = os.path.join(private, "token")
    with open(secret, "w") as f:
        f.write("t0ken\n")
    os.chmod(secret, 0o600 if os.geteuid() == 0 else 0)
    rc, out = run(["--config", "none", "--listen", "tcp:127.0.0.1:0", "--auth-token-file", secret,
                   "--weights-dir", wd, "--backend", "cpu-ref"], w, user=user)
    check(rc == 2 and "<3>error: --auth-token-file %s: permission denied: hairfilterd runs as "
          "uid %d" % (secret, uid) in out and "chmod 0640 %s" % secret in out,
          "an unreadable token file: status %s (want 2), the option, uid and fix: %r" % (rc, out))
    pconf = os.path.join(private, "hairfilterd.conf")
    with open(pconf, "w") as f:
        f.write(base)
    os.chmod(pconf, 0o600 if os.geteuid() == 0 else 0)
    rc, out = run(["--config", pconf], w, user=user)
    check(rc == 2 and "<3>error: cannot read config file %s: permission denied: hairfilterd runs "
          "as uid %d" % (pconf, uid) in out and "chmod 0640 %s" % pconf in out,
          "an unreadable config file: status %s (want 2), the uid and fix: %r" % (rc, out))


if __name__ == "__main__":
    main()
