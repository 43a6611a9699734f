#!/bin/bash
# tools/gpu-run/run.sh ends and packs its results although a daemon it
# starts never stops on SIGTERM and the logs outgrow what comes back:
# stand-ins for the carried programs (a hairfilterd that ignores SIGTERM
# and writes 12 MiB of logs that do not compress, everything else
# answering at once) run the whole script with BACKEND=cudnn, which must
# finish well within the limit, say in steps.txt which daemon it had to
# kill, and leave summary.txt and a logs.tgz small enough to come back
# (16 MiB) in OUT. No GPU and no build needed.
#
#   tests/gpu/run_sh_bounded.sh REPO_ROOT
set -u
ROOT=${1:?usage: run_sh_bounded.sh REPO_ROOT}
T=$(mktemp -d)
# Stand-ins that outlived a failing run are ended by their recorded ids.
trap 'for p in $(cat "$T/carry/pids" 2>/dev/null); do kill -KILL "$p" 2>/dev/null; done; rm -rf "$T"' EXIT
mkdir -p "$T/carry/bin" "$T/carry/lib" "$T/out"
for p in test_cudnn_backend test_cudnn_graph test_cudnn_kernels hairfilter hairfilter-load; do
  printf '#!/bin/sh\nexit 0\n' > "$T/carry/bin/$p"
done
# Ready at once (the file named after --ready-file), then deaf to SIGTERM.
cat > "$T/carry/bin/hairfilterd" <<'EOF'
#!/bin/bash
trap '' TERM
echo $$ >> "$(dirname "$0")/../pids"
# Logs that do not compress: cuDNN's and its own, 6 MiB each.
head -c 4718592 /dev/urandom | base64 > "${CUDNN_LOGDEST_DBG:-/dev/null}"
head -c 4718592 /dev/urandom | base64
while [ $# -gt 0 ]; do
  [ "$1" = --ready-file ] && echo ready > "$2"
  shift
done
while :; do sleep 0.2; done
EOF
chmod +x "$T"/carry/bin/*
echo "stand-in carry" > "$T/carry/MANIFEST"

# DEADLINE leaves room for every daemon (each waits for left > 60..120 s);
# the run itself takes seconds once stop() is bounded.
start=$(date +%s)
CARRY=$T/carry OUT=$T/out BACKEND=cudnn BIG=64x64 SECS=1 DEADLINE=200 STOP_GRACE=1 \
  timeout -k 5 150 bash "$ROOT/tools/gpu-run/run.sh" > "$T/run.log" 2>&1
rc=$?
took=$(($(date +%s) - start))
fail() {
  echo "FAIL: $*"
  tail -40 "$T/run.log"
  exit 1
}
[ "$rc" = 124 ] || [ "$rc" = 137 ] && fail "run.sh still running after 150 s (a daemon's stop waited without bound)"
[ -s "$T/out/summary.txt" ] || fail "no summary.txt in OUT (rc $rc)"
[ -s "$T/out/logs.tgz" ] || fail "no logs.tgz in OUT (rc $rc)"
# Five daemons' 60 MiB of logs, cut so that logs.tgz comes back (the
# device tool brings back no file over 16 MiB).
size=$(stat -c %s "$T/out/logs.tgz")
[ "$size" -le $((16 << 20)) ] || fail "logs.tgz is $size bytes, over the 16 MiB that come back"
grep -q "cut to its last MiB" "$T/out/summary.txt" || fail "summary.txt does not say the logs were cut"
mkdir "$T/logs"
tar xzf "$T/out/logs.tgz" -C "$T/logs" || fail "logs.tgz does not unpack"
for tag in e2e kac staged hostcheck depth1; do
  grep -q "server_$tag .*did not stop in 1 s after SIGTERM: killed" "$T/logs/steps.txt" ||
    fail "steps.txt does not say server $tag was killed"
done
grep -q "rc=" "$T/logs/steps.txt" || fail "steps.txt has no step"
# Nothing the run started outlives it.
for p in $(cat "$T/carry/pids"); do
  kill -0 "$p" 2>/dev/null && fail "a stand-in hairfilterd (pid $p) outlived run.sh"
done
echo "PASS: run.sh ended in ${took} s with every unstoppable daemon killed and OUT packed"
