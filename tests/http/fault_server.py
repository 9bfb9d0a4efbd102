"""A small HTTP server for the remote-streaming tests that behaves like an object store and can
misbehave on request. It serves files from --root, one byte range per request (as S3 does: a
multi-range request gets the first range only), with ETag and Last-Modified, keep-alive, and
faults chosen by the URL's first path segments:

    /FILE                      served as it is
    /~latency=50/FILE          50 ms before each response
    /~rate=200000/FILE         each body at 200,000 bytes/s
    /~bandwidth=2e7/FILE       every body of every request with this fault shares 2e7 bytes/s (a link)
    /~fail=503x2/FILE          the first 2 requests for this URL (after the first one, the open's)
                               get 503 (or 500, 429)
    /~drop=2/FILE              the first 2 requests after the open's drop the connection mid-body
    /~short=1/FILE             every request after the open's sends a short body and closes
    /~full200=1/FILE           every request gets 200 and the whole file (no range support)
    /~change=3/FILE            after 3 requests the file is "replaced": a new ETag and Last-Modified
    /~hang=1/FILE              requests after the first 1 (the open's) are read and never answered;
                               /~hang=0/ never answers at all
    /~garbage=1/FILE           requests after the first 1 get bytes that are no HTTP response
    /~infinite=1/FILE          requests after the first 1 get a 206 whose body never ends

Segments combine (/~latency=50/~rate=1e6/FILE). --port 0 picks a free port; it is written to
--port-file once the server listens.

    fault_server.py --root DIR [--port N] [--port-file F]
"""
import argparse
import email.utils
import os
import re
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

counts = {}
counts_lock = threading.Lock()
link_lock = threading.Lock()
link_free = [0.0]  # when the shared link (~bandwidth) is next free, time.monotonic()


def link_send(wfile, data, rate):
    """Writes data through the one link all ~bandwidth requests share, in slices."""
    step = max(1024, int(rate / 100))
    for i in range(0, len(data), step):
        piece = data[i:i + step]
        with link_lock:
            start = max(time.monotonic(), link_free[0])
            link_free[0] = start + len(piece) / rate
            done = link_free[0]
        pause = done - time.monotonic()
        if pause > 0:
            time.sleep(pause)
        wfile.write(piece)


TYPES = {".html": "text/html", ".js": "text/javascript", ".mjs": "text/javascript", ".wasm": "application/wasm",
         ".css": "text/css", ".png": "image/png"}


def content_type(path):
    """What browsers need for the web player's page (module scripts are refused without it)."""
    return TYPES.get(os.path.splitext(path)[1], "application/octet-stream")


def count(key):
    with counts_lock:
        counts[key] = counts.get(key, 0) + 1
        return counts[key]


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True  # headers and body go in separate writes

    def log_message(self, *args):
        pass

    def faults_and_path(self):
        faults, rest = {}, self.path.split("?", 1)[0]
        while True:
            m = re.match(r"^/~([a-z0-9]+)=([^/]+)(/.*)$", rest)
            if not m:
                break
            faults[m.group(1)] = m.group(2)
            rest = m.group(3)
        return faults, rest

    def do_HEAD(self):
        self.handle_request(head=True)

    def do_GET(self):
        self.handle_request(head=False)

    def send_plain(self, code, text):
        body = text.encode()
        self.send_response(code)
        self.send_header("Content-Type", "text/plain")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def handle_request(self, head):
        faults, path = self.faults_and_path()
        n = count(self.path)  # this URL's requests so far, this one included
        later = n > 1  # not the open's first request
        if "latency" in faults:
            time.sleep(float(faults["latency"]) / 1000)
        def past(fault):  # this request is past the first N that the fault spares
            return fault in faults and n > int(faults[fault])

        if past("hang"):
            time.sleep(3600)
            return
        if past("garbage"):
            self.wfile.write(b"\x00\xffNOT HTTP AT ALL\r\n\r\n\x01\x02")
            self.close_connection = True
            return
        if "fail" in faults and later:
            code, times = faults["fail"].split("x")
            if n - 1 <= int(times):
                self.send_plain(int(code), "injected failure\n")
                return
        file = os.path.join(self.server.root, path.lstrip("/"))
        if not os.path.isfile(file):
            self.send_plain(404, "not found\n")
            return
        size = os.path.getsize(file)
        version = 1
        if "change" in faults and n > int(faults["change"]):
            version = 2
        etag = f'"{size:x}-v{version}"'
        modified = email.utils.formatdate(1700000000 + version * 1000, usegmt=True)
        start, end = 0, size - 1
        ranged = False
        header = self.headers.get("Range")
        if header and "full200" not in faults:
            m = re.match(r"^bytes=(\d+)-(\d*)", header.strip())  # the first range only
            if m:
                ranged = True
                start = int(m.group(1))
                end = min(int(m.group(2)) if m.group(2) else size - 1, size - 1)
                if start >= size:
                    self.send_response(416)
                    self.send_header("Content-Range", f"bytes */{size}")
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
        with open(file, "rb") as f:  # only the range: files may be large
            f.seek(start)
            body = f.read(end + 1 - start)
        if past("infinite"):
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
            self.send_header("ETag", etag)
            self.end_headers()  # no length: the body ends when the connection does (never)
            try:
                while True:
                    self.wfile.write(b"\x55" * 65536)
            except OSError:
                pass
            self.close_connection = True
            return
        self.send_response(206 if ranged else 200)
        if ranged:
            self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("ETag", etag)
        self.send_header("Last-Modified", modified)
        self.send_header("Content-Type", content_type(path))
        self.end_headers()
        if head:
            return
        if ("drop" in faults and later and n - 1 <= int(faults["drop"])) or ("short" in faults and later):
            self.wfile.write(body[: len(body) // 2])
            self.wfile.flush()
            self.connection.shutdown(socket.SHUT_RDWR)
            self.close_connection = True
            return
        rate = float(faults.get("rate", 0))
        if "bandwidth" in faults:
            link_send(self.wfile, body, float(faults["bandwidth"]))
        elif rate > 0:
            step = max(1024, int(rate / 50))
            for i in range(0, len(body), step):
                t = time.monotonic()
                self.wfile.write(body[i:i + step])
                pause = len(body[i:i + step]) / rate - (time.monotonic() - t)
                if pause > 0:
                    time.sleep(pause)
        else:
            self.wfile.write(body)


class Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def handle_error(self, request, client_address):
        pass  # clients that drop connections (cut-off bodies, closing streams) are expected here


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", required=True)
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--port-file")
    args = parser.parse_args()
    server = Server(("127.0.0.1", args.port), Handler)
    server.root = os.path.abspath(args.root)
    if args.port_file:
        with open(args.port_file + ".tmp", "w") as f:
            f.write(str(server.server_address[1]))
        os.replace(args.port_file + ".tmp", args.port_file)
    server.serve_forever()


if __name__ == "__main__":
    main()
