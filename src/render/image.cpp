#include <stb_image.h>
#include <stb_image_write.h>

#include <fmt/format.h>

#include "particlestream/render.hpp"

namespace pstream::render {

void write_png(const std::filesystem::path& path, int width, int height, std::span<const std::uint8_t> rgba) {
  if (rgba.size() < std::size_t(width) * height * 4) throw Error(fmt::format("{}: not enough pixels", path.string()));
  if (stbi_write_png(path.c_str(), width, height, 4, rgba.data(), width * 4) == 0) {
    throw Error(fmt::format("{}: cannot write the PNG", path.string()));
  }
}

std::vector<std::uint8_t> read_png(const std::filesystem::path& path, int& width, int& height) {
  int channels = 0;
  unsigned char* data = stbi_load(path.c_str(), &width, &height, &channels, 4);
  if (data == nullptr) throw Error(fmt::format("{}: cannot read the image: {}", path.string(), stbi_failure_reason()));
  std::vector<std::uint8_t> out(data, data + std::size_t(width) * height * 4);
  stbi_image_free(data);
  return out;
}

}  // namespace pstream::render
