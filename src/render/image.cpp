#include <stb_image.h>
#include <stb_image_write.h>

#include <limits>

#include <fmt/format.h>

#include "base/mapped_file.hpp"
#include "base/output_file.hpp"
#include "particlestream/render.hpp"

namespace pstream::render {

void write_png(const std::filesystem::path& path, int width, int height, std::span<const std::uint8_t> rgba) {
  if (rgba.size() < std::size_t(width) * height * 4) throw Error(fmt::format("{}: not enough pixels", path.string()));
  // Encoded in memory, then written through an OutputFile: checked, and complete or absent.
  std::vector<std::byte> png;
  const auto append = [](void* context, void* data, int size) {
    auto& out = *static_cast<std::vector<std::byte>*>(context);
    const auto* bytes = static_cast<const std::byte*>(data);
    out.insert(out.end(), bytes, bytes + size);
  };
  if (stbi_write_png_to_func(append, &png, width, height, 4, rgba.data(), width * 4) == 0) {
    throw Error(fmt::format("{}: cannot encode a {}x{} PNG", path.string(), width, height));
  }
  write_file(path, png);
}

std::vector<std::uint8_t> read_png(const std::filesystem::path& path, int& width, int& height) {
  const MappedFile file = MappedFile::open(path);  // a regular file only: a FIFO would block
  if (file.bytes().size() > static_cast<std::size_t>(std::numeric_limits<int>::max()))
    throw Error(fmt::format("{}: {} bytes is too large for an image", path.string(), file.bytes().size()));
  int channels = 0;
  unsigned char* data = stbi_load_from_memory(reinterpret_cast<const stbi_uc*>(file.bytes().data()),
                                              static_cast<int>(file.bytes().size()), &width, &height, &channels, 4);
  file.check_intact();
  if (data == nullptr) throw Error(fmt::format("{}: cannot read the image: {}", path.string(), stbi_failure_reason()));
  std::vector<std::uint8_t> out(data, data + std::size_t(width) * height * 4);
  stbi_image_free(data);
  return out;
}

}  // namespace pstream::render
