#!/usr/bin/env bash
# Runs a command with an HTTP server on 127.0.0.1 serving the whole file system (so tests can
# stream any file they made), then stops the server:
#   with_server.sh nginx|faulty COMMAND...
# The command gets PSTREAM_TEST_URL_BASE=http://127.0.0.1:PORT (a URL is that plus an absolute
# path). nginx runs in the foreground from a config in a temporary folder (tests only: it
# answers multi-range requests, which we never send); `faulty` is tests/http/fault_server.py,
# single-range like S3.
set -uo pipefail
kind=$1; shift
here=$(cd "$(dirname "$0")" && pwd)
dir=$(mktemp -d /tmp/pstream-http.XXXXXX)
server=""
cleanup() { [ -n "$server" ] && kill "$server" 2>/dev/null; wait 2>/dev/null; rm -rf "$dir"; }
trap cleanup EXIT
case $kind in
  nginx)
    port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    user_line=""
    [ "$(id -u)" = 0 ] && user_line="user root;"  # workers read the tests' files as they were written
    mkdir -p "$dir/tmp"
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
    ;;
  faulty)
    python3 "$here/fault_server.py" --root / --port 0 --port-file "$dir/port" &
    server=$!
    ;;
  *) echo "with_server.sh: expected nginx or faulty, got '$kind'" >&2; exit 2 ;;
esac
for _ in $(seq 100); do
  [ "$kind" = faulty ] && [ -s "$dir/port" ] && port=$(cat "$dir/port")
  if [ -n "${port:-}" ] && (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; then break; fi
  sleep 0.1
done
export PSTREAM_TEST_URL_BASE="http://127.0.0.1:$port" PSTREAM_TEST_SERVER=$kind
"$@"
