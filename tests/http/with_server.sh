#!/usr/bin/env bash
# Runs a command with an HTTP server on 127.0.0.1 serving the whole file system (so tests can
# stream any file they made), then stops the server:
#   with_server.sh nginx|faulty COMMAND...
# The command gets PSTREAM_TEST_URL_BASE=http://127.0.0.1:PORT (a URL is that plus an absolute
# path). nginx runs in the foreground from a config in a temporary folder (tests only: it
# answers multi-range requests, which we never send); `faulty` is tests/http/fault_server.py,
# single-range like S3.
#
# The server is ours before the command starts, or the command does not start:
#   - nginx gets a port that was free a moment before, and another test's server or connection
#     may take it first: nginx then exits ("bind() failed") while the port still answers, as the
#     other's. So it is ours once nginx has written its pid file (it does so after it listens)
#     and still runs; if it exited, a new port is tried;
#   - fault_server.py binds port 0 itself and names the port in its port file once it listens.
# On a machine busy with the rest of the suite a server may take seconds to start: it gets 60.
set -uo pipefail
kind=$1; shift
here=$(cd "$(dirname "$0")" && pwd)
dir=$(mktemp -d /tmp/pstream-http.XXXXXX)
server=""
cleanup() { [ -n "$server" ] && kill "$server" 2>/dev/null; wait 2>/dev/null; rm -rf "$dir"; }
trap cleanup EXIT

# Waits until `ready` (a command) succeeds while the server runs: false if the server exits or
# 60 s pass.
wait_until() {
  for _ in $(seq 600); do
    "$@" && return 0
    kill -0 "$server" 2>/dev/null || return 1
    sleep 0.1
  done
  return 1
}
answers() { (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; }
nginx_listens() { [ -s "$dir/nginx.pid" ] && answers; }
fault_server_listens() { [ -s "$dir/port" ] && port=$(cat "$dir/port") && answers; }

start_nginx() {
  port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  local user_line=""
  [ "$(id -u)" = 0 ] && user_line="user root;"  # workers read the tests' files as they were written
  mkdir -p "$dir/tmp"
  rm -f "$dir/nginx.pid"
  cat >"$dir/nginx.conf" <<CONF
daemon off;
master_process on;
worker_processes 2;
$user_line
pid $dir/nginx.pid;
error_log $dir/error.log;
events { worker_connections 256; }
http {
  access_log off;
  client_body_temp_path $dir/tmp; proxy_temp_path $dir/tmp; fastcgi_temp_path $dir/tmp;
  uwsgi_temp_path $dir/tmp; scgi_temp_path $dir/tmp;
  default_type application/octet-stream;
  types { text/html html; text/javascript js mjs; application/wasm wasm; text/css css; image/png png; }
  keepalive_requests 100000;
  server { listen 127.0.0.1:$port; root /; }
}
CONF
  nginx -c "$dir/nginx.conf" -p "$dir" &
  server=$!
  wait_until nginx_listens
}

case $kind in
  nginx)
    started=false
    for _ in 1 2 3 4 5; do
      if start_nginx; then started=true; break; fi
      [ -n "$server" ] && kill "$server" 2>/dev/null; wait "$server" 2>/dev/null; server=""
    done
    if ! $started; then
      echo "with_server.sh: nginx did not start on 127.0.0.1 in 5 tries; its log:" >&2
      cat "$dir/error.log" >&2
      exit 1
    fi
    ;;
  faulty)
    python3 "$here/fault_server.py" --root / --port 0 --port-file "$dir/port" &
    server=$!
    if ! wait_until fault_server_listens; then
      echo "with_server.sh: fault_server.py did not listen on 127.0.0.1 within 60 s" >&2
      exit 1
    fi
    ;;
  *) echo "with_server.sh: expected nginx or faulty, got '$kind'" >&2; exit 2 ;;
esac
export PSTREAM_TEST_URL_BASE="http://127.0.0.1:$port" PSTREAM_TEST_SERVER=$kind
"$@"
