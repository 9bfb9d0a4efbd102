#!/usr/bin/env bash
# Every pstream command on every input of the adversarial tree (tests/adversarial/make_inputs.cpp,
# plus special files made here), each under a timeout and, outside sanitizer builds, an
# address-space limit. Fails when any run
#   - ends on a signal or hits the timeout (a crash or a hang),
#   - prints "internal error" or a sanitizer report,
# or when afterwards a temporary (.NAME.partial-PID) is left anywhere or an input has changed.
# Also: outputs that are inputs, special outputs, absurd plans, files truncated while they are
# read, and SIGINT/SIGTERM/SIGHUP during a cook.
# Each input also goes through the C API (HOST_OPEN: tests/adversarial/host_open.c, the file and
# host IO callbacks) and, when given, the Python module (PYTHON, with particlestream on
# PYTHONPATH, running tests/adversarial/python_open.py); MISUSE (tests/sdk/misuse.c) runs once.
#   run.sh PSTREAM MAKE_INPUTS DATA_DIR plain|sanitized HOST_OPEN MISUSE [PYTHON]
set -uo pipefail
pstream=$1 make_inputs=$2 data=$3 flavour=${4:-plain} host_open=${5:-} misuse=${6:-} python=${7:-}
here=$(cd "$(dirname "$0")" && pwd)
root=$(mktemp -d /tmp/pstream-adversarial.XXXXXX)
trap 'rm -rf "$root"' EXIT
in=$root/inputs out=$root/out
mkdir -p "$in" "$out"
"$make_inputs" "$data" "$in" || { echo "make_inputs failed"; exit 1; }
mkfifo "$in/fifo.abc" "$in/fifo.pstream" "$in/fifo.0001.ply"
mkdir "$in/folder.pstream" "$in/folder.abc"

failures=0 runs=0
limit_kb=$((4 * 1024 * 1024))  # 4 GiB of address space: far below what a runaway allocation asks
timeout_s=60
[ "$flavour" = sanitized ] && timeout_s=180

# run LABEL ARGS...: one pstream command, checked. run_program LABEL PROGRAM ARGS...: any program.
run() {
  local label=$1; shift
  run_program "$label" "$pstream" "$@"
}
run_program() {
  local label=$1 program=$2; shift 2
  local log=$root/last.log rc
  if [ "$flavour" = plain ]; then
    (ulimit -v "$limit_kb"; cd "$out" && timeout -k 5 "$timeout_s" "$program" "$@") >"$log" 2>&1 </dev/null
  else
    # Mesa leaks a little when it is unloaded at exit: no leak checking for the GL commands (as in
    # pstream_render_tests); every other check stays on.
    local asan=${ASAN_OPTIONS:-}
    case $1 in render | play) asan="detect_leaks=0:abort_on_error=1" ;; esac
    [ "$program" != "$pstream" ] && asan="detect_leaks=0:abort_on_error=1"  # a host abandons reads by design
    (cd "$out" && ASAN_OPTIONS=$asan timeout -k 5 "$timeout_s" "$program" "$@") >"$log" 2>&1 </dev/null
  fi
  judge "$label" "$program" $? "$log" "" "$@"
  return 0
}

# judge LABEL PROGRAM RC LOG WHY_SO_FAR ARGS...: counts the run, and a failure when it hung, ended
# on a signal, said "internal error", got a sanitizer report, or WHY_SO_FAR says why already.
judge() {
  local label=$1 program=$2 rc=$3 log=$4 why=$5
  shift 5
  runs=$((runs + 1))
  if [ -n "$why" ]; then :
  elif [ "$rc" -eq 124 ] || [ "$rc" -eq 137 ]; then why="timed out (a hang)"
  elif [ "$rc" -ge 128 ]; then why="ended by signal $((rc - 128))"
  elif [ "$rc" -eq 2 ] && [ "$program" != "$pstream" ]; then why="an error without a message, or an exception that is not particlestream.Error"
  elif grep -q "internal error" "$log"; then why="internal error"
  elif grep -qE "AddressSanitizer|LeakSanitizer|runtime error:" "$log"; then why="sanitizer report"
  fi
  if [ -n "$why" ]; then
    failures=$((failures + 1))
    echo "FAIL [$label] $(basename "$program") $* -> rc $rc: $why"
    head -c 3000 "$log" | sed 's/^/    /'
  fi
}

checksums() { (cd "$in" && find . -type f -print0 | sort -z | xargs -0 sha256sum); }
before=$(checksums)

# URL inputs (tests/http/fault_server.py, and a port that accepts and never answers): a server
# that never answers, one that answers garbage instead of HTTP, one whose body never ends, at the
# open and after it. Each run may wait out the HTTP source's stall budget (about 20 s a read), so
# they run side by side, started here and checked as above after the inputs' runs: their waits
# (about 45 s, little CPU) overlap the inputs' runs rather than following them.
url_runs=()
url_run() {  # LABEL PROGRAM ARGS...: started in the background, checked after the inputs' runs
  local n=${#url_runs[@]} label=$1 program=$2; shift 2
  url_runs+=("$label|$program|$*")
  (
    cd "$uout" || exit 99
    asan=${ASAN_OPTIONS:-}
    [ "$flavour" = sanitized ] && [ "$program" != "$pstream" ] && asan="detect_leaks=0:abort_on_error=1"
    # As above: render and play load the GL driver, whose allocations LeakSanitizer cannot name
    # once it is unloaded (a URL that fails after the context exists showed 256 bytes of them).
    case ${1:-} in render | play) asan="detect_leaks=0:abort_on_error=1" ;; esac
    ASAN_OPTIONS=$asan timeout -k 5 240 "$program" "$@" >"$root/url.$n.log" 2>&1 </dev/null
    echo $? >"$root/url.$n.rc"
  ) &
}
if [ -n "$python" ] || command -v python3 >/dev/null; then
  py=${python:-python3}
  "$py" "$here/../http/fault_server.py" --root / --port 0 --port-file "$root/port" &
  fault_server=$!
  "$py" -c 'import socket, sys, time
s = socket.socket(); s.bind(("127.0.0.1", 0)); s.listen(64)
open(sys.argv[1], "w").write(str(s.getsockname()[1])); time.sleep(3600)' "$root/silent_port" &
  silent_server=$!
  for _ in $(seq 100); do [ -s "$root/port" ] && [ -s "$root/silent_port" ] && break; sleep 0.1; done
  base=http://127.0.0.1:$(cat "$root/port")
  clip=$in/good.pstream
  urls=("http://127.0.0.1:$(cat "$root/silent_port")$clip")
  for fault in hang garbage infinite; do urls+=("$base/~$fault=0$clip" "$base/~$fault=1$clip"); done
  uout=$root/url_out  # not under $out, which each input empties
  mkdir -p "$uout"
  for i in "${!urls[@]}"; do
    u=${urls[$i]}
    url_run "$u" "$pstream" info "$u" --json
    url_run "$u" "$pstream" verify "$u"
    url_run "$u" "$pstream" export "$u" -o "$uout/e$i.abc" -q
    url_run "$u" "$pstream" render "$u" --out "$uout/r$i" --frames 0:3 --size 32x32 -q
    [ -n "$host_open" ] && url_run "$u" "$host_open" "$u"
    [ -n "$python" ] && url_run "$u" "$python" "$here/python_open.py" "$u"
  done
  url_started=$SECONDS
fi

for f in "$in"/*; do
  name=$(basename "$f")
  rm -rf "${out:?}"/*
  run "$name" info "$f"
  run "$name" info "$f" --json
  run "$name" info "$f" --json --frames
  run "$name" verify "$f"
  run "$name" verify "$f" --json
  run "$name" cook "$f" -o "$out/c.pstream" -q
  run "$name" cook "$f" -o "$out/c.pstream" --codec particle -q
  run "$name" cook "$f" -o "$out/c.pstream" --interpolate --fps 60 -q
  run "$name" render "$f" --out "$out/r" --frames 0:3 --size 32x32 -q
  run "$name" export "$f" --out "$out/e" -q
  run "$name" export "$f" -o "$out/e.abc" -q
  run "$name" bench stream "$f" --laps 1 --json
  run "$name" bench codec "$f" --frames 3 --repetitions 1 --json
  run "$name" bench read "$f" --repetitions 1 --json
  run "$name" play "$f" --frames-to-run 2
  [ -n "$host_open" ] && run_program "$name" "$host_open" "$f"
  [ -n "$python" ] && run_program "$name" "$python" "$here/python_open.py" "$f"
done

if [ -n "${url_started:-}" ]; then
  for n in "${!url_runs[@]}"; do
    while [ ! -e "$root/url.$n.rc" ] && [ $((SECONDS - url_started)) -lt 300 ]; do sleep 0.5; done
    IFS='|' read -r label program args <<<"${url_runs[$n]}"
    rc=$(cat "$root/url.$n.rc" 2>/dev/null || echo 124)
    why=""
    if [ "$rc" -eq 0 ] && [ "$program" = "$pstream" ] &&
      [[ $label == *"~"*"=0"* || $label == *":$(cat "$root/silent_port")/"* ]]; then
      why="succeeded against a server that never serves"
    fi
    # shellcheck disable=SC2086  # the arguments as they were given, for the message
    judge "$label" "$program" "$rc" "$root/url.$n.log" "$why" $args
  done
  kill "$fault_server" "$silent_server" 2>/dev/null
  wait "$fault_server" "$silent_server" 2>/dev/null
  echo "adversarial: ${#url_runs[@]} URL runs, done $((SECONDS - url_started)) s after they started"
fi

# A host that breaks the C API's rules (a completion twice, one that never comes, double close).
if [ -n "$misuse" ]; then
  mkdir -p "$root/misuse"
  run_program misuse "$misuse" "$data" "$root/misuse"
fi

# Absurd plans and outputs.
rm -rf "${out:?}"/*
run plan cook "$in/good.abc" --fps 1e15 -o "$out/c.pstream"
run plan cook "$in/good.abc" --fps 1e-300 -o "$out/c.pstream"
run plan cook "$in/good.abc" --frames 0:99999999999999999999 -o "$out/c.pstream"
run plan render "$in/good.pstream" --fps 1e6 --out "$out/r"
run output cook "$in/good.abc" -o "$in/good.abc"
run output cook "$in/good.abc" -o "$in/fifo.pstream"
run output cook "$in/good.abc" -o "$in/folder.pstream"
run output cook "$in/good.abc" -o /dev/null -q
run output export "$in/good.pstream" -o "$in/good.pstream"
run output export "$in/good.pstream" -o "$in/good.txt"  # an extension that is no format: refused, nothing written
run output render "$in/good.pstream" --out "$in/good.abc" --frames 0:1
run output bench all --out "$out/no/such/folder/b.md"
if [ ! -c /dev/null ]; then echo "FAIL /dev/null is no longer a character device"; failures=$((failures + 1)); fi

# Files truncated while they are read (a copy each time: these are not inputs of the tree).
"$pstream" cook "$data/alembic/points_large.abc" -o "$root/race_src.pstream" -q --chunk-size 64KiB
for delay in 0 0.01 0.02 0.05 0.1; do
  for what in cook verify info; do
    cp "$data/alembic/points_large.abc" "$root/race.abc"
    cp "$root/race_src.pstream" "$root/race.pstream"
    case $what in
      cook) args=(cook "$root/race.abc" -o "$out/race_out.pstream" -q --codec zstd) file=$root/race.abc ;;
      verify) args=(verify "$root/race.pstream") file=$root/race.pstream ;;
      info) args=(info "$root/race.pstream" --json --frames) file=$root/race.pstream ;;
    esac
    ( sleep "$delay"; truncate -s 100000 "$file" ) &
    run "truncated after ${delay}s" "${args[@]}"
    wait
  done
done

# Signals during a cook: the temporary must go with the process.
for sig in INT TERM HUP; do
  cp "$data/alembic/points_large.abc" "$root/sig.abc"
  (cd "$out" && exec "$pstream" cook "$root/sig.abc" -o "$out/sig.pstream" -q --codec zstd:19) >/dev/null 2>&1 &
  pid=$!
  sleep 0.3
  kill -s "$sig" "$pid" 2>/dev/null
  wait "$pid"
  runs=$((runs + 1))
done

# Every run's working directory and output is under $root, and it reads $data: a temporary can only
# be there. (The test's own directory is not searched: ctest runs other tests beside this one, and
# their cooks' temporaries there are not ours. It had been, and one in flight failed this test.)
leftovers=$(find "$root" "$data" -maxdepth 4 -name '.*.partial-*' 2>/dev/null)
if [ -n "$leftovers" ]; then
  echo "FAIL temporaries left behind:"; echo "$leftovers" | sed 's/^/    /'
  failures=$((failures + 1))
fi
after=$(checksums)
if [ "$before" != "$after" ]; then
  echo "FAIL an input was modified:"; diff <(echo "$before") <(echo "$after") | sed 's/^/    /'
  failures=$((failures + 1))
fi
echo "adversarial: $runs runs, $failures failures ($(ls "$in" | wc -l) inputs, $flavour build)"
[ "$failures" -eq 0 ]
