// Built without libcurl: URLs are refused with a message that says how to get them.
#include "particlestream/io.hpp"

namespace pstream::io {

bool http_supported() { return false; }

std::unique_ptr<ByteSource> open_url(const std::string& url, const HttpOptions&) {
  throw Error(url +
              ": this build of ParticleStream has no HTTP(S) streaming (configure with libcurl installed: Debian's "
              "libcurl4-openssl-dev, and -DPSTREAM_HTTP=ON)");
}

}  // namespace pstream::io
