# shellcheck shell=bash
# Sourced by scripts/test.sh and scripts/build.sh: one job at a time beside the caller's own work,
# in its own process group (stop_background ends it with everything it started), its output kept
# in a file until the caller waits for it.
background=""      # the job's process id (and group), or empty
background_log=""  # where its output goes

start_background() {  # log, command...
  background_log=$1
  shift
  setsid "$@" >"$background_log" 2>&1 &
  background=$!
}

# Waits for the job; prints its output, and stops the caller if it failed.
finish_background() {  # label
  local rc=0
  wait "$background" || rc=$?
  background=""
  cat "$background_log"
  if [ "$rc" -ne 0 ]; then echo "$1 FAILED (exit code $rc)"; exit "$rc"; fi
}

# For the caller's EXIT trap: ends the job if it is still running.
stop_background() {
  if [ -n "$background" ]; then kill -- "-$background" 2>/dev/null || true; fi
}
