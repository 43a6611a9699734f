# Sourced by the bench scripts that start a hairfilterd of their own:
# a work directory removed at exit, with the daemon ($pid, when set) stopped
# first, and a wait for the daemon's ready file.

work=$(mktemp -d)
pid=
bench_cleanup() {
  [ -n "$pid" ] && kill -TERM "$pid" 2> /dev/null && wait "$pid" 2> /dev/null
  rm -rf "$work"
}
trap bench_cleanup EXIT

# bench_wait_ready READY_FILE LOG [TENTHS]: waits up to TENTHS/10 s (default
# 120 s) for the ready file to be written; prints the log and fails if not.
bench_wait_ready() {
  for _ in $(seq "${3:-1200}"); do [ -s "$1" ] && return 0; sleep 0.1; done
  cat "$2" >&2
  return 1
}
